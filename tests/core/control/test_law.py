"""Unit and property tests for relayd.core.control.law (docs/CONTROL.md sections 3-6)."""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import replace

import pytest
from hypothesis import given
from hypothesis import strategies as st

from relayd.core.control.actuator import Actuator
from relayd.core.control.law import (
    ControlInputs,
    ControlMemory,
    ControlOutput,
    ControlParams,
    background_speed,
    control_step,
    link_rule,
    speed_scale,
    wheel_law,
)
from relayd.core.scan.estimator import avoidance_bearing, front_readings
from relayd.core.vocab import DriveState, Mode

P = ControlParams()
DRIVING = ControlMemory(link_drive=True)


def wire(left: float, right: float) -> tuple[float, float]:
    """What the paper's wheel law becomes once VEL/RVEL (1 mm/s, 1 deg/s) carry it."""
    return Actuator().express_wheels(left, right, P.v_max_mm_s)


def sonar(**by_index: int | None) -> tuple:
    ranges: list[int | None] = [None] * 16
    for key, value in by_index.items():
        ranges[int(key.lstrip("s"))] = value
    return front_readings(ranges)


def healthy(**changes: object) -> ControlInputs:
    """Follow mode with every input fresh, leader far (-50 dBm), rear link good (-40 dBm)."""
    base = ControlInputs(
        mode=Mode.FOLLOW,
        sip_age_s=0.1,
        rssi_age_s=0.5,
        scan_servo_ok=True,
        bearing_deg=10.0,
        prev_bearing_deg=4.0,
        rssi_leader_dbm=-50.0,
        rssi_behind_dbm=-40.0,
        rear_age_s=1.0,
        front_sonar=sonar(),
        leader_lost=False,
    )
    return dataclasses.replace(base, **changes)  # type: ignore[arg-type]


def step(
    memory: ControlMemory = DRIVING, params: ControlParams = P, **changes: object
) -> ControlOutput:
    return control_step(healthy(**changes), params, memory)


def zero(out: ControlOutput) -> bool:
    return out.left_mm_s == 0.0 and out.right_mm_s == 0.0


# --- background speed and wheel law -----------------------------------------------------


@pytest.mark.parametrize(
    ("rssi", "speed"),
    [(-50.0, 350.0), (-30.0, 150.0), (-70.0, 400.0), (-10.0, 0.0), (-15.0, 0.0), (-55.0, 400.0)],
)
def test_background_speed_numbers(rssi: float, speed: float) -> None:
    assert background_speed(rssi, 10.0, 150.0, 400.0) == pytest.approx(speed)


@given(rssi=st.floats(-200.0, 50.0, allow_nan=False))
def test_background_speed_bounded_and_monotone(rssi: float) -> None:
    v = background_speed(rssi, 10.0, 150.0, 400.0)
    assert 0.0 <= v <= 400.0
    assert background_speed(rssi - 1.0, 10.0, 150.0, 400.0) >= v


def test_wheel_law_worked_numbers() -> None:
    assert wheel_law(200.0, 10.0, None, 1.0, 0.3, 400.0) == pytest.approx((190.0, 210.0))
    # D term: kd * (10 - 4) = 1.8 on top of kp * 10.
    assert wheel_law(200.0, 10.0, 4.0, 1.0, 0.3, 400.0) == pytest.approx((188.2, 211.8))
    assert wheel_law(0.0, -30.0, -30.0, 1.0, 0.3, 400.0) == pytest.approx((30.0, -30.0))
    # Clamped per wheel.
    assert wheel_law(390.0, 20.0, None, 1.0, 0.3, 400.0) == pytest.approx((370.0, 400.0))
    assert wheel_law(0.0, 90.0, -90.0, 10.0, 5.0, 400.0) == pytest.approx((-400.0, 400.0))


bearing_st = st.floats(-180.0, 180.0, allow_nan=False)


@given(v=st.floats(0.0, 400.0), b=bearing_st, bp=st.one_of(st.none(), bearing_st))
def test_wheel_law_turn_direction_symmetry_and_clamps(v: float, b: float, bp: float | None) -> None:
    left, right = wheel_law(v, b, bp, 1.0, 0.3, 400.0)
    assert -400.0 <= left <= 400.0 and -400.0 <= right <= 400.0
    mirror = wheel_law(v, -b, None if bp is None else -bp, 1.0, 0.3, 400.0)
    assert mirror == pytest.approx((right, left))
    if bp is None or bp == b:
        # Positive bearing (leader to the left) turns left, negative turns right.
        if b > 0:
            assert right >= left
        elif b < 0:
            assert left >= right
        if 1e-6 < abs(b) < 400.0 - v:
            assert right != left


# --- link rule with hysteresis ----------------------------------------------------------


@pytest.mark.parametrize(
    ("rssi_l", "rssi_b", "was_driving", "expected"),
    [
        (-30.0, -40.0, True, (False, "leader_near")),
        (-30.01, -40.0, True, (True, "driving")),
        (-31.0, -60.0, True, (False, "rear_weak")),
        (-31.0, -59.99, True, (True, "driving")),
        (-32.0, -40.0, False, (False, "leader_near")),
        (-31.0, -40.0, False, (False, "leader_near")),
        (-32.01, -40.0, False, (True, "driving")),
        (-50.0, -58.0, False, (False, "rear_weak")),
        (-50.0, -57.99, False, (True, "driving")),
        (-29.0, -70.0, True, (False, "leader_near")),
        (None, -40.0, True, (False, "no_scan_yet")),
        (-50.0, None, True, (False, "rear_link_stale")),
    ],
)
def test_link_rule_thresholds(
    rssi_l: float | None, rssi_b: float | None, was_driving: bool, expected: tuple[bool, str]
) -> None:
    assert link_rule(rssi_l, rssi_b, P, was_driving, True) == expected


def test_link_rule_ignores_the_rear_when_not_required() -> None:
    assert link_rule(-50.0, -90.0, P, True, False) == (True, "driving")
    assert link_rule(-50.0, None, P, False, False) == (True, "driving")
    assert link_rule(-30.0, None, P, True, False) == (False, "leader_near")


def run_latch(values: list[tuple[float, float]], hysteresis_db: float) -> list[bool]:
    params = dataclasses.replace(P, hysteresis_db=hysteresis_db)
    driving, out = True, []
    for rssi_l, rssi_b in values:
        driving, _ = link_rule(rssi_l, rssi_b, params, driving, True)
        out.append(driving)
    return out


def test_hysteresis_stops_chatter() -> None:
    wobble = [(-29.5, -40.0), (-30.5, -40.0)] * 5 + [(-50.0, -59.5), (-50.0, -60.5)] * 5
    without = run_latch(wobble, 0.0)
    with_band = run_latch(wobble, 2.0)
    assert sum(a != b for a, b in itertools.pairwise(without)) >= 10  # it would chatter
    assert with_band == [False] * len(wobble)  # stops once and stays stopped
    # And resumes once the values leave the band.
    assert run_latch([(-29.0, -40.0), (-31.0, -40.0), (-33.0, -40.0), (-31.0, -40.0)], 2.0) == [
        False,
        False,
        True,
        True,
    ]


@given(
    leader=st.lists(st.floats(-31.99, -30.01), min_size=1, max_size=30),
    behind=st.lists(st.floats(-59.99, -58.01), min_size=1, max_size=30),
    start=st.booleans(),
)
def test_inside_the_band_the_latch_never_changes(
    leader: list[float], behind: list[float], start: bool
) -> None:
    driving = start
    for rssi_l, rssi_b in zip(leader, behind, strict=False):
        driving, _ = link_rule(rssi_l, rssi_b, P, driving, True)
        assert driving == start


# --- fail-safes -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("changes", "reason"),
    [
        ({"sip_age_s": None}, "no_sip"),
        ({"sip_age_s": 0.51}, "no_sip"),
        ({"sip_age_s": math.nan}, "no_sip"),
        ({"rssi_age_s": None}, "rssi_stale"),
        ({"rssi_age_s": 5.01}, "rssi_stale"),
        ({"scan_servo_ok": False}, "scan_servo"),
        ({"rear_age_s": None}, "rear_link_stale"),
        ({"rear_age_s": 3.01}, "rear_link_stale"),
        ({"rssi_behind_dbm": None}, "rear_link_stale"),
        # No SIP comes first, before every other fault.
        (
            {"sip_age_s": None, "rssi_age_s": None, "scan_servo_ok": False, "rear_age_s": None},
            "no_sip",
        ),
        ({"rssi_age_s": None, "scan_servo_ok": False}, "rssi_stale"),
        # Faults beat leader lost and obstacles.
        ({"scan_servo_ok": False, "leader_lost": True, "front_sonar": sonar(s3=200)}, "scan_servo"),
    ],
)
def test_fail_safes_stop_the_wheels(changes: dict, reason: str) -> None:
    out = step(**changes)
    assert zero(out)
    assert out.state is DriveState.FAULT
    assert out.reason == reason


def test_fail_safe_boundaries_are_still_fresh() -> None:
    out = step(sip_age_s=P.sip_timeout_s, rssi_age_s=P.rssi_timeout_s, rear_age_s=P.rear_timeout_s)
    assert out.state is DriveState.DRIVING


def test_fail_safes_keep_the_link_latch() -> None:
    assert step(memory=DRIVING, sip_age_s=None).memory.link_drive is True
    assert step(memory=ControlMemory(), rssi_age_s=None).memory.link_drive is False


def test_resumes_by_itself_when_data_is_fresh_again() -> None:
    faulted = step(sip_age_s=2.0)
    assert faulted.state is DriveState.FAULT
    assert step(memory=faulted.memory).state is DriveState.DRIVING


def test_rear_link_ignored_when_not_required() -> None:
    params = dataclasses.replace(P, rear_link_required=False)
    out = step(params=params, rear_age_s=None, rssi_behind_dbm=None)
    assert out.state is DriveState.DRIVING
    out = step(params=params, rssi_behind_dbm=-90.0)
    assert out.state is DriveState.DRIVING


# --- modes ------------------------------------------------------------------------------


def test_hold_mode_holds() -> None:
    out = step(mode=Mode.HOLD)
    assert zero(out) and out.state is DriveState.STOPPED and out.reason == "hold"
    # Hold does not need the follow-mode inputs, only the SIP.
    out = step(mode=Mode.HOLD, rssi_age_s=None, scan_servo_ok=False, rear_age_s=None)
    assert out.reason == "hold"
    assert step(mode=Mode.HOLD, sip_age_s=None).reason == "no_sip"


def manual(**changes: object) -> ControlOutput:
    base: dict[str, object] = {
        "mode": Mode.MANUAL,
        "manual_left_mm_s": 100.0,
        "manual_right_mm_s": 150.0,
        "manual_age_s": 0.2,
        "rssi_age_s": None,
        "scan_servo_ok": False,
        "rear_age_s": None,
    }
    base.update(changes)
    return control_step(healthy(**base), P, DRIVING)


def test_manual_drives_the_command() -> None:
    out = manual()
    assert (out.left_mm_s, out.right_mm_s) == (100.0, 150.0)
    assert out.state is DriveState.DRIVING and out.reason == "manual"
    assert manual(manual_age_s=0.5).reason == "manual"  # the dead-man time itself is fine
    clamped = manual(manual_left_mm_s=-900.0, manual_right_mm_s=1e9)
    assert (clamped.left_mm_s, clamped.right_mm_s) == (-400.0, 400.0)
    still = manual(manual_left_mm_s=0.0, manual_right_mm_s=0.0)
    assert zero(still) and still.state is DriveState.STOPPED


@pytest.mark.parametrize(
    "changes",
    [
        {"manual_age_s": 0.51},
        {"manual_age_s": None},
        {"manual_left_mm_s": None, "manual_right_mm_s": None},
        {"manual_right_mm_s": math.nan},
    ],
)
def test_manual_dead_man(changes: dict) -> None:
    out = manual(**changes)
    assert zero(out) and out.state is DriveState.STOPPED and out.reason == "deadman"


def test_manual_dead_man_expires_over_time() -> None:
    reasons = [manual(manual_age_s=age).reason for age in (0.0, 0.3, 0.5, 0.6, 5.0)]
    assert reasons == ["manual", "manual", "manual", "deadman", "deadman"]


def test_manual_still_faults_without_sip() -> None:
    out = manual(sip_age_s=None)
    assert zero(out) and out.state is DriveState.FAULT and out.reason == "no_sip"


def test_manual_guard_drops_only_the_forward_part_near_an_obstacle() -> None:
    out = manual(front_sonar=sonar(s3=250))
    assert out.reason == "obstacle"
    assert (out.left_mm_s, out.right_mm_s) == (-25.0, 25.0)  # the turn survives
    back = manual(manual_left_mm_s=-100.0, manual_right_mm_s=-100.0, front_sonar=sonar(s3=250))
    assert (back.left_mm_s, back.right_mm_s) == (-100.0, -100.0) and back.reason == "manual"
    side = manual(front_sonar=sonar(s0=100))  # a wall alongside does not block
    assert (side.left_mm_s, side.right_mm_s) == (100.0, 150.0)


# --- follow -----------------------------------------------------------------------------


def test_follow_drives_with_the_wheel_law() -> None:
    out = step()
    assert out.state is DriveState.DRIVING and out.reason == "driving" and out.situation == 0
    # v = 350 (-50 dBm), B = 10, B' = 4 -> turn = 10 + 0.3 * 6 = 11.8.
    assert (out.left_mm_s, out.right_mm_s) == pytest.approx(wire(338.2, 361.8))
    assert out.memory == ControlMemory(link_drive=True, prev_steer_deg=None)
    right = step(bearing_deg=-20.0, prev_bearing_deg=None)
    assert (right.left_mm_s, right.right_mm_s) == pytest.approx(wire(370.0, 330.0))


def test_follow_leader_lost_and_no_scan_yet() -> None:
    out = step(leader_lost=True)
    assert zero(out) and out.state is DriveState.LEADER_LOST and out.reason == "leader_lost"
    for inputs in (
        healthy(bearing_deg=None, prev_bearing_deg=None),
        healthy(rssi_leader_dbm=None),
        healthy(bearing_deg=math.nan),
        healthy(rssi_leader_dbm=math.inf),
    ):
        out = control_step(inputs, P, DRIVING)
        assert zero(out) and out.state is DriveState.STOPPED and out.reason == "no_scan_yet"


def test_broken_previous_bearing_only_drops_the_d_term() -> None:
    out = step(prev_bearing_deg=math.nan)
    assert (out.left_mm_s, out.right_mm_s) == pytest.approx(wire(340.0, 360.0))


def test_follow_stop_rule_and_latch_through_control_step() -> None:
    near = step(rssi_leader_dbm=-30.0)
    assert zero(near) and near.state is DriveState.STOPPED and near.reason == "leader_near"
    assert near.memory.link_drive is False
    weak = step(rssi_behind_dbm=-60.0)
    assert zero(weak) and weak.reason == "rear_weak"
    # Stopped at -31 dBm: inside the band, stays stopped; -33 resumes.
    held = step(memory=near.memory, rssi_leader_dbm=-31.0)
    assert held.reason == "leader_near"
    resumed = step(memory=held.memory, rssi_leader_dbm=-33.0)
    assert resumed.state is DriveState.DRIVING and resumed.memory.link_drive is True
    # A fresh controller (latch False) starts only outside the band.
    assert step(memory=ControlMemory(), rssi_leader_dbm=-31.0).reason == "leader_near"


def test_stop_rule_beats_obstacle_avoidance() -> None:
    out = step(rssi_leader_dbm=-25.0, front_sonar=sonar(s3=500))
    assert zero(out) and out.reason == "leader_near" and out.situation == 1


def test_situation_one_speed_scaling() -> None:
    # Obstacle straight ahead-left at 0.55 m; the rest open. v = 350 at -50 dBm.
    out = step(front_sonar=sonar(s3=550), prev_bearing_deg=None)
    assert out.state is DriveState.AVOIDING and out.reason == "obstacle" and out.situation == 1
    assert (out.left_mm_s + out.right_mm_s) / 2 == pytest.approx(175.0)  # half speed
    steer = avoidance_bearing(sonar(s3=550), 1.0)
    assert steer < 0  # obstacle on the left (+10): steer right
    # A turn of 2 * steer mm/s is below half an RVEL step: a deliberate 0 on the wire.
    assert (out.left_mm_s, out.right_mm_s) == pytest.approx(wire(175.0 - steer, 175.0 + steer))
    assert out.memory.prev_steer_deg == pytest.approx(steer)
    assert out.left_mm_s >= out.right_mm_s


@pytest.mark.parametrize(
    ("d_mm", "fraction"), [(800, 1.0), (700, 0.8), (550, 0.5), (400, 0.2), (300, 0.0)]
)
def test_speed_scale_numbers(d_mm: int, fraction: float) -> None:
    assert speed_scale(d_mm / 1000, 0.8, 0.3) == pytest.approx(fraction)


@given(d=st.floats(0.0, 5.0))
def test_speed_scale_bounded(d: float) -> None:
    assert 0.0 <= speed_scale(d, 0.8, 0.3) <= 1.0


@pytest.mark.parametrize("d_mm", [200, 50])
def test_an_echo_inside_the_corners_sweep_stops_the_turn_too(d_mm: int) -> None:
    # This close to the 30 degree sonar the echo may lie inside the circle the corners
    # sweep (plus the turn margin): a turn in place would swing the body into it, so the
    # guard holds the wheels (the escape backs off first when it may).
    out = step(front_sonar=sonar(s2=d_mm), prev_bearing_deg=None)
    assert zero(out)


@pytest.mark.parametrize("d_mm", [299, 260])
def test_situation_one_only_turns_below_the_stop_distance(d_mm: int) -> None:
    out = step(front_sonar=sonar(s2=d_mm), prev_bearing_deg=None)
    assert out.state is DriveState.AVOIDING
    assert out.left_mm_s + out.right_mm_s == pytest.approx(0.0)  # no forward speed
    assert out.left_mm_s > 0 > out.right_mm_s  # turning right, away from the obstacle on the left


def test_avoidance_steers_away_from_the_near_side() -> None:
    left = step(front_sonar=sonar(s1=500, s2=600))
    right = step(front_sonar=sonar(s5=600, s6=500))
    assert left.left_mm_s > left.right_mm_s
    assert right.right_mm_s > right.left_mm_s


def test_avoidance_d_term_uses_the_previous_steering_angle() -> None:
    first = step(front_sonar=sonar(s3=500))
    second = step(memory=first.memory, front_sonar=sonar(s3=500, s4=600))
    steer1 = first.memory.prev_steer_deg
    steer2 = second.memory.prev_steer_deg
    assert steer1 is not None and steer2 is not None
    turn = 1.0 * steer2 + 0.3 * (steer2 - steer1)
    v = (second.left_mm_s + second.right_mm_s) / 2
    assert (second.left_mm_s, second.right_mm_s) == pytest.approx(wire(v - turn, v + turn), abs=0.6)
    # Leaving situation 1 clears the memory so a stale angle never kicks the D term.
    assert step(memory=second.memory).memory.prev_steer_deg is None


def test_situation_two_drives_on_the_scan_bearing() -> None:
    out = step(front_sonar=sonar(s2=1500))
    assert out.state is DriveState.DRIVING and out.situation == 2
    assert (out.left_mm_s, out.right_mm_s) == pytest.approx(wire(338.2, 361.8))


def test_side_wall_in_a_corridor_does_not_slow_the_robot() -> None:
    walls = sonar(s0=400, s7=400)
    paper = replace(P, wall_slide_m=0.0)
    out = step(params=paper, front_sonar=walls)
    assert out.state is DriveState.DRIVING and out.situation == 0
    assert (out.left_mm_s, out.right_mm_s) == pytest.approx(wire(338.2, 361.8))
    # As shipped, the bearing's few degrees into the left wall slide along it (section
    # 7.4): straight on, at the same speed.
    slid = step(front_sonar=walls)
    assert slid.state is DriveState.DRIVING and slid.situation == 0
    assert slid.left_mm_s == slid.right_mm_s == pytest.approx(sum(wire(338.2, 361.8)) / 2, abs=1)


inputs_st = st.builds(
    ControlInputs,
    mode=st.sampled_from(list(Mode)),
    sip_age_s=st.one_of(st.none(), st.floats(0.0, 2.0)),
    rssi_age_s=st.one_of(st.none(), st.floats(0.0, 10.0)),
    scan_servo_ok=st.booleans(),
    bearing_deg=st.one_of(st.none(), st.floats(-180.0, 180.0)),
    prev_bearing_deg=st.one_of(st.none(), st.floats(-180.0, 180.0)),
    rssi_leader_dbm=st.one_of(st.none(), st.floats(-100.0, -10.0)),
    rssi_behind_dbm=st.one_of(st.none(), st.floats(-100.0, -10.0)),
    rear_age_s=st.one_of(st.none(), st.floats(0.0, 10.0)),
    front_sonar=st.lists(st.one_of(st.none(), st.integers(0, 6000)), min_size=16, max_size=16).map(
        front_readings
    ),
    leader_lost=st.booleans(),
    manual_left_mm_s=st.one_of(st.none(), st.floats(-1000.0, 1000.0)),
    manual_right_mm_s=st.one_of(st.none(), st.floats(-1000.0, 1000.0)),
    manual_age_s=st.one_of(st.none(), st.floats(0.0, 2.0)),
)


@given(
    inputs=inputs_st,
    link_drive=st.booleans(),
    prev_steer=st.one_of(st.none(), st.floats(-90.0, 90.0)),
)
def test_control_step_invariants(
    inputs: ControlInputs, link_drive: bool, prev_steer: float | None
) -> None:
    memory = ControlMemory(link_drive=link_drive, prev_steer_deg=prev_steer)
    out = control_step(inputs, P, memory)
    assert abs(out.left_mm_s) <= P.v_max_mm_s and abs(out.right_mm_s) <= P.v_max_mm_s
    assert out.situation in (0, 1, 2)
    moving = not zero(out)
    if out.state in (DriveState.FAULT, DriveState.LEADER_LOST) or out.reason in ("hold", "deadman"):
        assert not moving
    if inputs.sip_age_s is None or inputs.sip_age_s > P.sip_timeout_s:
        assert out.reason == "no_sip" and not moving
    if moving and inputs.mode is Mode.FOLLOW:
        assert out.state in (DriveState.DRIVING, DriveState.AVOIDING)
        assert out.memory.link_drive is True
    if inputs.mode is not Mode.FOLLOW or out.state is DriveState.FAULT:
        assert out.memory.link_drive == link_drive  # the latch moves only through the link rule
