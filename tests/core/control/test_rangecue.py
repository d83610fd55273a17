"""The sonar floor on the leader's distance (relayd/core/control/rangecue.py) and its release of
"leader_near" in the controller (docs/CONTROL.md section 5.3).

The floor's promise is checked against the simulator's own sonar model (the exact
nearest surface in each beam, relayd.sim.geometry.cone_range): a body whose centre is in
the front fan is never nearer than the floor, whatever else stands around it.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.arcos.sonar import SONAR_POSES
from relayd.cli import main
from relayd.config.model import ConfigError, ControlSettings
from relayd.core.avoid.state import AvoidMode, AvoidState
from relayd.core.control.law import (
    ControlInputs,
    ControlMemory,
    ControlOutput,
    ControlParams,
    control_step,
)
from relayd.core.control.rangecue import (
    CORE_M,
    CREEP_MM_S,
    HALF_BEAM_DEG,
    MIN_HALF_DEG,
    NEAR_M,
    RELEASE_HYSTERESIS_M,
    centre_bound_m,
    cover_deg,
    fan_deg,
    far_by_sonar,
    known_front,
    leader_floor_m,
    release_speed_mm_s,
)
from relayd.core.scan.estimator import FRONT_RING, SONAR_MAX_RANGE_M, SonarReading, front_readings
from relayd.core.vocab import DriveState, Mode
from relayd.sim.geometry import cone_range

NO_ECHO = tuple(SonarReading(SONAR_POSES[i].heading_deg, None, index=i) for i in FRONT_RING)


def ring(**by_index: float | None) -> tuple[SonarReading, ...]:
    """The read front ring, no echo but where given (s2=3.0: sonar 2 echoes at 3 m)."""
    ranges = {int(k.lstrip("s")): v for k, v in by_index.items()}
    return tuple(
        SonarReading(SONAR_POSES[i].heading_deg, ranges.get(i), index=i) for i in FRONT_RING
    )


def world_ring(circles: list[tuple[float, float, float]]) -> tuple[SonarReading, ...]:
    """The front ring as the simulator measures it: discs (x, y, radius) in the robot frame."""
    out = []
    for i in FRONT_RING:
        p = SONAR_POSES[i]
        r = cone_range(
            p.x_mm / 1000.0,
            p.y_mm / 1000.0,
            p.heading_deg,
            HALF_BEAM_DEG,
            SONAR_MAX_RANGE_M,
            (),
            circles,
        )
        out.append(SonarReading(p.heading_deg, r, index=i))
    return tuple(out)


# --- the geometry the bound rests on -----------------------------------------------------------


def test_the_fan_is_the_front_ring_seen_whole_from_0_7_m() -> None:
    fan = fan_deg()
    assert len(fan) == 3  # the 50-75 degree gaps between the +-50 and +-90 sonars stay open
    (a, b), (c, d), (e, f) = fan
    assert (a, b) == pytest.approx((-90.34, -75.0), abs=0.01)
    assert (c, d) == pytest.approx((-54.74, 54.74), abs=0.01)
    assert (e, f) == pytest.approx((75.0, 90.34), abs=0.01)
    # Nearer, the 30 and 50 degree sonars leave a sliver at 35 degrees unseen: why 0.7 m.
    assert cover_deg(2, 0.6)[1] < cover_deg(1, 0.6)[0]


def test_every_front_transducer_looks_away_from_the_robot_centre() -> None:
    for i in FRONT_RING:
        p = SONAR_POSES[i]
        for off in (-HALF_BEAM_DEG, 0.0, HALF_BEAM_DEG):
            a = math.radians(p.heading_deg + off)
            assert p.x_mm * math.cos(a) + p.y_mm * math.sin(a) > 0


@given(index=st.sampled_from(FRONT_RING), share=st.floats(0.0, 1.0), dist=st.floats(NEAR_M, 50.0))
def test_a_bearing_in_a_sonars_cover_is_inside_its_beam_from_near_m_out(
    index: int, share: float, dist: float
) -> None:
    lo, hi = cover_deg(index)
    bearing = math.radians(lo + share * (hi - lo))
    p = SONAR_POSES[index]
    seen = math.degrees(
        math.atan2(
            dist * math.sin(bearing) - p.y_mm / 1000.0, dist * math.cos(bearing) - p.x_mm / 1000.0
        )
    )
    assert abs(seen - p.heading_deg) <= HALF_BEAM_DEG + 1e-6


@given(index=st.sampled_from(FRONT_RING), r=st.floats(0.1, 5.0))
def test_the_centre_bound_is_at_least_the_echo_plus_the_core(index: int, r: float) -> None:
    assert r + CORE_M <= centre_bound_m(index, r) <= r + CORE_M + 0.25


# --- the floor ----------------------------------------------------------------------------


@st.composite
def scenes(draw: st.DrawFn) -> tuple[float, float, float, list[tuple[float, float, float]]]:
    """A leader disc with its centre in the fan, at least 0.7 m out, and a few other discs."""
    span = draw(st.sampled_from(fan_deg()))
    bearing = draw(st.floats(*span))
    dist = draw(st.floats(NEAR_M, 7.0))
    radius = draw(st.floats(CORE_M, 0.4))
    others = draw(
        st.lists(
            st.tuples(st.floats(-6.0, 6.0), st.floats(-6.0, 6.0), st.floats(0.05, 0.5)), max_size=4
        )
    )
    others = [(x, y, rad) for x, y, rad in others if math.hypot(x, y) > rad + 0.35]
    return bearing, dist, radius, others


@given(scene=scenes(), estimate=st.floats(-34.0, 34.0), sd=st.floats(0.0, 10.0))
@settings(max_examples=300, deadline=None)
def test_a_leader_in_the_fan_is_never_nearer_than_the_floor(
    scene: tuple[float, float, float, list[tuple[float, float, float]]], estimate: float, sd: float
) -> None:
    bearing, dist, radius, others = scene
    b = math.radians(bearing)
    leader = (dist * math.cos(b), dist * math.sin(b), radius)
    floor = leader_floor_m(world_ring([leader, *others]), estimate, sd)
    assert floor is not None  # the estimate +- max(2 sd, 20) lies inside the fan
    assert floor <= dist + 1e-9
    # ... nor than any other body as thick whose centre is in the fan (a pole thinner than
    # 2 * CORE_M may be nearer than the floor by up to CORE_M: the floor is for bodies).
    for x, y, rad in others:
        d, a = math.hypot(x, y), math.degrees(math.atan2(y, x))
        if rad >= CORE_M and d >= NEAR_M and any(lo <= a <= hi for lo, hi in fan_deg()):
            assert floor <= d + 1e-9


def test_the_floor_in_numbers() -> None:
    # Nothing within 5 m anywhere in front: the floor is the ring's reach, plus the core.
    assert leader_floor_m(NO_ECHO, 0.0, 2.0) == pytest.approx(
        min(centre_bound_m(i, 5.0) for i in FRONT_RING)
    )
    # An echo anywhere on the ring counts, not only around the estimate.
    assert leader_floor_m(ring(s6=3.0), 0.0, 2.0) == pytest.approx(centre_bound_m(6, 3.0))
    assert leader_floor_m(ring(s3=4.0, s4=3.9), 5.0, 1.0) == pytest.approx(centre_bound_m(4, 3.9))
    # A P3-AT leader 4.5 m ahead, facing away: its back (0.31 m behind its centre) echoes in
    # the 10 degree sonars; the floor is within 0.25 m of the true gap.
    assert 4.25 < leader_floor_m(world_ring([(4.5, 0.0, 0.31)]), 0.0, 3.0) <= 4.5  # type: ignore[operator]


@pytest.mark.parametrize(
    ("bearing", "sd"),
    [
        (None, 2.0),
        (0.0, None),
        (math.nan, 2.0),
        (0.0, math.inf),
        (35.0, 1.0),  # 35 + 20 reaches past the fan's 54.7 degrees
        (0.0, 28.0),  # 2 sd = 56 degrees
        (0.0, 10.5),  # the filter is not sure enough
        (-60.0, 1.0),
        (82.0, 1.0),
        (180.0, 1.0),  # off the nose, in the 90 degree sonar's cover or behind
    ],
)
def test_no_floor_when_the_leader_may_be_outside_the_fan(
    bearing: float | None, sd: float | None
) -> None:
    assert leader_floor_m(NO_ECHO, bearing, sd) is None


@settings(max_examples=200, deadline=None)
@given(bearing=st.floats(-180.0, 180.0), sd=st.floats(0.0, 10.0))
def test_a_floor_only_for_bearings_within_about_35_degrees(bearing: float, sd: float) -> None:
    # The fan's 75-90 degree parts are narrower than the 40 degrees the margin needs.
    edge = fan_deg()[1][1] - MIN_HALF_DEG  # ~34.7
    if abs(bearing) > edge + 1e-9:
        assert leader_floor_m(NO_ECHO, bearing, sd) is None
    elif abs(bearing) < edge - 1e-9:  # sd <= 10: the margin is the 20 degrees
        assert leader_floor_m(NO_ECHO, bearing, sd) is not None
    assert 34.0 < edge < 35.0


def test_no_floor_until_every_front_sonar_has_been_read() -> None:
    ranges: list[int | None] = [None] * 16
    for i in range(7):
        ranges[i] = 5000
    assert len(known_front(ranges)) == 7
    assert leader_floor_m(known_front(ranges), 0.0, 1.0) is None
    ranges[7] = 2500
    front = known_front(ranges)
    assert [r.range_m for r in front] == [None] * 7 + [2.5]  # 5000 mm is no echo
    assert leader_floor_m(front, 0.0, 1.0) == pytest.approx(centre_bound_m(7, 2.5))
    # The estimator's front_readings says None for both "never read" and "no echo": not used here.
    assert leader_floor_m(front_readings([None] * 16), 0.0, 1.0) is not None


# --- the release --------------------------------------------------------------------------


def test_far_by_sonar_with_its_hysteresis() -> None:
    assert not far_by_sonar(9.0, 0.0, False, -28.0, -30.0)  # off
    assert not far_by_sonar(None, 3.5, True, -28.0, -30.0)
    assert not far_by_sonar(math.nan, 3.5, True, -28.0, -30.0)
    assert far_by_sonar(3.5, 3.5, False, -28.0, -30.0) and not far_by_sonar(
        3.49, 3.5, False, -28.0, -30.0
    )
    assert far_by_sonar(3.5 - RELEASE_HYSTERESIS_M, 3.5, True, -28.0, -30.0)
    assert not far_by_sonar(3.49 - RELEASE_HYSTERESIS_M, 3.5, True, -28.0, -30.0)
    # Too loud for a far leader (10 dB or more above threshold_l): never released.
    assert far_by_sonar(4.0, 3.5, True, -20.01, -30.0) and not far_by_sonar(
        4.0, 3.5, True, -20.0, -30.0
    )


@pytest.mark.parametrize(
    ("w1", "w2", "v_max", "speed"),
    [
        (10.0, 150.0, 400.0, 150.0),  # the paper's law at -30 dBm
        (10.0, 250.0, 400.0, CREEP_MM_S),  # a law that stops before threshold_l: creep
        (30.0, 0.0, 400.0, 400.0),  # never above v_max
        (10.0, 150.0, 30.0, 30.0),  # ... even below the creep
    ],
)
def test_the_release_speed_is_the_laws_at_threshold_l(
    w1: float, w2: float, v_max: float, speed: float
) -> None:
    assert release_speed_mm_s(-30.0, w1, w2, v_max) == pytest.approx(speed)


ON = ControlParams(leader_gap_max_m=3.5)
NEAR = -25.0  # RSSI^l above threshold_l (-30): the RSSI rule says "leader_near"


def inputs(**changes: object) -> ControlInputs:
    base = ControlInputs(
        mode=Mode.FOLLOW,
        sip_age_s=0.1,
        rssi_age_s=0.1,
        scan_servo_ok=True,
        bearing_deg=0.0,
        prev_bearing_deg=0.0,
        rssi_leader_dbm=NEAR,
        rssi_behind_dbm=-40.0,
        rear_age_s=0.5,
        front_sonar=front_readings([None] * 16),
        leader_lost=False,
        leader_floor_m=4.0,
    )
    return dataclasses.replace(base, **changes)  # type: ignore[arg-type]


def step(
    params: ControlParams = ON, memory: ControlMemory | None = None, **changes: object
) -> ControlOutput:
    return control_step(inputs(**changes), params, memory or ControlMemory(link_drive=True))


def test_released_only_while_the_floor_reaches_the_gap_limit() -> None:
    out = step(leader_floor_m=3.5)
    assert (out.state, out.reason) == (DriveState.DRIVING, "leader_far_sonar")
    assert out.left_mm_s == out.right_mm_s == pytest.approx(150.0)  # the paper's law at threshold_l
    assert out.memory.sonar_release and out.memory.link_drive
    for floor in (3.49, None):
        out = step(leader_floor_m=floor)
        assert (out.state, out.reason, out.left_mm_s) == (DriveState.STOPPED, "leader_near", 0.0)
        assert not out.memory.sonar_release


def test_released_with_hysteresis_and_the_rssi_rule_takes_over_below_threshold_l() -> None:
    floors = [3.6, 3.3, 3.21, 3.19, 3.3, 3.49, 3.5]
    memory, reasons = ControlMemory(), []
    for floor in floors:
        out = step(memory=memory, leader_floor_m=floor)
        memory = out.memory
        reasons.append(out.reason)
    assert reasons == ["leader_far_sonar"] * 3 + ["leader_near"] * 3 + ["leader_far_sonar"]
    # Released, then the leader fades below threshold_l: the paper's rule drives, no band needed.
    out = step(memory=memory, rssi_leader_dbm=-31.0, leader_floor_m=None)
    assert out.reason == "driving" and not out.memory.sonar_release


def test_a_leader_heard_far_above_threshold_l_is_never_released() -> None:
    """20 dB above threshold_l is a leader really close that the sonars miss, not a bright spot."""
    assert (
        step(rssi_leader_dbm=-28.0, leader_floor_m=4.0).reason == "leader_far_sonar"
    )  # 2 dB above
    out = step(rssi_leader_dbm=-10.0, leader_floor_m=4.0)  # 20 dB above
    assert (out.state, out.reason, out.left_mm_s) == (DriveState.STOPPED, "leader_near", 0.0)
    assert not out.memory.sonar_release
    # Released, then the leader gets that loud: the release ends.
    released = step(rssi_leader_dbm=-28.0, leader_floor_m=4.0).memory
    out = step(memory=released, rssi_leader_dbm=-15.0, leader_floor_m=4.0)
    assert out.reason == "leader_near" and not out.memory.sonar_release


@pytest.mark.parametrize("rear", [-60.0, -65.0])
def test_never_released_while_the_link_behind_is_weak(rear: float) -> None:
    out = step(rssi_behind_dbm=rear, leader_floor_m=5.0)
    assert (out.state, out.reason, out.left_mm_s) == (DriveState.STOPPED, "rear_weak", 0.0)
    # While stopped, the rear must clear its hysteresis band too (threshold_b + 2 dB).
    stopped = ControlMemory(link_drive=False)
    assert step(memory=stopped, rssi_behind_dbm=-59.0, leader_floor_m=5.0).reason == "rear_weak"
    assert (
        step(memory=stopped, rssi_behind_dbm=-57.0, leader_floor_m=5.0).reason == "leader_far_sonar"
    )


def test_the_obstacle_rule_and_the_fail_safes_still_apply_when_released() -> None:
    near = front_readings([None, None, None, 600, None, None, None, None] + [None] * 8)
    out = step(
        front_sonar=near, leader_floor_m=5.0
    )  # an inconsistent floor: the guard still sees 0.6 m
    assert out.reason == "obstacle" and out.memory.sonar_release
    assert step(rssi_age_s=None, leader_floor_m=5.0).reason == "rssi_stale"
    assert step(leader_lost=True, leader_floor_m=5.0).reason == "leader_lost"
    # A stop for any cause ends the release: it must be earned again at the full limit.
    stopped = step(memory=ControlMemory(link_drive=True, sonar_release=True), mode=Mode.HOLD)
    assert not stopped.memory.sonar_release


def test_the_escape_taking_over_ends_the_release() -> None:
    # Released, then the escape holds the robot ("blocked", the leader 60 deg off): the release
    # is over, as for any stop (docs/CONTROL.md 5.3).
    blocked = AvoidState(mode=AvoidMode.BLOCKED, escape_t=0.0, mode_t=0.0)
    memory = ControlMemory(link_drive=True, sonar_release=True, avoid=blocked)
    out = step(
        memory=memory,
        bearing_deg=60.0,
        prev_bearing_deg=60.0,
        leader_floor_m=4.0,
        t_s=1.0,
        odom=(0.0, 0.0, 0.0),
    )
    assert (out.state, out.reason, out.left_mm_s) == (DriveState.STOPPED, "blocked", 0.0)
    assert not out.memory.sonar_release


finite = st.floats(-100.0, 10.0, allow_nan=False)


def zero(out: ControlOutput) -> bool:
    return out.left_mm_s == 0.0 and out.right_mm_s == 0.0


@given(
    rssi_l=finite,
    rssi_b=finite,
    floor=st.one_of(st.none(), st.floats(0.0, 6.0)),
    link_drive=st.booleans(),
    released=st.booleans(),
    bearing=st.floats(-90.0, 90.0),
    s3=st.one_of(st.none(), st.integers(100, 5000)),
)
@settings(max_examples=300, deadline=None)
def test_off_is_the_paper_rule_and_on_never_drives_with_a_weak_rear(
    rssi_l: float,
    rssi_b: float,
    floor: float | None,
    link_drive: bool,
    released: bool,
    bearing: float,
    s3: int | None,
) -> None:
    memory = ControlMemory(link_drive=link_drive)
    sonar = front_readings([None, None, None, s3] + [None] * 12)
    ci = inputs(
        rssi_leader_dbm=rssi_l,
        rssi_behind_dbm=rssi_b,
        leader_floor_m=floor,
        bearing_deg=bearing,
        front_sonar=sonar,
    )
    off = control_step(ci, ControlParams(), memory)
    assert off == control_step(
        dataclasses.replace(ci, leader_floor_m=None), ControlParams(), memory
    )
    assert off.reason != "leader_far_sonar" and not off.memory.sonar_release
    on = control_step(ci, ON, dataclasses.replace(memory, sonar_release=released))
    if rssi_b <= ON.threshold_b_dbm:
        assert on.state is DriveState.STOPPED and on.left_mm_s == on.right_mm_s == 0.0
    if on.reason == "leader_far_sonar":
        assert floor is not None and floor >= ON.leader_gap_max_m - RELEASE_HYSTERESIS_M
        assert rssi_l >= ON.threshold_l_dbm - (0.0 if link_drive else ON.hysteresis_db)
    if on.reason != off.reason:  # the release is the only difference ...
        # ... or, where the sonars put the leader far, the weak rear is what holds the robot.
        assert on.memory.sonar_release or (on.reason, off.reason) == ("rear_weak", "leader_near")
        assert zero(on) == zero(off) or on.memory.sonar_release


# --- the setting --------------------------------------------------------------------------


@pytest.mark.parametrize("gap", [0.0, 3.5, 5.0, 1.11])
def test_leader_gap_max_accepted(gap: float) -> None:
    assert ControlSettings(leader_gap_max_m=gap).leader_gap_max_m == gap


@pytest.mark.parametrize("gap", [-1.0, 0.5, 0.8, 0.81, 1.0, 1.1, 5.01])
def test_leader_gap_max_refused_below_threshold_o_or_beyond_the_sonars(gap: float) -> None:
    # 0.81 .. 1.1: the release would hold down to gap - 0.3, within threshold_o (0.8 m) or
    # nearer than the 0.7 m from which the floor holds.
    with pytest.raises((ConfigError, ValueError), match="leader_gap_max_m"):
        ControlSettings(leader_gap_max_m=gap)


def test_the_release_may_never_hold_within_where_the_floor_holds() -> None:
    # threshold_o below NEAR_M: the floor's own limit (0.7 m) is the one that counts.
    base = {"stop_distance_m": 0.2, "threshold_o_m": 0.3}
    assert ControlSettings(**base, leader_gap_max_m=1.01).leader_gap_max_m == 1.01
    with pytest.raises((ConfigError, ValueError), match="leader_gap_max_m"):
        ControlSettings(**base, leader_gap_max_m=0.95)


def test_check_config_exits_2_naming_the_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "relayd.toml"
    bad.write_text('[control]\nrear_link = "ignore"\nleader_gap_max_m = 0.81\n')
    assert main(["check-config", str(bad)]) == 2
    assert "  control.leader_gap_max_m:" in capsys.readouterr().err
