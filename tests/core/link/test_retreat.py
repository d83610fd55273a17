"""Stepping back out of a shadow (relayd/core/link/retreat.py): when it starts, how far it goes,
that it never drives in doubt or into an echo; unit tests and hypothesis properties."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from relayd.api.reasons import phrasebook
from relayd.core.control.law import ControlInputs, ControlMemory, ControlOutput, ControlParams
from relayd.core.link.retreat import (
    BELOW_POLLS,
    EDGE_DROP_DB,
    EDGE_M,
    HOLD_MARGIN_DB,
    MAX_RETREAT_M,
    REACH_M,
    RetreatMemory,
    held_limit,
    is_edge,
    record_poll,
    retreat_step,
    retreat_target,
)
from relayd.core.recovery.trail import REAR_SONARS, TrailPoint
from relayd.core.vocab import DriveState, Mode
from tests.support import diff_drive

P = ControlParams(threshold_b_dbm=-72.0)
OPEN: tuple[int | None, ...] = (5000,) * 16
STOP_REAR = ControlOutput(0.0, 0.0, DriveState.STOPPED, "rear_weak", 1, ControlMemory())
DRIVING = ControlOutput(200.0, 200.0, DriveState.DRIVING, "driving", 1, ControlMemory())


def ci(
    pose: tuple[float, float, float] | None = (0.0, 0.0, 0.0), t: float = 0.0, **kw: object
) -> ControlInputs:
    base: dict[str, object] = dict(
        mode=Mode.FOLLOW,
        sip_age_s=0.05,
        rssi_age_s=0.05,
        scan_servo_ok=True,
        bearing_deg=0.0,
        prev_bearing_deg=0.0,
        rssi_leader_dbm=-50.0,
        rssi_behind_dbm=-80.0,
        rear_age_s=0.5,
        front_sonar=(),
        leader_lost=False,
        t_s=t,
        odom=pose,
    )
    base.update(kw)
    return ControlInputs(**base)  # type: ignore[arg-type]


#: A miss 6 dB below the polls that met the target: a gradual edge, no sudden shadow.
GRADUAL_DBM = -72.0


def walked_into_shadow(
    edge_mm: float = 2000.0, past_mm: float = 100.0, miss_dbm: float = GRADUAL_DBM
) -> tuple[RetreatMemory, float]:
    """A relay that drove along +x meeting the target at -66 dBm at every poll (one each
    200 mm) up to edge_mm, then one poll past_mm beyond it that missed at miss_dbm: the
    controller stops it there, at its rear limit. Returns (memory, x)."""
    m = RetreatMemory()
    x = 0.0
    while x <= edge_mm:
        _, m = retreat_step(ci((x, 0.0, 0.0)), OPEN, DRIVING, P, m, enabled=True)
        if int(x) % 200 == 0:
            m = record_poll(m, (x, 0.0, 0.0), -66.0, True)
        x += 50.0
    x = edge_mm + past_mm
    _, m = retreat_step(ci((x, 0.0, 0.0)), OPEN, DRIVING, P, m, enabled=True)
    m = record_poll(m, (x, 0.0, 0.0), miss_dbm, False)
    return m, x


def run_move(
    m: RetreatMemory, x: float, dt: float = 0.1
) -> tuple[ControlOutput, RetreatMemory, float]:
    """Let a started move run to its end (exact kinematics); returns the last output and where it stopped."""
    pose = (x, 0.0, 0.0)
    out = STOP_REAR
    for _ in range(400):
        out, m = retreat_step(ci(pose), OPEN, STOP_REAR, P, m, enabled=True)
        if m.target is None:
            break
        pose = diff_drive(pose, out.left_mm_s, out.right_mm_s, dt)
    return out, m, pose[0]


def stand_below(m: RetreatMemory, x: float, polls: int) -> tuple[ControlOutput, RetreatMemory]:
    """Standing at x, the controller at its rear limit, `polls` polls that miss the target."""
    out = STOP_REAR
    for _ in range(polls):
        out, m = retreat_step(ci((x, 0.0, 0.0)), OPEN, STOP_REAR, P, m, enabled=True)
        m = record_poll(m, (x, 0.0, 0.0), -80.0, False)
    out, m = retreat_step(ci((x, 0.0, 0.0)), OPEN, STOP_REAR, P, m, enabled=True)
    return out, m


def test_every_retreat_reason_has_a_phrase() -> None:
    assert {
        "retreat",
        "retreat_hold",
        "retreat_stale_input",
        "rear_obstacle",
        "rear_blocked",
    } <= set(phrasebook())


def test_it_steps_back_after_enough_polls_below_target_standing_and_holds_with_a_floor() -> None:
    m, x = walked_into_shadow()
    out, m = stand_below(m, x, BELOW_POLLS - 1)
    assert out is STOP_REAR and m.target is None  # one poll short: the controller's stop stands
    out, m = stand_below(m, x, 1)
    assert out.left_mm_s < 0 and out.right_mm_s < 0 and out.reason == "retreat"
    assert out.state is DriveState.RECOVERING and m.target is not None
    out, m, stop_x = run_move(m, x)
    pose = (stop_x, 0.0, 0.0)
    assert out.reason == "retreat_hold" and out.left_mm_s == out.right_mm_s == 0.0
    # At the poll before the newest one that met the target (its value may be a poll period old).
    assert abs(stop_x - 1800.0) < REACH_M * 1000.0 + 20.0
    assert m.floor_dbm == -66.0 + HOLD_MARGIN_DB
    assert held_limit(P, m, -55.0).threshold_b_dbm == -66.0 + HOLD_MARGIN_DB
    assert held_limit(P, m, -70.0).threshold_b_dbm == -70.0  # never above the tightest bound
    # Holding: the controller, with the floor, keeps it standing; no new move.
    out, m = retreat_step(ci(pose), OPEN, STOP_REAR, P, m, enabled=True)
    assert out is STOP_REAR


def test_polls_below_target_while_driving_do_not_count() -> None:
    m, x = walked_into_shadow()
    for _ in range(BELOW_POLLS + 2):
        _, m = retreat_step(ci((x, 0.0, 0.0)), OPEN, DRIVING, P, m, enabled=True)
        m = record_poll(m, (x, 0.0, 0.0), -80.0, False)
    assert m.below == 0
    out, m = retreat_step(ci((x, 0.0, 0.0)), OPEN, STOP_REAR, P, m, enabled=True)
    assert out is STOP_REAR


def test_a_poll_that_meets_the_target_resets_the_run() -> None:
    m, x = walked_into_shadow()
    _, m = stand_below(m, x, BELOW_POLLS - 1)
    m = record_poll(m, (x, 0.0, 0.0), -70.0, True)
    out, m = stand_below(m, x, BELOW_POLLS - 1)
    assert out is STOP_REAR and m.target is None


def test_disabled_or_other_stop_reasons_never_move() -> None:
    m, x = walked_into_shadow()
    _, m_on = stand_below(m, x, BELOW_POLLS - 1)
    m_on = record_poll(m_on, (x, 0.0, 0.0), -80.0, False)
    out, _ = retreat_step(ci((x, 0.0, 0.0)), OPEN, STOP_REAR, P, m_on, enabled=False)
    assert out is STOP_REAR  # fixed policy: the controller alone
    near = ControlOutput(0.0, 0.0, DriveState.STOPPED, "leader_near", 1, ControlMemory())
    out, _ = retreat_step(ci((x, 0.0, 0.0)), OPEN, near, P, m_on, enabled=True)
    assert out is near


def test_a_shadow_edge_steps_back_at_once() -> None:
    """A poll 14 dB below the one before it, 0.1 m further on: no standing through polls below."""
    m, x = walked_into_shadow(miss_dbm=-80.0)
    assert m.edge and m.below == 0
    out, m = retreat_step(ci((x, 0.0, 0.0)), OPEN, STOP_REAR, P, m, enabled=True)
    assert out.left_mm_s < 0 and out.right_mm_s < 0 and out.reason == "retreat"
    assert not m.edge  # a move consumes it
    out, m, stop_x = run_move(m, x)
    assert out.reason == "retreat_hold" and abs(stop_x - 1800.0) < REACH_M * 1000.0 + 20.0
    assert m.floor_dbm == -66.0 + HOLD_MARGIN_DB


def test_an_edge_waits_for_the_controller_to_stop_it() -> None:
    """The edge poll still above the limit (the controller drives on): the edge does not move it,
    and the next poll clears it."""
    m, x = walked_into_shadow(miss_dbm=-80.0)
    out, m = retreat_step(ci((x, 0.0, 0.0)), OPEN, DRIVING, P, m, enabled=True)
    assert out is DRIVING and m.target is None
    m = record_poll(m, (x + 200.0, 0.0, 0.0), -66.0, True)
    assert not m.edge
    near = ControlOutput(0.0, 0.0, DriveState.STOPPED, "leader_near", 1, ControlMemory())
    m2, _ = walked_into_shadow(miss_dbm=-80.0)
    out, m2 = retreat_step(ci((x, 0.0, 0.0)), OPEN, near, P, m2, enabled=True)
    assert out is near and m2.target is None  # standing for another reason: never back


@pytest.mark.parametrize(
    ("drop_db", "moved_mm", "edge"),
    [
        (EDGE_DROP_DB, 100.0, True),
        (EDGE_DROP_DB - 0.5, 100.0, False),  # within what two fading readings differ by
        (EDGE_DROP_DB + 6.0, 5.0, False),  # standing: the drop came to it (something between)
        (EDGE_DROP_DB + 6.0, EDGE_M * 1000.0 + 50.0, False),  # too far driven to be one edge
    ],
)
def test_what_counts_as_an_edge(drop_db: float, moved_mm: float, edge: bool) -> None:
    trail = (TrailPoint(0.0, 0.0, rssi_b_dbm=-66.0, met=True), TrailPoint(50.0, 0.0))
    assert is_edge(trail, TrailPoint(moved_mm, 0.0, rssi_b_dbm=-66.0 - drop_db, met=False)) is edge
    # The poll before must have met the target.
    missed = (TrailPoint(0.0, 0.0, rssi_b_dbm=-66.0, met=False),)
    assert not is_edge(missed, TrailPoint(moved_mm, 0.0, rssi_b_dbm=-66.0 - drop_db, met=False))


def test_retreat_target_prefers_the_poll_before_the_newest_that_met() -> None:
    trail = (
        TrailPoint(0.0, 0.0, rssi_b_dbm=-65.0, met=True),
        TrailPoint(100.0, 0.0),
        TrailPoint(200.0, 0.0, rssi_b_dbm=-66.0, met=True),
        TrailPoint(300.0, 0.0),
        TrailPoint(400.0, 0.0, rssi_b_dbm=-80.0, met=False),
    )
    assert retreat_target(trail, 400.0, 0.0, MAX_RETREAT_M) == 0
    # The poll before the newest that met missed: the newest that met it is the goal.
    trail2 = (TrailPoint(0.0, 0.0, rssi_b_dbm=-80.0, met=False), *trail[1:])
    assert retreat_target(trail2, 400.0, 0.0, MAX_RETREAT_M) == 2
    # The older one beyond the budget: the newest that met it.
    assert retreat_target(trail, 400.0, 0.0, 0.3) == 2
    assert retreat_target(trail, 400.0, 0.0, 0.1) is None


def test_no_spot_within_the_bound_means_it_stays() -> None:
    m, x = walked_into_shadow(edge_mm=2000.0, past_mm=MAX_RETREAT_M * 1000.0 + 300.0)
    out, m = stand_below(m, x, BELOW_POLLS)
    assert out is STOP_REAR and m.last_outcome == "no_spot"


def test_retreat_target_counts_path_not_straight_line() -> None:
    # A U-shaped trail: the met spot is 0.5 m away in a straight line but 4.5 m of path.
    trail = (
        TrailPoint(0.0, 500.0, rssi_b_dbm=-60.0, met=True),
        TrailPoint(2000.0, 500.0),
        TrailPoint(2000.0, 0.0),
        TrailPoint(0.0, 0.0, rssi_b_dbm=-80.0, met=False),
    )
    assert retreat_target(trail, 0.0, 0.0, MAX_RETREAT_M) is None
    assert retreat_target(trail, 0.0, 0.0, 5.0) == 0


@settings(max_examples=80, deadline=None)
@given(
    which=st.sampled_from(REAR_SONARS),
    range_mm=st.integers(1, int(P.stop_distance_m * 1000)),
    others=st.lists(st.integers(1, 5000), min_size=16, max_size=16),
    edge=st.booleans(),
    steps=st.integers(0, 6),
)
def test_never_reverses_toward_an_echo_inside_stop_distance(
    which: int, range_mm: int, others: list[int], edge: bool, steps: int
) -> None:
    """Whatever started the move and wherever it is, an echo behind within stop_distance means
    no backward wheel speed on that step."""
    m, x = walked_into_shadow(miss_dbm=-80.0 if edge else GRADUAL_DBM)
    if not edge:
        _, m = stand_below(m, x, BELOW_POLLS - 1)
        m = record_poll(m, (x, 0.0, 0.0), -80.0, False)
    pose = (x, 0.0, 0.0)
    for _ in range(steps):
        out, m = retreat_step(ci(pose), OPEN, STOP_REAR, P, m, enabled=True)
        pose = diff_drive(pose, out.left_mm_s, out.right_mm_s, 0.1)
    sonar = list(others)
    sonar[which] = range_mm
    out, m = retreat_step(ci(pose), tuple(sonar), STOP_REAR, P, m, enabled=True)
    assert out.left_mm_s == 0.0 and out.right_mm_s == 0.0


def test_a_rear_sonar_never_read_stops_a_move() -> None:
    m, x = walked_into_shadow(miss_dbm=-80.0)
    blind: list[int | None] = list(OPEN)
    blind[REAR_SONARS[0]] = None
    out, m = retreat_step(ci((x, 0.0, 0.0)), tuple(blind), STOP_REAR, P, m, enabled=True)
    assert out.left_mm_s == out.right_mm_s == 0.0 and out.reason == "rear_blocked"


def test_an_echo_right_behind_stops_it() -> None:
    m, x = walked_into_shadow()
    _, m = stand_below(m, x, BELOW_POLLS - 1)
    m = record_poll(m, (x, 0.0, 0.0), -80.0, False)
    blocked = list(OPEN)
    blocked[11] = 200  # rear sonar, inside stop_distance
    out, m = retreat_step(ci((x, 0.0, 0.0)), tuple(blocked), STOP_REAR, P, m, enabled=True)
    assert out.left_mm_s == out.right_mm_s == 0.0 and out.reason == "rear_blocked"


def test_leaving_follow_mode_aborts_with_zero_wheels() -> None:
    m, x = walked_into_shadow()
    _, m = stand_below(m, x, BELOW_POLLS)
    assert m.target is not None
    out, m = retreat_step(ci((x, 0.0, 0.0), mode=Mode.MANUAL), OPEN, STOP_REAR, P, m, enabled=True)
    assert (
        out.left_mm_s == out.right_mm_s == 0.0 and m.target is None and m.last_outcome == "aborted"
    )


STALE = st.sampled_from(["sip", "rssi", "rear", "rear_none", "pose", "nan_age"])


@settings(max_examples=60, deadline=None)
@given(which=STALE, steps=st.integers(0, 5))
def test_any_doubt_during_a_move_means_zero_wheels(which: str, steps: int) -> None:
    m, x = walked_into_shadow()
    _, m = stand_below(m, x, BELOW_POLLS)
    pose = (x, 0.0, 0.0)
    for _ in range(steps):
        out, m = retreat_step(ci(pose), OPEN, STOP_REAR, P, m, enabled=True)
        pose = diff_drive(pose, out.left_mm_s, out.right_mm_s, 0.1)
    table: dict[str, dict[str, object]] = {
        "sip": {"sip_age_s": 5.0},
        "rssi": {"rssi_age_s": 5.0},
        "rear": {"rear_age_s": 10.0},
        "rear_none": {"rssi_behind_dbm": None},
        "pose": {"odom": None},
        "nan_age": {"sip_age_s": math.nan},
    }
    args = dict(table[which])
    odom = args.pop("odom", pose)
    out, m = retreat_step(ci(odom, **args), OPEN, STOP_REAR, P, m, enabled=True)  # type: ignore[arg-type]
    assert out.left_mm_s == 0.0 and out.right_mm_s == 0.0
    assert m.target is None


@settings(max_examples=60, deadline=None)
@given(which=STALE, edge=st.booleans())
def test_stale_input_never_starts_a_move(which: str, edge: bool) -> None:
    m, x = walked_into_shadow(miss_dbm=-80.0 if edge else GRADUAL_DBM)
    if not edge:
        _, m = stand_below(m, x, BELOW_POLLS - 1)
        m = record_poll(m, (x, 0.0, 0.0), -80.0, False)
    table: dict[str, dict[str, object]] = {
        "sip": {"sip_age_s": 5.0},
        "rssi": {"rssi_age_s": 5.0},
        "rear": {"rear_age_s": 10.0},
        "rear_none": {"rssi_behind_dbm": None},
        "pose": {"odom": None},
        "nan_age": {"sip_age_s": math.nan},
    }
    args = dict(table[which])
    odom = args.pop("odom", (x, 0.0, 0.0))
    out, m = retreat_step(ci(odom, **args), OPEN, STOP_REAR, P, m, enabled=True)  # type: ignore[arg-type]
    assert out is STOP_REAR and m.target is None


@settings(max_examples=60, deadline=None)
@given(
    edge_m=st.floats(0.5, 6.0),
    past_m=st.floats(0.05, 4.0),
    dt=st.floats(0.05, 1.0),
    rounds=st.integers(1, 10),
    spacing_mm=st.floats(50.0, 1500.0),
    drop_db=st.floats(0.0, 30.0),
)
def test_reverse_travel_never_exceeds_the_bound(
    edge_m: float, past_m: float, dt: float, rounds: int, spacing_mm: float, drop_db: float
) -> None:
    """Over repeated triggers in one place (an edge or polls below, drops of any size), with
    any control period, the path reversed stays within MAX_RETREAT_M (the speed is tapered
    to what is left)."""
    m = RetreatMemory()
    x = 0.0
    while x <= edge_m * 1000.0:
        _, m = retreat_step(ci((x, 0.0, 0.0)), OPEN, DRIVING, P, m, enabled=True)
        m = record_poll(m, (x, 0.0, 0.0), -66.0, True)
        x += spacing_mm
    pose = (edge_m * 1000.0 + past_m * 1000.0, 0.0, 0.0)
    reversed_m = 0.0
    for _ in range(rounds):
        # Each round: it stands where it is, the hop below target; then any move runs out.
        for _ in range(BELOW_POLLS):
            _, m = retreat_step(ci(pose), OPEN, STOP_REAR, P, m, enabled=True)
            m = record_poll(m, pose, -66.0 - drop_db, False)
        for _ in range(400):
            out, m = retreat_step(ci(pose), OPEN, STOP_REAR, P, m, enabled=True)
            assert out.left_mm_s <= 0.0 and out.right_mm_s <= 0.0  # only ever backwards
            new = diff_drive(pose, out.left_mm_s, out.right_mm_s, dt)
            reversed_m += math.dist(new[:2], pose[:2]) / 1000.0
            pose = new
            if m.target is None:
                break
    assert reversed_m <= MAX_RETREAT_M + 0.05


def test_the_hold_and_budget_clear_once_it_drove_away() -> None:
    m = replace(RetreatMemory(), floor_dbm=-63.0, anchor=(0.0, 0.0), spent_m=2.0)
    _, m = retreat_step(ci((1000.0, 0.0, 0.0)), OPEN, DRIVING, P, m, enabled=True)
    assert m.floor_dbm == -63.0
    _, m = retreat_step(ci((3500.0, 0.0, 0.0)), OPEN, DRIVING, P, m, enabled=True)
    assert m.floor_dbm is None and m.spent_m == 0.0
    assert held_limit(P, m, -55.0) is P


def test_a_controller_fault_passes_through() -> None:
    m, x = walked_into_shadow()
    _, m = stand_below(m, x, BELOW_POLLS - 1)
    fault = ControlOutput(0.0, 0.0, DriveState.FAULT, "no_sip", 1, ControlMemory())
    out, m = retreat_step(ci((x, 0.0, 0.0)), OPEN, fault, P, m, enabled=True)
    assert out is fault and m.target is None


@settings(max_examples=40, deadline=None)
@given(left_m=st.floats(0.03, 1.0), dt=st.floats(0.05, 1.0))
def test_a_move_that_runs_longer_than_planned_stops_at_the_bound(left_m: float, dt: float) -> None:
    """Wheel slip or a detour round an echo can make the path longer than the trail said:
    the move still ends within MAX_RETREAT_M with any control period up to TAPER_S."""
    trail = (
        TrailPoint(0.0, 0.0, rssi_b_dbm=-66.0, met=True),
        TrailPoint(5000.0, 0.0, rssi_b_dbm=-80.0, met=False),
    )
    m = RetreatMemory(trail=trail, target=0, started_t=0.0, spent_m=MAX_RETREAT_M - left_m)
    pose = (5000.0, 0.0, 0.0)
    m = replace(m, last_pose=pose[:2])
    moved_m = 0.0
    for k in range(1000):
        out, m = retreat_step(ci(pose, t=k * dt), OPEN, STOP_REAR, P, m, enabled=True)
        new = diff_drive(pose, out.left_mm_s, out.right_mm_s, dt)
        moved_m += math.dist(new[:2], pose[:2]) / 1000.0
        pose = new
        if m.target is None:
            break
    assert m.target is None and m.last_outcome in ("gave_up_distance", "gave_up_time")
    assert moved_m <= left_m + 0.03
