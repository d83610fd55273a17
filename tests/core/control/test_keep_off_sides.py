"""keep_off_sides: the paper's law steered off a wall beside the robot (control.side_keep_m)."""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given
from hypothesis import strategies as st

from relayd.core.control.law import ControlParams
from relayd.core.control.steer import KEEP_PUSH_DEG, keep_off_sides
from relayd.core.scan.estimator import SonarReading
from tests.core.control.test_law import sonar, step

LEFT, RIGHT = 0, 7  # the front ring's side sonars: +90 and -90 deg


def sides(left_mm: int | None, right_mm: int | None) -> tuple[SonarReading, ...]:
    return sonar(**{f"s{LEFT}": left_mm, f"s{RIGHT}": right_mm})


def test_on_by_default_and_off_at_zero() -> None:
    assert ControlParams().side_keep_m == 0.35
    assert keep_off_sides(7.0, sides(100, 100), 0.0) == 7.0


def test_a_wall_near_on_the_right_turns_the_steer_left_in_proportion() -> None:
    assert keep_off_sides(0.0, sides(None, 100), 0.35) == pytest.approx(KEEP_PUSH_DEG * 0.25 / 0.35)
    assert keep_off_sides(0.0, sides(100, None), 0.35) == pytest.approx(
        -KEEP_PUSH_DEG * 0.25 / 0.35
    )
    # Beyond the keep distance, nothing; between two walls, toward the farther one.
    assert keep_off_sides(3.0, sides(400, 500), 0.35) == 3.0
    assert keep_off_sides(0.0, sides(300, 100), 0.35) > 0.0


@given(
    st.floats(-90, 90),
    st.one_of(st.none(), st.integers(0, 5000)),
    st.one_of(st.none(), st.integers(0, 5000)),
    st.floats(0.05, 1.5),
)
def test_the_push_is_bounded_and_never_toward_the_nearer_side(
    steer: float, left: int | None, right: int | None, keep: float
) -> None:
    push = keep_off_sides(steer, sides(left, right), keep) - steer
    assert abs(push) <= KEEP_PUSH_DEG + 1e-9
    far = 10_000
    lm, rm = (left if left is not None else far), (right if right is not None else far)
    if lm < rm:
        assert push <= 1e-9  # a nearer left wall never pulls the steer left
    if rm < lm:
        assert push >= -1e-9


def test_the_law_turns_off_a_glancing_wall_and_stays_within_v_max() -> None:
    near_right = sides(None, 200)
    paper = dataclasses.replace(ControlParams(), side_keep_m=0.0)
    plain = step(params=paper, bearing_deg=0.0, prev_bearing_deg=0.0, front_sonar=near_right)
    keep = ControlParams()
    kept = step(params=keep, bearing_deg=0.0, prev_bearing_deg=0.0, front_sonar=near_right)
    assert plain.left_mm_s == plain.right_mm_s  # the paper's law: straight at the bearing
    assert kept.right_mm_s > kept.left_mm_s  # turning left, off the wall on the right
    assert max(abs(kept.left_mm_s), abs(kept.right_mm_s)) <= keep.v_max_mm_s
    assert kept.reason == plain.reason == "driving"
