"""The escape when forward motion is blocked (relayd/core/avoid/escape.py) and the actuator's
resolution: unit tests at the boundaries, and property tests over the pure closed-loop
model (relayd/sim/model.py) with the truthful simulated sonar."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from drivers.arcos.sip import wheel_to_vel_rvel
from relayd.core.avoid.escape import avoid_step
from relayd.core.avoid.ring import choose_side, guard, path_blocked, rear_min_m, rear_readings
from relayd.core.avoid.state import AvoidMode, AvoidParams, AvoidState, Sense
from relayd.core.control.actuator import Actuator
from relayd.core.control.law import ControlInputs, ControlMemory, ControlParams, control_step
from relayd.core.scan.estimator import front_readings
from relayd.core.vocab import DriveState, Mode
from relayd.sim.model import Step, run_model
from relayd.sim.scenario import Scenario, load_scenario, parse_scenario

ACT = Actuator()
P = AvoidParams()


def ring(**by_index: int | None) -> list[int | None]:
    ranges: list[int | None] = [5000] * 16
    for key, value in by_index.items():
        ranges[int(key.lstrip("s"))] = value
    return ranges


def sense(
    t: float,
    ranges: list[int | None],
    bearing: float = 0.0,
    pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> Sense:
    return Sense(t, pose, front_readings(ranges), bearing, rear_readings(ranges))


# --- the actuator's resolution ----------------------------------------------------------


def test_the_issues_wheels_are_a_deliberate_zero_not_an_accident() -> None:
    # +-2.4 mm/s of wheel difference is 0.47 deg/s: half a step short of RVEL 1.
    assert ACT.express(*ACT.vel_rvel(2.4, -2.4)) == (0, 0)
    assert wheel_to_vel_rvel(*ACT.express_wheels(2.4, -2.4)) == (0, 0)


@pytest.mark.parametrize(
    ("rvel", "expected"), [(0.49, 0), (0.51, 1), (-0.51, -1), (1.49, 1), (1.51, 2)]
)
def test_express_rounds_at_half_a_step(rvel: float, expected: int) -> None:
    assert ACT.express(0.0, rvel) == (0, expected)


@pytest.mark.parametrize(
    ("asked", "sent"),
    [(0.1, 8), (-0.1, -8), (7.2, 8), (8.0, 8), (12.4, 13), (-20.0, -20), (400.0, 300)],
)
def test_a_turn_is_always_one_the_robot_executes(asked: float, sent: int) -> None:
    assert ACT.turn(asked) == sent
    # ... and the driver puts exactly that on the wire.
    assert wheel_to_vel_rvel(*ACT.wheels(0, ACT.turn(asked)))[1] == sent


def test_a_zero_turn_stays_zero() -> None:
    assert ACT.turn(0.0) == 0


@given(left=st.floats(-600, 600), right=st.floats(-600, 600))
def test_expressed_wheels_are_what_the_driver_sends(left: float, right: float) -> None:
    vel, rvel = ACT.express(*ACT.vel_rvel(left, right))
    vel, rvel = ACT.within(vel, rvel, 400.0)
    l2, r2 = ACT.wheels(vel, rvel)
    assert max(abs(l2), abs(r2)) <= 400.0 + 1e-6
    assert wheel_to_vel_rvel(l2, r2) == (vel, rvel)


def test_the_controller_only_commands_what_the_wire_can_say() -> None:
    base = ControlInputs(
        mode=Mode.FOLLOW,
        sip_age_s=0.1,
        rssi_age_s=0.5,
        scan_servo_ok=True,
        bearing_deg=0.3,
        prev_bearing_deg=0.3,
        rssi_leader_dbm=-50.0,
        rssi_behind_dbm=-40.0,
        rear_age_s=1.0,
        front_sonar=front_readings(ring()),
        leader_lost=False,
    )
    out = control_step(base, ControlParams(), ControlMemory(link_drive=True))
    vel, rvel = wheel_to_vel_rvel(out.left_mm_s, out.right_mm_s)
    assert rvel == 0  # kp * 0.3 = 0.3 mm/s per wheel: a deliberate zero
    assert ACT.wheels(vel, rvel) == pytest.approx((out.left_mm_s, out.right_mm_s))


# --- side choice and the guard ------------------------------------------------------------


def test_the_freer_side_wins() -> None:
    assert choose_side(front_readings(ring(s1=500, s2=600)), 30.0, P.tie_m) == -1
    assert choose_side(front_readings(ring(s5=600, s6=500)), -30.0, P.tie_m) == 1


@pytest.mark.parametrize(
    ("bearing", "side"), [(-2.0, -1), (2.0, 1), (0.0, 1), (-0.0, 1), (-1e-9, -1)]
)
def test_a_tie_goes_to_the_leaders_side_deterministically(bearing: float, side: int) -> None:
    symmetric = front_readings(ring(s3=300, s4=300))
    assert choose_side(symmetric, bearing, P.tie_m) == side


def test_guard_never_drives_toward_a_near_echo() -> None:
    near_ahead = front_readings(ring(s3=250))
    assert guard(100, 0, near_ahead, 0.3, rear_readings(ring())) == (0, 0)
    # An echo 0.28 m off the 50 degree sonar is beside the path, not in it.
    beside = front_readings(ring(s6=280))
    assert guard(100, 0, beside, 0.3, rear_readings(ring())) == (100, 0)
    # No reversing blind or into something behind.
    assert guard(-100, 0, front_readings(ring()), 0.3, ()) == (0, 0)
    assert guard(-100, 0, front_readings(ring()), 0.3, rear_readings(ring(s11=200))) == (0, 0)
    assert guard(-100, 0, front_readings(ring()), 0.3, rear_readings(ring())) == (-100, 0)
    # No turn in place toward a side that is too close, nor with anything in the sweep.
    assert guard(0, 20, front_readings(ring(s0=200)), 0.3, rear_readings(ring())) == (0, 0)
    assert guard(0, -20, front_readings(ring(s0=200)), 0.3, rear_readings(ring())) == (0, 0)
    assert guard(0, -20, front_readings(ring(s0=600)), 0.3, rear_readings(ring())) == (0, -20)


def test_rear_unknown_means_no_room_behind() -> None:
    assert rear_min_m(()) == 0.0
    assert rear_min_m(rear_readings(ring(s10=700))) == pytest.approx(0.7)


# --- the state machine, step by step --------------------------------------------------------


def run_steps(
    ranges: list[int | None], bearing: float, seconds: float, st: AvoidState | None = None
) -> list[tuple[AvoidState, int, int, str]]:
    """The robot stands still (the pose never changes) with these sonars: what happens."""
    st = st or AvoidState()
    out = []
    for i in range(round(seconds / 0.1)):
        st, cmd = avoid_step(st, sense(i * 0.1, ranges, bearing), P, ACT)
        out.append((st, cmd.vel_mm_s, cmd.rvel_deg_s, "follow" if cmd.follow else cmd.reason))
    return out


def test_box_dead_ahead_at_the_stop_distance_backs_off_on_the_leaders_side() -> None:
    # A box dead ahead on the way to the leader (the symmetric case that would hold the
    # paper's centroid steering at 0): sonars 3 and 4 at 300 mm, bearing -2, all else clear.
    # Below the back-off trigger with room behind, it first backs off, then turns right.
    # Closer than the back-off trigger with room behind: it backs off first (room to turn
    # and to go round), the side already latched toward the leader (right).
    steps = run_steps(ring(s3=290, s4=290), -2.0, 1.0)
    assert steps[0][0].side == -1 and steps[0][0].mode is AvoidMode.BACKOFF
    assert all(v < 0 and w == 0 for _, v, w, _ in steps)


def test_stuck_short_of_the_stop_distance_escapes_after_the_progress_watchdog() -> None:
    # The offset box: sonars read just above the stop distance, the robot never moves.
    steps = run_steps(ring(s2=340, s3=320, s4=330), 0.3, 6.0)
    kinds = [k for *_, k in steps]
    first = kinds.index("avoiding")
    assert first * 0.1 == pytest.approx(P.no_progress_s, abs=0.15)  # not before, not much after
    moving = [(v, w) for _, v, w, k in steps[first:] if k == "avoiding"]
    assert all(v != 0 or abs(w) >= ACT.min_turn_deg_s for v, w in moving)  # never a dead turn
    sides = {s.side for s, *_ in steps[first:]}
    assert len(sides) == 1  # latched: no dithering


def test_limits_end_in_blocked_with_wheels_at_zero() -> None:
    # A robot boxed in on every side (turning has no room, nothing behind is free).
    closed = ring(**{f"s{i}": 250 for i in range(16)})
    steps = run_steps(closed, 0.0, P.max_escape_s + 5.0)
    assert all(v == 0 and w == 0 for _, v, w, _ in steps)
    assert steps[-1][0].mode is AvoidMode.BLOCKED and steps[-1][3] == "blocked"


def test_blocked_ends_when_the_way_to_the_leader_opens() -> None:
    st = dataclasses.replace(AvoidState(), mode=AvoidMode.BLOCKED, escape_t=0.0)
    st, cmd = avoid_step(st, sense(1.0, ring(s3=250), 0.0), P, ACT)
    assert not cmd.follow and cmd.reason == "blocked"
    st, cmd = avoid_step(st, sense(2.0, ring(), 0.0), P, ACT)  # the person walked away
    assert cmd.follow and st.mode is AvoidMode.FOLLOW


def test_a_turn_onto_the_leader_jammed_in_a_doorway_backs_out_and_turns_toward_it() -> None:
    # The real-daemon doorway run: ALIGN has turned the robot into a 1 m door, the leader
    # 7 degrees to the right, and the right jamb (sonar 7 at 0.35 m) inside the circle
    # the corners sweep, so the turn is refused. The way ahead through the door is open.
    # It used to end the back-off at once (nothing ahead within backoff_to_m) and hand
    # it to a lane change on the latched side (left, away from the leader), which drove
    # it into the door's far side and held it there "blocked". It must back out the
    # unjam distance, then take up ALIGN again, never turning away from the leader.
    # (The sonars as the run saw them: the left door frame abeam, the right jamb; then,
    # backed out of the door, the jamb falls behind the right-hand sonar's beam.)
    first = ring(s0=1350, s7=350, **{f"s{i}": 1026 for i in range(8, 16)})
    in_door = ring(s0=900, s7=350, **{f"s{i}": 1201 for i in range(8, 16)})
    out_of_it = ring(s0=900, s7=700, **{f"s{i}": 1201 for i in range(8, 16)})
    st = AvoidState(
        mode=AvoidMode.ALIGN, side=1, escape_t=0.0, goal_deg=-3.0, last_pose=(2717.0, 952.0, 6.3)
    )
    x, heading = 2717.0, 6.3
    modes = []
    for i in range(40):
        ranges = first if i == 0 else in_door if 2717.0 - x < 200.0 else out_of_it
        st, cmd = avoid_step(st, sense(50.0 + i * 0.1, ranges, -7.1, (x, 952.0, heading)), P, ACT)
        modes.append(st.mode)
        assert cmd.rvel_deg_s <= 0, (i, st.mode, cmd)  # never away from the leader
        assert not cmd.follow
        if st.mode is not AvoidMode.BACKOFF:
            break
        assert cmd.vel_mm_s < 0 and cmd.reason == "rejoining"
        x += cmd.vel_mm_s * 0.1 * math.cos(math.radians(heading))
    assert modes[0] is AvoidMode.BACKOFF
    assert 2717.0 - x >= P.unjam_m * 1000.0 - 1.0  # backed out the whole unjam distance
    assert modes[-1] is AvoidMode.ALIGN and cmd.rvel_deg_s < 0  # turning onto the leader


def test_a_leader_behind_round_a_corner_is_turned_onto_not_escaped_from() -> None:
    # The corridor's corner 2 (seed 2, three relays): relay1 overran the corner and stands
    # 0.31 m from the end wall, its leader at -96 deg (behind-right, round the corner).
    # The freer side by the front sonars is the left, away from the leader; the escape used
    # to latch it and follow the wall 12 m back down the corridor. The leader is not
    # beyond the wall: the escape turns right, onto it, and never drives away.
    at_wall = ring(
        s0=1030,
        s1=640,
        s2=410,
        s3=330,
        s4=310,
        s5=310,
        s6=350,
        s7=710,
        **{f"s{i}": 1500 for i in range(8, 16)},
    )
    st = AvoidState(anchor=(17699.0, 20952.0), anchor_t=0.0)
    modes = []
    for i in range(10):
        st, cmd = avoid_step(
            st,
            sense(P.no_progress_s + 0.1 * (i + 1), at_wall, -96.4, (17699.0, 20952.0, 107.0)),
            P,
            ACT,
        )
        modes.append(st.mode)
        assert not cmd.follow and cmd.vel_mm_s <= 0 and cmd.rvel_deg_s <= 0, (i, st, cmd)
    assert modes[0] in (AvoidMode.ALIGN, AvoidMode.BACKOFF) and st.side in (0, -1)
    assert any(m is AvoidMode.ALIGN for m in modes)


def corner_world() -> Scenario:
    """Corner 2 of the corridor: corridor B (x 18.5-21.5) north into C (y 18.5-21.5) east;
    the relay has overrun the corner, facing the end wall, its leader 6 m down C."""
    return parse_scenario(
        {
            "name": "corner",
            "environment": "indoor",
            "relays": 1,
            "command_center": {"x": 20.0, "y": 0.0},
            "leader": {"waypoints": [{"x": 26.0, "y": 20.0}]},
            "relay": [{"name": "r", "x": 19.7, "y": 20.87, "theta_deg": 102.0}],
            "walls": [
                {"points": [[18.5, 10.0], [18.5, 21.5], [30.0, 21.5]], "material": "brick"},
                {"points": [[21.5, 10.0], [21.5, 18.5], [30.0, 18.5]], "material": "brick"},
            ],
            "radio": {"shadow_sigma_db": 0.0, "fading": False},
        }
    )


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_relay_that_overran_a_corner_turns_round_it_toward_its_leader(seed: int) -> None:
    # Closed loop over the same corner: the leader at -119 deg, beyond the servo's range.
    # It used to drive 9 m back down corridor B (the escape round the end wall, on its
    # freer side); it must turn toward the leader, go round the corner and never get
    # further from the leader than where it stood.
    sc = corner_world()
    leader, start = (26.0, 20.0), (19.7, 20.87)
    d0 = math.dist(leader, start)
    further = [0.0]

    def watch(step: Step) -> None:
        check_step(step, ControlParams().stop_distance_m)
        assert step.inputs.odom is not None
        x, y, _ = step.inputs.odom
        further[0] = max(further[0], math.dist(leader, (x / 1000.0, y / 1000.0)) - d0)

    # 2.5 m along the line to the leader is round the corner; with the slide along a wall
    # (control.wall_slide_m) the relay stops there on leader_near, 3.1 m from it.
    out = run_model(sc, seed=seed, past_m=2.5, seconds=90.0, on_step=watch)
    assert out.passed_at_s is not None and out.collisions == 0 and out.min_clearance_m >= 0.1, out
    assert further[0] < 0.3


def test_an_escape_never_takes_the_robot_beyond_max_stray_m_of_where_it_took_over() -> None:
    # Boundary following along a long wall on the right, the leader beyond it (its
    # direction not open: the Bug's leave condition does not end the escape).
    wall = ring(s6=600, s7=550, **{f"s{i}": 1500 for i in range(8, 16)})
    st = AvoidState(mode=AvoidMode.WALL, side=1, escape_t=0.0, hit_at=(0.0, 0.0), had_wall=True)
    x = 5800.0
    st, cmd = avoid_step(st, sense(10.0, wall, -60.0, (x, 0.0, 0.0)), P, ACT)
    assert st.mode is AvoidMode.WALL and cmd.vel_mm_s > 0  # within the bound: on it goes
    st, cmd = avoid_step(
        st, sense(10.1, wall, -60.0, (P.max_stray_m * 1000.0 + 10.0, 0.0, 0.0)), P, ACT
    )
    assert st.mode is AvoidMode.BLOCKED and (cmd.vel_mm_s, cmd.rvel_deg_s, cmd.reason) == (
        0,
        0,
        "blocked",
    )


modes_st = st.sampled_from([m for m in AvoidMode if m not in (AvoidMode.FOLLOW, AvoidMode.BLOCKED)])


@given(
    mode=modes_st,
    side=st.sampled_from([-1, 1]),
    bearing=st.floats(-180.0, 180.0),
    heading=st.floats(-180.0, 180.0),
    angle=st.floats(-math.pi, math.pi),
    beyond_m=st.floats(0.001, 50.0),
    ranges=st.lists(st.integers(100, 5000), min_size=16, max_size=16),
)
def test_beyond_max_stray_m_an_escape_holds_whatever_it_sees(
    mode: AvoidMode,
    side: int,
    bearing: float,
    heading: float,
    angle: float,
    beyond_m: float,
    ranges: list[int],
) -> None:
    hit = (1000.0, -2000.0)
    r_mm = (P.max_stray_m + beyond_m) * 1000.0
    pose = (hit[0] + r_mm * math.cos(angle), hit[1] + r_mm * math.sin(angle), heading)
    st0 = AvoidState(
        mode=mode,
        side=side,
        escape_t=0.0,
        hit_at=hit,
        last_pose=pose,
        backoff_from=pose[:2],
        lane_ref=pose,
        corner_heading_deg=heading,
    )
    new, cmd = avoid_step(st0, sense(1.0, list(ranges), bearing, pose), P, ACT)
    assert new.mode is AvoidMode.BLOCKED
    assert (cmd.follow, cmd.vel_mm_s, cmd.rvel_deg_s, cmd.reason) == (False, 0, 0, "blocked")


def test_the_state_machine_is_pure() -> None:
    s = sense(3.0, ring(s3=320, s4=320), -2.0)
    a = avoid_step(AvoidState(anchor=(0.0, 0.0), anchor_t=-5.0), s, P, ACT)
    b = avoid_step(AvoidState(anchor=(0.0, 0.0), anchor_t=-5.0), s, P, ACT)
    assert a == b


def test_the_controller_reports_the_escape() -> None:
    inputs = ControlInputs(
        mode=Mode.FOLLOW,
        sip_age_s=0.1,
        rssi_age_s=0.5,
        scan_servo_ok=True,
        bearing_deg=-2.0,
        prev_bearing_deg=-2.0,
        rssi_leader_dbm=-50.0,
        rssi_behind_dbm=-40.0,
        rear_age_s=1.0,
        front_sonar=front_readings(ring(s3=320, s4=320)),
        leader_lost=False,
        t_s=0.0,
        odom=(0.0, 0.0, 0.0),
        rear_sonar=rear_readings(ring()),
    )
    memory = ControlMemory(link_drive=True)
    reasons = []
    for i in range(60):
        out = control_step(dataclasses.replace(inputs, t_s=i * 0.1), ControlParams(), memory)
        memory = out.memory
        reasons.append(out.reason)
        vel, rvel = wheel_to_vel_rvel(out.left_mm_s, out.right_mm_s)
        if out.reason == "avoiding":
            assert out.state is DriveState.AVOIDING and (
                vel != 0 or abs(rvel) >= ACT.min_turn_deg_s
            )
    assert "obstacle" in reasons and "avoiding" in reasons  # the paper's law first, then the escape
    # Anything that stops the robot resets the escape.
    held = control_step(dataclasses.replace(inputs, mode=Mode.HOLD), ControlParams(), memory)
    assert held.memory.avoid == AvoidState()


# --- property tests over the closed-loop model ------------------------------------------------


def box_world(width_m: float, x_m: float, y_m: float) -> Scenario:
    return parse_scenario(
        {
            "name": "box",
            "environment": "outdoor",
            "relays": 1,
            "command_center": {"x": -1.5, "y": 0.0},
            "leader": {"waypoints": [{"x": 10.0, "y": 0.0}]},
            "relay": [{"name": "r", "x": 0.0, "y": 0.0}],
            "boxes": [
                {
                    "min": [x_m - width_m / 2, y_m - width_m / 2],
                    "max": [x_m + width_m / 2, y_m + width_m / 2],
                }
            ],
            # A steady radio: the link rule must keep saying "the leader is beyond", or a
            # shadowing peak can stop the relay legitimately before it meets the box.
            "radio": {"shadow_sigma_db": 0.0, "fading": False},
        }
    )


def check_step(step: Step, stop_m: float) -> None:
    """Never a command toward a sonar reading below the stop distance."""
    front, rear = step.inputs.front_sonar, step.inputs.rear_sonar
    if step.vel_mm_s > 0:
        assert not path_blocked(front, stop_m), step
    if step.vel_mm_s < 0:
        assert rear_min_m(rear) >= stop_m, step
    if step.vel_mm_s == 0 and step.rvel_deg_s != 0:
        side = 1 if step.rvel_deg_s > 0 else -1
        near = [
            r.range_m
            for r in front
            if r.range_m is not None and r.heading_deg in (side * 90.0, side * 50.0)
        ]
        assert min(near, default=5.0) >= stop_m, step
    if step.out.reason == "avoiding":
        assert step.vel_mm_s != 0 or step.rvel_deg_s != 0


# Each example is a whole closed-loop run (about 0.2 s): no shrinking or tracing phases.
@pytest.mark.timeout(300)
@settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
    phases=(Phase.explicit, Phase.reuse, Phase.generate),
)
@given(
    width=st.floats(0.1, 1.0),
    x=st.floats(1.5, 4.0),
    y=st.floats(-1.0, 1.0),
    seed=st.integers(0, 1000),
)
def test_a_single_box_near_the_line_is_passed_in_bounded_time(
    width: float, x: float, y: float, seed: int
) -> None:
    stop_m = ControlParams().stop_distance_m
    out = run_model(
        box_world(width, x, y),
        seed=seed,
        past_m=x + width / 2,
        seconds=150.0,
        on_step=lambda s: check_step(s, stop_m),
    )
    assert out.collisions == 0
    assert out.min_clearance_m >= 0.1
    assert out.passed_at_s is not None, out


def test_without_the_escape_the_papers_law_deadlocks_on_the_box() -> None:
    scenario = load_scenario("box-dead-ahead")
    before = run_model(
        scenario, seed=1, past_m=2.75, seconds=90.0, escape=False, bearing_noise_deg=0.0
    )
    assert before.passed_at_s is None and before.final_reason == "obstacle"
    assert 2.25 - before.x_m - 0.313 == pytest.approx(
        0.24, abs=0.03
    )  # nose ~0.24 m short of the face
    after = run_model(scenario, seed=1, past_m=2.75, seconds=90.0, bearing_noise_deg=0.0)
    assert after.passed_at_s is not None and after.collisions == 0


@pytest.mark.parametrize(
    ("name", "past_m"),
    [
        ("box-dead-ahead", 2.75),
        ("box-dead-ahead-offset", 2.75),
        ("u-trap", 3.5),
        ("doorway", 3.0),
        ("person-in-corridor", 2.75),
    ],
)
def test_shipped_obstacle_scenarios_are_passed(name: str, past_m: float) -> None:
    out = run_model(load_scenario(name), seed=1, past_m=past_m, seconds=300.0)
    assert out.passed_at_s is not None and out.collisions == 0 and out.min_clearance_m >= 0.1, out
    assert math.isfinite(out.passed_at_s)
