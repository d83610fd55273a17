"""The door passage (relayd/core/avoid/door.py): what counts as a door, and a relay
through doors 0.8-1.0 m wide in the closed-loop model, with and without the passage."""

from __future__ import annotations

import dataclasses

import pytest

from relayd.core.avoid.door import door_gap, side_lateral_m
from relayd.core.avoid.escape import avoid_step
from relayd.core.avoid.ring import by_heading, path_blocked
from relayd.core.avoid.state import AvoidMode, AvoidParams, AvoidState
from relayd.core.control.actuator import Actuator
from relayd.core.control.law import ControlParams
from relayd.core.geometry import HALF_WIDTH_M
from relayd.sim.model import Step, run_model
from relayd.sim.scenario import Scenario, parse_scenario
from tests.core.avoid.test_escape import ring, sense

P = AvoidParams(door_pass=True)  # opt-in: the tests are of the passage
ACT = Actuator()


def jambs(lateral_m: float) -> list[int | None]:
    """The front ring in a door whose jambs are `lateral_m` each side of the centreline,
    level with the robot's 50 degree sonars (as at the moment it enters), the way on open."""
    # Sonar 1 (50 deg) sits 0.119 m off the centreline: on its axis a jamb at lateral L
    # reads (L - 0.119) / sin 50.
    mm = round((lateral_m - 0.119) / 0.766 * 1000)
    return ring(s1=mm, s6=mm)


def test_a_gap_the_robot_fits_is_a_door() -> None:
    gap = door_gap(by_heading(sense(0.0, jambs(0.4)).sonar), P)
    assert gap is not None and gap[0] == pytest.approx(0.4, abs=0.01)
    assert gap[1] == pytest.approx(0.4, abs=0.01)


def test_a_gap_without_the_margin_is_not() -> None:
    # 0.65 m: the 0.505 m robot with 0.145 m to spare, under door_margin_m (0.2).
    assert door_gap(by_heading(sense(0.0, jambs(0.325)).sonar), P) is None
    assert 2 * HALF_WIDTH_M + P.door_margin_m > 0.65


def test_one_side_or_a_shut_way_on_is_not_a_door() -> None:
    one_side = ring(s1=350)
    assert side_lateral_m(by_heading(sense(0.0, one_side).sonar), -1, P.door_side_m) is None
    assert door_gap(by_heading(sense(0.0, one_side).sonar), P) is None
    shut = jambs(0.4)
    shut[3] = shut[4] = 500  # something across the gap, 0.5 m ahead
    assert door_gap(by_heading(sense(0.0, shut).sonar), P) is None


def test_in_a_door_the_escape_drives_slowly_through_its_middle() -> None:
    # Jambs 0.45 m left and 0.35 m right: the middle is 0.05 m to the left.
    ranges = ring(s1=round((0.45 - 0.119) / 0.766 * 1000), s6=round((0.35 - 0.119) / 0.766 * 1000))
    st, cmd = avoid_step(AvoidState(), sense(0.0, ranges, bearing=10.0), P, ACT)
    assert st.mode is AvoidMode.DOOR and not cmd.follow
    assert cmd.vel_mm_s == P.door_speed_mm_s and cmd.rvel_deg_s == 5  # 100 deg/s/m * 0.05 m
    # The leader off to the side (beyond door_bearing_deg): not through this gap.
    st, cmd = avoid_step(AvoidState(), sense(0.0, ranges, bearing=60.0), P, ACT)
    assert st.mode is not AvoidMode.DOOR
    # Off by the config key.
    off = dataclasses.replace(P, door_pass=False)
    st, cmd = avoid_step(AvoidState(), sense(0.0, ranges, bearing=10.0), off, ACT)
    assert st.mode is AvoidMode.FOLLOW and cmd.follow


def test_the_passage_ends_once_the_sides_open() -> None:
    st, _ = avoid_step(AvoidState(), sense(0.0, jambs(0.4)), P, ACT)
    assert st.mode is AvoidMode.DOOR
    st, cmd = avoid_step(st, sense(0.1, ring(), pose=(300.0, 0.0, 0.0)), P, ACT)
    assert st.mode is AvoidMode.FOLLOW and cmd.follow and st.anchor == (300.0, 0.0)


def test_held_in_a_door_by_the_guard_the_escape_takes_over_after_the_watchdog() -> None:
    # A gap 0.88 m wide (left 90 degree sonar 0.11 m from a jamb, right one 0.5 m), the
    # way on open, but the left jamb inside the footprint's path: the guard holds the
    # robot. The passage must not hold it for ever: FOLLOW's progress watchdog fires.
    ranges = ring(s0=110, s1=500, s7=500)
    assert door_gap(by_heading(sense(0.0, ranges).sonar), P) is not None
    assert path_blocked(sense(0.0, ranges).sonar, P.stop_distance_m)
    st = AvoidState()
    modes = []
    for i in range(60):
        st, cmd = avoid_step(st, sense(i * 0.1, ranges), P, ACT)
        assert cmd.vel_mm_s <= 0, cmd  # never forward into the jamb
        modes.append(st.mode)
    first = next(i for i, m in enumerate(modes) if m not in (AvoidMode.FOLLOW, AvoidMode.DOOR))
    assert first * 0.1 == pytest.approx(P.no_progress_s, abs=0.15)


def door_world(width_m: float) -> Scenario:
    """A wall across the way at x = 3 m with a door `width_m` wide on the line to the
    leader, who stands 7 m beyond it."""
    half = width_m / 2.0
    return parse_scenario(
        {
            "name": "door",
            "environment": "outdoor",
            "relays": 1,
            "command_center": {"x": -1.5, "y": 0.0},
            "leader": {"waypoints": [{"x": 10.0, "y": 0.0}]},
            "relay": [{"name": "r", "x": 0.0, "y": 0.0}],
            "walls": [
                {"points": [[3.0, half], [3.0, 4.0]], "material": "light"},
                {"points": [[3.0, -half], [3.0, -4.0]], "material": "light"},
            ],
            "radio": {"shadow_sigma_db": 0.0, "fading": False},
        }
    )


def _never_toward_an_echo(step: Step) -> None:
    if step.vel_mm_s > 0:
        assert not path_blocked(step.inputs.front_sonar, ControlParams().stop_distance_m), step


@pytest.mark.parametrize("width_m", [0.8, 0.9, 1.0])
def test_a_relay_passes_a_narrow_door(width_m: float) -> None:
    out = run_model(
        door_world(width_m),
        seed=1,
        past_m=3.6,
        seconds=60.0,
        on_step=_never_toward_an_echo,
        params=ControlParams(rear_link_required=False, avoid=P),
    )
    assert out.passed_at_s is not None and out.collisions == 0, out
    # Through the middle: the centre no nearer a jamb than the half-width plus most of the spare.
    assert out.min_clearance_m >= (width_m - 2 * HALF_WIDTH_M) / 2 - 0.05, out


def test_without_the_passage_an_08_m_door_is_not_passed() -> None:
    params = ControlParams(rear_link_required=False, avoid=P)
    off = dataclasses.replace(params, avoid=dataclasses.replace(params.avoid, door_pass=False))
    out = run_model(door_world(0.8), seed=1, past_m=3.6, seconds=60.0, params=off)
    assert out.passed_at_s is None and out.collisions == 0, out
