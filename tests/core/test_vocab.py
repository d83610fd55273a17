"""The one vocabulary (relayd.core.vocab): every reason code is a Reason, and every Reason
has a phrase; one angle wrap (relayd.core.geometry)."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from relayd.api.reasons import phrasebook
from relayd.core.geometry import SONAR_COUNT, SONAR_HEADINGS_DEG, SONAR_POSES, wrap_deg, wrap_rad
from relayd.core.vocab import Reason
from tests.core.test_reasons import source_reason_codes


def test_every_reason_has_a_phrase_and_every_phrase_a_reason() -> None:
    assert set(phrasebook()) == {r.value for r in Reason}


def test_every_code_the_source_gives_is_a_reason() -> None:
    assert source_reason_codes() <= {r.value for r in Reason}


def test_a_reason_is_its_string() -> None:
    """Documents and traces read the same whether a code is a member or a literal."""
    assert Reason.LEADER_NEAR == "leader_near"
    assert f"{Reason.REAR_WEAK}" == "rear_weak"


@given(st.floats(min_value=-1e6, max_value=1e6, allow_nan=False))
def test_wrap_is_in_range_and_the_same_angle(angle_deg: float) -> None:
    w = wrap_deg(angle_deg)
    assert -180.0 < w <= 180.0
    assert math.isclose(math.remainder(w - angle_deg, 360.0), 0.0, abs_tol=1e-6)


@given(st.floats(min_value=-179.999, max_value=180.0, allow_nan=False))
def test_wrap_leaves_an_angle_in_range_alone(angle_deg: float) -> None:
    assert wrap_deg(angle_deg) == angle_deg


@given(st.floats(min_value=-1e4, max_value=1e4, allow_nan=False))
def test_the_radians_wrap_has_the_same_convention(angle_rad: float) -> None:
    w = wrap_rad(angle_rad)
    assert -math.pi < w <= math.pi
    assert math.isclose(math.remainder(w - angle_rad, math.tau), 0.0, abs_tol=1e-9)
    in_deg = math.radians(wrap_deg(math.degrees(angle_rad)))  # one convention, two units
    assert math.isclose(math.remainder(in_deg - w, math.tau), 0.0, abs_tol=1e-9)


@given(st.floats(min_value=-3.14159, max_value=math.pi, allow_nan=False))
def test_the_radians_wrap_leaves_an_angle_in_range_alone(angle_rad: float) -> None:
    assert wrap_rad(angle_rad) == angle_rad


def test_the_radians_wrap_keeps_the_half_turn_on_the_positive_side() -> None:
    assert wrap_rad(-math.pi) == math.pi
    assert wrap_rad(math.pi) == math.pi
    assert wrap_rad(3.0 * math.pi) == math.pi


def test_the_sonar_geometry_is_the_drivers() -> None:
    assert SONAR_COUNT == 16
    assert tuple(float(p.heading_deg) for p in SONAR_POSES) == SONAR_HEADINGS_DEG
