"""slide_along_wall: the law steers no further into a wall beside the robot than along it
(control.wall_slide_m), so a leader heard through a wall is followed along it, not into it."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from relayd.core.avoid.ring import POSE_M, rear_readings
from relayd.core.control.law import ControlParams
from relayd.core.control.steer import SLIDE_MAX_DEG, slide_along_wall
from relayd.core.geometry import SONAR_POSES
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


def rear_ring(side: int, lateral_m: float, angle_deg: float = 0.0) -> tuple[SonarReading, ...]:
    """The rear ring's 90 and 130 deg sonars on `side` beside the same wall: a beam within
    15 deg of the wall's normal reads the transducer's distance to it (the front one too),
    the 130 deg one its axis to the line."""
    a = math.radians(angle_deg)
    nx, ny = -side * math.sin(a), side * math.cos(a)
    ranges: list[int | None] = [None] * 16
    for index in (15, 14) if side > 0 else (8, 9):
        pose = SONAR_POSES[index]
        gap = lateral_m - (nx * pose.x_mm + ny * pose.y_mm) / 1000.0
        h = math.radians(pose.heading_deg)
        dot = 1.0 if abs(pose.heading_deg) == 90 else nx * math.cos(h) + ny * math.sin(h)
        ranges[index] = round(1000 * gap / dot) if dot > 1e-6 and gap > 0 else None
    return rear_readings(ranges)


def abeam_ring(side: int, lateral_m: float, angle_deg: float = 0.0) -> tuple[SonarReading, ...]:
    """wall_ring with the front 90 deg sonar reading the perpendicular, as rear_ring."""
    a = math.radians(angle_deg)
    nx, ny = -side * math.sin(a), side * math.cos(a)
    h = side * 90.0
    x0, y0 = POSE_M[h]
    ring = list(wall_ring(side, lateral_m, angle_deg))
    i = next(k for k, r in enumerate(ring) if r.heading_deg == h)
    ring[i] = dataclasses.replace(ring[i], range_m=round(lateral_m - (nx * x0 + ny * y0), 3))
    return tuple(ring)


@pytest.mark.parametrize("side", [1, -1])
def test_a_leader_through_the_wall_beside_is_followed_along_it(side: int) -> None:
    ring = wall_ring(side, 0.8)
    assert slide_along_wall(side * 84.0, ring, 1.0, rear_ring(side, 0.8)) == pytest.approx(
        0.0, abs=0.5
    )
    # The wall converging ahead (the robot heading 10 deg into it): along it is away.
    into = abeam_ring(side, 0.8, angle_deg=-side * 10.0)
    behind = rear_ring(side, 0.8, angle_deg=-side * 10.0)
    assert slide_along_wall(side * 84.0, into, 1.0, behind) == pytest.approx(-side * 10.0, abs=1.5)
    # No rear echo abeam: the front one may be the edge of its beam on a wall across
    # the way ahead; the slide leaves the steer alone.
    assert slide_along_wall(side * 84.0, into, 1.0) == side * 84.0


def test_a_wall_across_the_way_ahead_does_not_turn_the_relay_off_its_door() -> None:
    """A 3 m corridor, the relay 0.28 m right of its middle before a fire door in a wall
    across it (door, seed 2): the 50 and 30 deg echoes come from that wall, and a fit
    through them steered 12 deg left, off the door, onto its jamb. The two abeam echoes
    are the side walls: parallel, and the steer toward the leader is held straight."""
    ring = sonar(s0=1310, s1=1360, s2=1210, s3=None, s4=None, s5=1200, s6=1200, s7=1430)
    behind = rear_readings([None] * 8 + [1430, 1870] + [None] * 4 + [1710, 1310])
    assert slide_along_wall(-13.9, ring, 1.5, behind) == pytest.approx(0.0, abs=0.5)


def test_a_robot_beside_is_no_wall() -> None:
    """The leader relay 1.2 m abeam (a close convoy's relay passing it, convoy seed 4):
    both 90 deg sonars hear it, the 50 deg ones ahead and behind do not. The law turns to
    it, as the paper's does."""
    ring = sonar(s7=1200)
    behind = rear_readings([None] * 8 + [1200] + [None] * 7)
    assert slide_along_wall(-70.0, ring, 1.5, behind) == -70.0
    wall_ring_, wall_behind = wall_ring(-1, 1.2), rear_ring(-1, 1.2)
    assert slide_along_wall(-70.0, wall_ring_, 1.5, wall_behind) == pytest.approx(0.0, abs=0.5)
    # A wall with a door ahead in it (the front 50 deg sonar hears nothing): still a wall.
    door_ahead = tuple(
        dataclasses.replace(r, range_m=None) if r.heading_deg == -50.0 else r for r in wall_ring_
    )
    assert slide_along_wall(-70.0, door_ahead, 1.5, wall_behind) == pytest.approx(0.0, abs=0.5)


def test_off_at_zero_behind_and_away_from_the_wall() -> None:
    ring, behind = wall_ring(-1, 0.8), rear_ring(-1, 0.8)
    assert slide_along_wall(-84.0, ring, 0.0, behind) == -84.0
    assert slide_along_wall(-(SLIDE_MAX_DEG + 5.0), ring, 1.0, behind) == -(SLIDE_MAX_DEG + 5.0)
    assert slide_along_wall(40.0, ring, 1.0, behind) == 40.0  # toward the open side: as it was
    # A wall beyond reach is no wall.
    far = slide_along_wall(-84.0, wall_ring(-1, 1.6), 1.0, rear_ring(-1, 1.6))
    assert far == -84.0


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
    out = slide_along_wall(steer, ring, 1.0, rear_ring(side, lateral, angle))
    if steer * side <= 0 or abs(steer) > SLIDE_MAX_DEG:
        assert out == steer  # away from the wall, or behind: untouched
    else:
        assert out * side <= steer * side + 1e-9  # never further toward the wall side


def test_the_law_drives_along_the_wall_where_the_paper_turns_into_it() -> None:
    ring, behind = wall_ring(-1, 0.8), rear_ring(-1, 0.8)
    beside = {"front_sonar": ring, "rear_sonar": behind}
    paper = step(params=PAPER, bearing_deg=-84.0, prev_bearing_deg=-84.0, **beside)
    slid = step(params=SLIDE, bearing_deg=-84.0, prev_bearing_deg=-84.0, **beside)
    assert paper.left_mm_s > paper.right_mm_s  # turning right, into the wall
    assert slid.reason == "driving" and slid.left_mm_s > 0 and slid.right_mm_s > 0
    assert abs(slid.left_mm_s - slid.right_mm_s) < 0.1 * (slid.left_mm_s + slid.right_mm_s)
    assert max(abs(slid.left_mm_s), abs(slid.right_mm_s)) <= SLIDE.v_max_mm_s


def test_no_d_term_kick_when_the_slide_takes_the_steer() -> None:
    """Bearing -84 after -60 into a wall: the wheels are those of the wall's direction
    alone, not a D term on the jump from the bearing to it."""
    beside = {"front_sonar": wall_ring(-1, 0.8), "rear_sonar": rear_ring(-1, 0.8)}
    still = step(params=SLIDE, bearing_deg=-84.0, prev_bearing_deg=-84.0, **beside)
    moved = step(params=SLIDE, bearing_deg=-84.0, prev_bearing_deg=-60.0, **beside)
    assert (moved.left_mm_s, moved.right_mm_s) == (still.left_mm_s, still.right_mm_s)


def test_on_by_default_off_at_zero_from_config() -> None:
    from relayd.config.model import Settings
    from relayd.config.params import control_params

    assert control_params(Settings()).wall_slide_m == 1.5
    assert ControlParams().wall_slide_m == 1.5
    off = control_params(Settings.model_validate({"control": {"wall_slide_m": 0}}))
    assert off.wall_slide_m == 0.0
