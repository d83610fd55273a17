"""slide_along_wall: the law steers no further into a wall beside the robot than along it
(control.wall_slide_m), so a leader heard through a wall is followed along it, not into it."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from relayd.core.avoid.ring import POSE_M
from relayd.core.control.law import ControlParams
from relayd.core.control.steer import SLIDE_MAX_DEG, slide_along_wall
from relayd.core.scan.estimator import SonarReading
from tests.core.control.test_law import sonar, step

#: The front ring's indices by heading (sonar 0 is +90, the left side).
INDEX = {90.0: 0, 50.0: 1, 30.0: 2, 10.0: 3, -10.0: 4, -30.0: 5, -50.0: 6, -90.0: 7}
SLIDE = ControlParams()  # the slide is on by default (1.5 m)
PAPER = dataclasses.replace(SLIDE, wall_slide_m=0.0)


def wall_ring(side: int, lateral_m: float, angle_deg: float = 0.0) -> tuple[SonarReading, ...]:
    """The front ring beside one straight wall on `side`, lateral_m from the robot's centre
    and running angle_deg off the heading (ccw +): each sonar's axis to the line (the
    fit's own geometry, beam edges aside), nothing on the other side."""
    a = math.radians(angle_deg)
    nx, ny = -side * math.sin(a), side * math.cos(a)  # unit normal toward the wall
    ranges: dict[str, int | None] = {}
    for h, i in INDEX.items():
        x0, y0 = POSE_M[h]
        cx, cy = math.cos(math.radians(h)), math.sin(math.radians(h))
        gap = lateral_m - (nx * x0 + ny * y0)
        dot = nx * cx + ny * cy
        ranges[f"s{i}"] = round(1000 * gap / dot) if dot > 1e-6 and gap > 0 else None
    return sonar(**ranges)


@pytest.mark.parametrize("side", [1, -1])
def test_a_leader_through_the_wall_beside_is_followed_along_it(side: int) -> None:
    ring = wall_ring(side, 0.8)
    assert slide_along_wall(side * 84.0, ring, 1.0) == pytest.approx(0.0, abs=1.0)
    # The wall converging ahead (the robot heading 10 deg into it): along it is away.
    into = wall_ring(side, 0.8, angle_deg=-side * 10.0)
    assert slide_along_wall(side * 84.0, into, 1.0) == pytest.approx(-side * 10.0, abs=1.5)


def test_off_at_zero_behind_and_away_from_the_wall() -> None:
    ring = wall_ring(-1, 0.8)
    assert slide_along_wall(-84.0, ring, 0.0) == -84.0
    assert slide_along_wall(-(SLIDE_MAX_DEG + 5.0), ring, 1.0) == -(SLIDE_MAX_DEG + 5.0)
    assert slide_along_wall(40.0, ring, 1.0) == 40.0  # toward the open side: as it was
    # A wall beyond reach is no wall.
    assert slide_along_wall(-84.0, wall_ring(-1, 1.6), 1.0) == -84.0


@given(
    steer=st.floats(-180.0, 180.0),
    side=st.sampled_from([1, -1]),
    lateral=st.floats(0.3, 2.0),
    angle=st.floats(-30.0, 30.0),
)
def test_the_slide_only_ever_turns_the_steer_out_of_the_wall(
    steer: float, side: int, lateral: float, angle: float
) -> None:
    ring = wall_ring(side, lateral, angle)
    out = slide_along_wall(steer, ring, 1.0)
    if steer * side <= 0 or abs(steer) > SLIDE_MAX_DEG:
        assert out == steer  # away from the wall, or behind: untouched
    else:
        assert out * side <= steer * side + 1e-9  # never further toward the wall side


def test_the_law_drives_along_the_wall_where_the_paper_turns_into_it() -> None:
    ring = wall_ring(-1, 0.8)
    paper = step(params=PAPER, bearing_deg=-84.0, prev_bearing_deg=-84.0, front_sonar=ring)
    slid = step(params=SLIDE, bearing_deg=-84.0, prev_bearing_deg=-84.0, front_sonar=ring)
    assert paper.left_mm_s > paper.right_mm_s  # turning right, into the wall
    assert slid.reason == "driving" and slid.left_mm_s > 0 and slid.right_mm_s > 0
    assert abs(slid.left_mm_s - slid.right_mm_s) < 0.1 * (slid.left_mm_s + slid.right_mm_s)
    assert max(abs(slid.left_mm_s), abs(slid.right_mm_s)) <= SLIDE.v_max_mm_s


def test_no_d_term_kick_when_the_slide_takes_the_steer() -> None:
    """Bearing -84 after -60 into a wall: the wheels are those of the wall's direction
    alone, not a D term on the jump from the bearing to it."""
    ring = wall_ring(-1, 0.8)
    still = step(params=SLIDE, bearing_deg=-84.0, prev_bearing_deg=-84.0, front_sonar=ring)
    moved = step(params=SLIDE, bearing_deg=-84.0, prev_bearing_deg=-60.0, front_sonar=ring)
    assert (moved.left_mm_s, moved.right_mm_s) == (still.left_mm_s, still.right_mm_s)


def test_on_by_default_off_at_zero_from_config() -> None:
    from relayd.config.model import Settings
    from relayd.config.params import control_params

    assert control_params(Settings()).wall_slide_m == 1.5
    assert ControlParams().wall_slide_m == 1.5
    off = control_params(Settings.model_validate({"control": {"wall_slide_m": 0}}))
    assert off.wall_slide_m == 0.0
