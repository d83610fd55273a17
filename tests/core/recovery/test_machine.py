"""The recovery state machine (relayd/core/recovery/machine.py) and its breadcrumbs (relayd/core/recovery/trail.py):
unit tests and hypothesis properties."""

from __future__ import annotations

import math
from dataclasses import replace

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from relayd.api.reasons import phrasebook
from relayd.core.control.law import ControlParams
from relayd.core.recovery.machine import recovery_step
from relayd.core.recovery.state import (
    REAR_LOST_POLLS,
    REASONS,
    Kind,
    Phase,
    RecoveryInputs,
    RecoveryMemory,
    RecoveryParams,
    inputs_stale,
)
from relayd.core.recovery.trail import TrailPoint, add_crumb, leader_target
from relayd.core.recovery.view import recovery_view
from relayd.core.vocab import DriveState
from tests.support import diff_drive

P = RecoveryParams(
    enabled=True,
    control=ControlParams(rssi_timeout_s=0.5, rear_timeout_s=3.0),
    scan_timeout_s=7.0,
)
OPEN = (5000,) * 16


def inputs(**kw: object) -> RecoveryInputs:
    base: dict[str, object] = dict(
        following=True,
        pose=(0.0, 0.0, 0.0),
        sip_age_s=0.05,
        rssi_age_s=0.05,
        scan_age_s=1.0,
        rear_age_s=0.5,
        leader_lost=False,
        rssi_leader_dbm=-50.0,
        rssi_behind_dbm=-55.0,
        scan_count=0,
        sonar_mm=OPEN,
        now_s=0.0,
    )
    base.update(kw)
    return RecoveryInputs(**base)  # type: ignore[arg-type]


def straight_trail(n: int, step_mm: float = 250.0) -> tuple[TrailPoint, ...]:
    """Crumbs along +x from 0, the newest last; the leader fainter at each (a relay falling behind)."""
    return tuple(TrailPoint(i * step_mm, 0.0, -35.0 - i, -55.0) for i in range(n))


def test_every_recovery_reason_has_a_phrase() -> None:
    book = phrasebook()
    assert REASONS | {"recovery_error"} <= set(book), sorted(REASONS - set(book))


# -- breadcrumbs -----------------------------------------------------------------------


def test_crumbs_follow_the_spacing_and_the_trail_is_bounded() -> None:
    trail: tuple[TrailPoint, ...] = ()
    for x in range(0, 3000, 50):
        trail = add_crumb(trail, float(x), 0.0, -40.0, -50.0, spacing_m=0.25, keep=5)
    assert len(trail) == 5
    assert [c.x_mm for c in trail] == [1750.0, 2000.0, 2250.0, 2500.0, 2750.0]
    assert trail[-1] == TrailPoint(2750.0, 0.0, -40.0, -50.0)


def test_idle_relay_lays_crumbs_with_its_rssi_and_leaves_the_controller_alone() -> None:
    m = RecoveryMemory()
    for i in range(10):
        out = recovery_step(inputs(pose=(i * 100.0, 0.0, 0.0), rssi_leader_dbm=-40.0 - i), P, m)
        assert out.command is None
        m = out.memory
    assert [c.x_mm for c in m.trail] == [0.0, 300.0, 600.0, 900.0]
    assert [c.rssi_l_dbm for c in m.trail] == [-40.0, -43.0, -46.0, -49.0]


def test_disabled_is_inert() -> None:
    m = RecoveryMemory()
    out = recovery_step(
        inputs(leader_lost=True, rssi_behind_dbm=-95.0), replace(P, enabled=False), m
    )
    assert out.command is None and out.memory is m


def test_leader_target_is_the_newest_crumb_above_threshold_else_the_best() -> None:
    trail = (
        TrailPoint(0, 0, -25.0, None),
        TrailPoint(1, 0, -28.0, None),
        TrailPoint(2, 0, -60.0, None),
        TrailPoint(3, 0, None, None),
    )
    assert leader_target(trail, -30.0) == 1
    weak = (
        TrailPoint(0, 0, -70.0, None),
        TrailPoint(1, 0, -50.0, None),
        TrailPoint(2, 0, -80.0, None),
    )
    assert leader_target(weak, -30.0) == 1
    assert leader_target((), -30.0) is None


# -- leader lost -----------------------------------------------------------------------


def test_leader_lost_widens_first_then_reverses_along_the_trail_then_resumes_when_found() -> None:
    trail = straight_trail(12)
    m = RecoveryMemory(trail=trail)
    here = (trail[-1].x_mm, 0.0, 0.0)  # facing +x, the trail behind it
    out = recovery_step(inputs(pose=here, leader_lost=True, scan_count=4, now_s=10.0), P, m)
    assert out.memory.phase is Phase.WIDEN and out.memory.kind is Kind.LEADER
    assert out.command is not None and (out.command.left_mm_s, out.command.right_mm_s) == (0.0, 0.0)
    assert out.command.state is DriveState.LEADER_LOST
    # One full-range scan done: retrace, in reverse, straight back.
    out = recovery_step(
        inputs(pose=here, leader_lost=True, scan_count=5, now_s=13.0), P, out.memory
    )
    assert out.memory.phase is Phase.RETRACE
    assert out.command is not None and out.command.state is DriveState.RECOVERING
    assert out.command.left_mm_s < 0 and out.command.right_mm_s < 0
    assert out.command.left_mm_s == out.command.right_mm_s == -P.retrace_speed_mm_s
    # The leader heard again: the controller drives at once.
    out = recovery_step(
        inputs(pose=(2000.0, 0.0, 0.0), leader_lost=False, scan_count=6, now_s=15.0), P, out.memory
    )
    assert out.command is None
    assert out.memory.phase is Phase.IDLE and out.memory.last_outcome == "found"
    assert out.memory.episodes == 1


def test_retrace_stops_at_the_crumb_where_the_leader_was_strong() -> None:
    trail = tuple(TrailPoint(i * 250.0, 0.0, -25.0 if i == 4 else -60.0, -55.0) for i in range(12))
    m = replace(
        RecoveryMemory(trail=trail),
        phase=Phase.RETRACE,
        kind=Kind.LEADER,
        started_t=0.0,
        target=4,
        episodes=1,
    )
    pose = (trail[-1].x_mm, 0.0, 0.0)
    t = 0.0
    for _ in range(400):
        out = recovery_step(inputs(pose=pose, leader_lost=True, now_s=t, scan_count=9), P, m)
        m = out.memory
        assert out.command is not None
        pose = diff_drive(pose, out.command.left_mm_s, out.command.right_mm_s, 0.1)
        t += 0.1
    assert abs(pose[0] - 1000.0) < P.reach_m * 1000.0
    assert out.command is not None and out.command.reason == "retrace_wait"
    assert len(m.trail) == 5


def test_gives_up_after_max_time_and_holds_with_reason_leader_lost() -> None:
    p = replace(P, max_time_s=20.0)
    m = replace(
        RecoveryMemory(trail=straight_trail(3)),
        phase=Phase.RETRACE,
        kind=Kind.LEADER,
        started_t=0.0,
        episodes=1,
    )
    out = recovery_step(inputs(pose=(0.0, 0.0, 0.0), leader_lost=True, now_s=20.0), p, m)
    assert out.memory.phase is Phase.GAVE_UP and out.memory.last_outcome == "gave_up_time"
    assert out.command is not None and out.command.reason == "leader_lost"
    assert out.command.state is DriveState.LEADER_LOST
    # Held until the leader is heard again, then the controller takes over.
    out = recovery_step(inputs(leader_lost=True, now_s=40.0), p, out.memory)
    assert out.command is not None and out.command.left_mm_s == 0.0
    out = recovery_step(inputs(leader_lost=False, now_s=41.0), p, out.memory)
    assert out.command is None and out.memory.phase is Phase.IDLE


def test_mode_change_aborts_an_episode() -> None:
    m = replace(RecoveryMemory(), phase=Phase.WIDEN, kind=Kind.LEADER, started_t=0.0, episodes=1)
    out = recovery_step(inputs(following=False, leader_lost=True, now_s=1.0), P, m)
    assert (
        out.command is None
        and out.memory.phase is Phase.IDLE
        and out.memory.last_outcome == "aborted"
    )


# -- the link behind -------------------------------------------------------------------


def test_rear_link_below_lost_backs_up_until_above_threshold_b_plus_hysteresis() -> None:
    trail = straight_trail(20)
    m = RecoveryMemory(trail=trail)
    pose = (trail[-1].x_mm, 0.0, 0.0)
    polls = 0

    def poll(dbm: float, t: float) -> object:
        nonlocal polls, m
        polls += 1
        out = recovery_step(inputs(pose=pose, rssi_behind_dbm=dbm, rear_polls=polls, now_s=t), P, m)
        m = out.memory
        return out

    # Below threshold_b but above lost_rssi: the controller's rear_weak stop stands.
    assert poll(-70.0, 0.0).command is None  # type: ignore[attr-defined]
    # A poll below lost_rssi starts backing up.
    out = poll(-88.0, 3.0)
    assert m.phase is Phase.BACKUP and m.kind is Kind.REAR
    cmd = out.command  # type: ignore[attr-defined]
    assert cmd is not None and cmd.left_mm_s < 0 and cmd.right_mm_s < 0
    # The same poll seen again on the next SIP counts once.
    out = recovery_step(inputs(pose=pose, rssi_behind_dbm=-88.0, rear_polls=polls, now_s=3.1), P, m)
    assert out.memory.rear_low == 1
    # -59 is above threshold_b (-60) but inside the band: keep backing; then two polls above it.
    poll(-59.0, 4.0)
    assert m.phase is Phase.BACKUP
    poll(-57.0, 5.0)
    assert m.phase is Phase.BACKUP
    out = poll(-56.0, 6.0)
    assert out.command is None and m.last_outcome == "restored"  # type: ignore[attr-defined]


def rear_lost(m: RecoveryMemory) -> RecoveryMemory:
    """A memory that has counted enough rear polls below lost_rssi."""
    return replace(m, rear_seen=3, rear_low=REAR_LOST_POLLS)


def test_the_chain_behind_first_rear_break_preempts_a_leader_episode() -> None:
    m = replace(
        RecoveryMemory(trail=straight_trail(8)),
        phase=Phase.RETRACE,
        kind=Kind.LEADER,
        started_t=0.0,
        episodes=1,
    )
    out = recovery_step(
        inputs(
            pose=(1750.0, 0.0, 0.0),
            leader_lost=True,
            rssi_behind_dbm=-90.0,
            now_s=2.0,
            rear_polls=3,
        ),
        P,
        rear_lost(m),
    )
    assert out.memory.kind is Kind.REAR and out.memory.phase is Phase.BACKUP
    assert out.memory.episodes == 2
    assert out.command is not None and out.command.reason == "backup"


def test_chained_episodes_share_one_budget() -> None:
    # A leader episode 40 s and 3 m old is pre-empted by the link behind: the rear
    # episode gets what is left (20 s, 5 m), not a fresh 60 s and 8 m.
    m = replace(
        RecoveryMemory(trail=straight_trail(30)),
        phase=Phase.RETRACE,
        kind=Kind.LEADER,
        started_t=0.0,
        episodes=1,
        incident_t=0.0,
        incident_m=3.0,
        distance_m=3.0,
        last_pose=(7250.0, 0.0),
    )
    out = recovery_step(
        inputs(
            pose=(7250.0, 0.0, 0.0),
            leader_lost=True,
            rssi_behind_dbm=-90.0,
            now_s=40.0,
            rear_polls=3,
        ),
        P,
        rear_lost(m),
    )
    assert (
        out.memory.kind is Kind.REAR
        and out.memory.started_t == 40.0
        and out.memory.incident_t == 0.0
    )
    out = recovery_step(
        inputs(
            pose=(7000.0, 0.0, 0.0),
            leader_lost=True,
            rssi_behind_dbm=-90.0,
            now_s=60.0,
            rear_polls=3,
        ),
        P,
        out.memory,
    )
    assert out.memory.phase is Phase.GAVE_UP and out.memory.last_outcome == "gave_up_time"
    assert out.command is not None and out.command.reason == "rear_lost"
    # Given up on the leader, a break behind later is a new incident with a fresh budget.
    held = replace(out.memory, kind=Kind.LEADER)
    out = recovery_step(
        inputs(
            pose=(7000.0, 0.0, 0.0),
            leader_lost=True,
            rssi_behind_dbm=-90.0,
            now_s=90.0,
            rear_polls=3,
        ),
        P,
        held,
    )
    assert out.memory.phase is Phase.BACKUP and out.memory.incident_t == 90.0


def test_never_backs_into_an_obstacle_the_rear_sonars_see() -> None:
    m = rear_lost(
        replace(
            RecoveryMemory(trail=straight_trail(8)),
            phase=Phase.BACKUP,
            kind=Kind.REAR,
            started_t=0.0,
            episodes=1,
        )
    )
    sonar = list(OPEN)
    sonar[11] = 250  # the -170 degree rear sonar: something 0.25 m behind
    out = recovery_step(
        inputs(pose=(1750.0, 0.0, 0.0), rssi_behind_dbm=-90.0, sonar_mm=tuple(sonar), now_s=1.0),
        P,
        m,
    )
    assert out.command is not None
    assert (out.command.left_mm_s, out.command.right_mm_s) == (0.0, 0.0)
    assert out.command.reason == "rear_blocked"
    # Farther away: slower, and steered toward the open side. The echo is behind the
    # robot's right side, so its rear must swing to the robot's left: a clockwise turn,
    # the right wheel reversing faster.
    sonar[11], sonar[12] = 5000, 5000
    sonar[10] = 600  # -150: behind, to the right
    out = recovery_step(
        inputs(pose=(1750.0, 0.0, 0.0), rssi_behind_dbm=-90.0, sonar_mm=tuple(sonar), now_s=1.1),
        P,
        m,
    )
    assert out.command is not None and out.command.reason == "rear_obstacle"
    assert out.command.right_mm_s < out.command.left_mm_s
    assert -P.backup_speed_mm_s < (out.command.left_mm_s + out.command.right_mm_s) / 2 < 0


def test_status_view_reports_phase_and_progress() -> None:
    m = replace(
        RecoveryMemory(trail=straight_trail(4)),
        phase=Phase.RETRACE,
        kind=Kind.LEADER,
        started_t=10.0,
        episodes=3,
        distance_m=1.234,
    )
    v = recovery_view(m, P, 17.6)
    assert (v.phase, v.kind, v.episodes, v.elapsed_s, v.distance_m, v.trail_crumbs) == (
        Phase.RETRACE,
        Kind.LEADER,
        3,
        7.0,
        1.2,
        4,
    )


# -- properties ------------------------------------------------------------------------

ages = st.one_of(st.none(), st.floats(0.0, 20.0), st.just(math.nan))
dbm = st.one_of(st.none(), st.floats(-100.0, -10.0))
sonars = st.lists(st.one_of(st.none(), st.integers(100, 6000)), min_size=16, max_size=16).map(tuple)


@st.composite
def memories(draw: st.DrawFn) -> RecoveryMemory:
    n = draw(st.integers(0, 30))
    trail = tuple(
        TrailPoint(draw(st.floats(-5e3, 5e3)), draw(st.floats(-5e3, 5e3)), draw(dbm), draw(dbm))
        for _ in range(n)
    )
    phase = draw(st.sampled_from(list(Phase)))
    kind = None if phase is Phase.IDLE else draw(st.sampled_from(list(Kind)))
    return RecoveryMemory(
        trail=trail,
        phase=phase,
        kind=kind,
        episodes=1,
        started_t=draw(st.floats(0.0, 50.0)),
        distance_m=draw(st.floats(0.0, 3.0)),
        target=draw(st.none() | st.integers(0, 40)),
        rear_seen=draw(st.integers(0, 5)),
        rear_low=draw(st.integers(0, 5)),
        rear_high=draw(st.integers(0, 5)),
        incident_t=draw(st.none() | st.floats(0.0, 50.0)),
        incident_m=draw(st.floats(0.0, 3.0)),
    )


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    m=memories(),
    sip=ages,
    rssi=ages,
    scan=ages,
    rear=ages,
    lost=st.booleans(),
    rl=dbm,
    rb=dbm,
    sonar=sonars,
    now=st.floats(0.0, 100.0),
    count=st.integers(0, 10),
    polls=st.integers(0, 5),
)
def test_property_never_drives_on_stale_input(
    m: RecoveryMemory,
    sip: float | None,
    rssi: float | None,
    scan: float | None,
    rear: float | None,
    lost: bool,
    rl: float | None,
    rb: float | None,
    sonar: tuple[int | None, ...],
    now: float,
    count: int,
    polls: int,
) -> None:
    inp = inputs(
        sip_age_s=sip,
        rssi_age_s=rssi,
        scan_age_s=scan,
        rear_age_s=rear,
        leader_lost=lost,
        rssi_leader_dbm=rl,
        rssi_behind_dbm=rb,
        sonar_mm=sonar,
        now_s=now,
        scan_count=count,
        rear_polls=polls,
    )
    out = recovery_step(inp, P, m)
    assert out.command is None or out.command.reason in REASONS
    if out.command is not None and (out.command.left_mm_s or out.command.right_mm_s):
        assert not inputs_stale(inp, P, need_rear=out.memory.kind is Kind.REAR)
        assert sip is not None and sip <= P.control.sip_timeout_s
        assert rssi is not None and rssi <= P.control.rssi_timeout_s
        assert rear is not None and rear <= P.control.rear_timeout_s and rb is not None
        assert scan is None or scan <= (P.scan_timeout_s or math.inf)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    n=st.integers(0, 80),
    heading=st.floats(-180.0, 180.0),
    max_d=st.floats(0.1, 6.0),
    max_t=st.floats(1.0, 60.0),
    dt=st.floats(0.02, 0.5),
    rear=st.booleans(),
    wiggle=st.lists(st.floats(-300.0, 300.0), min_size=80, max_size=80),
    blocked=st.lists(st.booleans(), min_size=8, max_size=8),
)
def test_property_never_exceeds_its_distance_or_time_limit(
    n: int,
    heading: float,
    max_d: float,
    max_t: float,
    dt: float,
    rear: bool,
    wiggle: list[float],
    blocked: list[bool],
) -> None:
    p = replace(P, max_distance_m=max_d, max_time_s=max_t, widen_scans=0)
    # A winding trail laid by the relay itself, then the link breaks at its end.
    trail: tuple[TrailPoint, ...] = ()
    x = y = 0.0
    for i in range(n):
        a = math.radians(heading + wiggle[i] / 10.0)
        x, y = x + 250.0 * math.cos(a), y + 250.0 * math.sin(a)
        trail = add_crumb(
            trail,
            x,
            y,
            -40.0 + wiggle[i] / 30.0,
            -55.0,
            spacing_m=p.crumb_spacing_m,
            keep=p.trail_len,
        )
    m = RecoveryMemory(trail=trail)
    pose = (x, y, heading)
    t = 100.0
    start_t: float | None = None
    travelled_m = 0.0
    steps = int(1.5 * max_t / dt) + 5
    for k in range(steps):
        sonar = list(OPEN)
        if blocked[k % 8]:
            sonar[11] = 450
        inp = inputs(
            pose=pose,
            leader_lost=True,
            rssi_behind_dbm=-95.0 if rear else -55.0,
            now_s=t,
            scan_count=k,
            sonar_mm=tuple(sonar),
            rear_polls=k,
        )
        out = recovery_step(inp, p, m)
        m = out.memory
        if start_t is None and m.incident_t is not None:
            start_t = m.incident_t
        moving = out.command is not None and (out.command.left_mm_s or out.command.right_mm_s)
        if moving:
            assert start_t is not None and t - start_t < max_t
            assert out.command is not None
            new = diff_drive(pose, out.command.left_mm_s, out.command.right_mm_s, dt)
            travelled_m += math.dist(new[:2], pose[:2]) / 1000.0
            pose = new
        t += dt
    assert travelled_m <= max_d + 1e-9
    assert m.phase is Phase.GAVE_UP or len(m.trail) <= 1 or travelled_m > 0


def test_reverse_pursuit_follows_a_turning_trail_back_around_the_corner() -> None:
    # The relay drove east 2 m, then north 2 m (a corner); it backs the same way round.
    pts = [(x, 0.0) for x in range(0, 2001, 250)] + [(2000.0, y) for y in range(250, 2001, 250)]
    trail = tuple(
        TrailPoint(float(x), float(y), -25.0 if (x, y) == (0, 0.0) else -60.0, -55.0)
        for x, y in pts
    )
    m = replace(
        RecoveryMemory(trail=trail),
        phase=Phase.RETRACE,
        kind=Kind.LEADER,
        started_t=0.0,
        target=0,
        episodes=1,
    )
    pose = (2000.0, 2000.0, 90.0)
    worst_off_mm = 0.0
    for k in range(500):
        out = recovery_step(inputs(pose=pose, leader_lost=True, now_s=k * 0.1, scan_count=3), P, m)
        m = out.memory
        assert out.command is not None
        pose = diff_drive(pose, out.command.left_mm_s, out.command.right_mm_s, 0.1)
        # Distance from the L-shaped path the relay came along.
        off = min(
            abs(pose[1]) if pose[0] <= 2000 else math.hypot(pose[0] - 2000, pose[1]),
            abs(pose[0] - 2000) if 0 <= pose[1] <= 2000 else math.inf,
        )
        worst_off_mm = max(worst_off_mm, off)
    assert math.hypot(pose[0], pose[1]) < P.reach_m * 1000.0
    assert worst_off_mm < 400.0
    assert out.command is not None and out.command.reason == "retrace_wait"


def test_after_a_restore_it_does_not_drive_straight_back_over_the_edge() -> None:
    trail = straight_trail(20)
    m = rear_lost(
        replace(
            RecoveryMemory(trail=trail),
            phase=Phase.BACKUP,
            kind=Kind.REAR,
            started_t=0.0,
            episodes=1,
            incident_t=0.0,
            episode_from=(4750.0, 0.0),
        )
    )
    m = replace(m, rear_high=1)
    out = recovery_step(
        inputs(pose=(4300.0, 0.0, 0.0), rssi_behind_dbm=-55.0, rear_polls=4, now_s=5.0), P, m
    )
    assert out.memory.last_outcome == "restored" and out.memory.fence == (4750.0, 0.0)
    m = out.memory
    # The controller would drive on toward the leader: held at the edge, reason rear_fence.
    fwd = recovery_step(
        inputs(
            pose=(4300.0, 0.0, 0.0),
            rssi_behind_dbm=-55.0,
            rear_polls=4,
            now_s=6.0,
            forward_mm_s=200.0,
        ),
        P,
        m,
    )
    assert (
        fwd.command is not None
        and fwd.command.reason == "rear_fence"
        and fwd.command.left_mm_s == 0.0
    )
    # Turning in place or backing is the controller's; farther from the edge it may drive.
    assert (
        recovery_step(
            inputs(
                pose=(4300.0, 0.0, 0.0),
                rssi_behind_dbm=-55.0,
                rear_polls=4,
                now_s=6.0,
                forward_mm_s=0.0,
            ),
            P,
            m,
        ).command
        is None
    )
    assert (
        recovery_step(
            inputs(
                pose=(3000.0, 0.0, 0.0),
                rssi_behind_dbm=-55.0,
                rear_polls=4,
                now_s=6.0,
                forward_mm_s=200.0,
            ),
            P,
            m,
        ).command
        is None
    )
    # The fence goes after FENCE_S, or as soon as the link behind is much stronger.
    late = recovery_step(
        inputs(
            pose=(4300.0, 0.0, 0.0),
            rssi_behind_dbm=-55.0,
            rear_polls=4,
            now_s=70.0,
            forward_mm_s=200.0,
        ),
        P,
        m,
    )
    assert late.command is None and late.memory.fence is None
    strong = recovery_step(
        inputs(
            pose=(4300.0, 0.0, 0.0),
            rssi_behind_dbm=-40.0,
            rear_polls=5,
            now_s=7.0,
            forward_mm_s=200.0,
        ),
        P,
        m,
    )
    assert strong.command is None and strong.memory.fence is None


def test_a_nan_scan_age_is_stale() -> None:
    """Found by the property above: `age > limit` is False for NaN, so it read as fresh."""
    fresh = inputs(
        sip_age_s=0.0, rssi_age_s=0.0, scan_age_s=0.0, rear_age_s=0.0, rssi_behind_dbm=-50.0
    )
    assert not inputs_stale(fresh, P, need_rear=False)
    broken = inputs(
        sip_age_s=0.0, rssi_age_s=0.0, scan_age_s=math.nan, rear_age_s=0.0, rssi_behind_dbm=-50.0
    )
    assert inputs_stale(broken, P, need_rear=False)
