"""Self-healing when a link breaks: the recovery state machine (pure; docs/CONTROL.md 9).

`recovery_step` gets one snapshot (`RecoveryInputs`), the settings and the memory of
the step before, and returns a wheel command that replaces the follow controller's, or
None (the controller's output stands). It runs TRANSITIONS, an ordered table read top
to bottom (the override order): a rear link breaking pre-empts a lost leader; WIDEN,
RETRACE and BACKUP move in reverse along the breadcrumbs the relay drove through; an
incident gives up after its time or distance budget, shared by its episodes. It
promises: stale input never drives; the reverse speed is tapered so no control period
carries the relay past its distance limit. No I/O, no clock.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

from relayd.core.recovery.episode import fenced, run_episode
from relayd.core.recovery.state import (
    REAR_LOST_POLLS,
    REAR_RESTORED_POLLS,
    Kind,
    Phase,
    RecoveryInputs,
    RecoveryMemory,
    RecoveryOutput,
    RecoveryParams,
    close,
    stale,
    zero,
)
from relayd.core.recovery.trail import add_crumb
from relayd.core.vocab import DriveState


def _start(
    m: RecoveryMemory, kind: Kind, inp: RecoveryInputs, phase: Phase, *, chained: bool
) -> RecoveryMemory:
    pos = None if inp.pose is None else (inp.pose[0], inp.pose[1])
    if not chained or m.incident_t is None:
        m = replace(m, incident_t=inp.now_s, incident_m=0.0)
    return replace(
        m,
        phase=phase,
        kind=kind,
        episodes=m.episodes + 1,
        started_t=inp.now_s,
        start_scans=inp.scan_count,
        distance_m=0.0,
        last_pose=pos,
        target=None,
        episode_from=pos,
    )


def _count_rear(inp: RecoveryInputs, p: RecoveryParams, m: RecoveryMemory) -> RecoveryMemory:
    """Count a new rear poll into the low/high runs."""
    if inp.rear_polls == m.rear_seen:
        return m
    v = inp.rssi_behind_dbm
    low = v is not None and v < p.lost_rssi_dbm
    high = v is not None and v > p.control.threshold_b_dbm + p.control.hysteresis_db
    return replace(
        m,
        rear_seen=inp.rear_polls,
        rear_low=m.rear_low + 1 if low else 0,
        rear_high=m.rear_high + 1 if high else 0,
    )


def _rear_broken(inp: RecoveryInputs, p: RecoveryParams, m: RecoveryMemory) -> bool:
    return (
        p.control.rear_link_required
        and inp.rssi_behind_dbm is not None
        and not stale(inp.rear_age_s, p.control.rear_timeout_s)
        and inp.rssi_behind_dbm < p.lost_rssi_dbm
        and m.rear_low >= REAR_LOST_POLLS
    )


def _rear_restored(inp: RecoveryInputs, p: RecoveryParams, m: RecoveryMemory) -> bool:
    return (
        inp.rssi_behind_dbm is not None
        and inp.rssi_behind_dbm > p.control.threshold_b_dbm + p.control.hysteresis_db
        and m.rear_high >= REAR_RESTORED_POLLS
    )


def recovery_step(inp: RecoveryInputs, p: RecoveryParams, m: RecoveryMemory) -> RecoveryOutput:
    """One decision; see the module docstring."""
    if not p.enabled:
        return RecoveryOutput(None, m)
    if not inp.following:
        if m.phase in ACTIVE:
            m = close(m, Phase.IDLE, "aborted")
        elif m.phase is Phase.GAVE_UP:
            m = replace(m, phase=Phase.IDLE, kind=None)
        return RecoveryOutput(None, m)

    m = _count_rear(inp, p, m)
    step = _Step(inp, p, chained=m.phase in ACTIVE)
    m = _travel(inp, m)
    for rule in TRANSITIONS:
        if m.phase in rule.phases and rule.when(step, m):
            out = rule.then(step, m)
            if isinstance(out, RecoveryOutput):
                return out
            m = out
    return run_episode(inp, p, m)


#: The phases of a running episode.
ACTIVE = frozenset({Phase.WIDEN, Phase.RETRACE, Phase.BACKUP})


@dataclass(frozen=True, slots=True)
class _Step:
    inp: RecoveryInputs
    p: RecoveryParams
    chained: bool  # an episode was running when this step began (the incident goes on)


def _travel(inp: RecoveryInputs, m: RecoveryMemory) -> RecoveryMemory:
    """Odometry travel during an episode: the distance limit's measure."""
    if m.phase is Phase.IDLE or inp.pose is None or not all(math.isfinite(v) for v in inp.pose):
        return m
    here = (inp.pose[0], inp.pose[1])
    if m.last_pose is not None:
        step_m = math.dist(here, m.last_pose) / 1000.0
        m = replace(m, distance_m=m.distance_m + step_m, incident_m=m.incident_m + step_m)
    return replace(m, last_pose=here)


def _cleared(st: _Step, m: RecoveryMemory) -> bool:
    """What a gave-up episode waited for came back."""
    if m.kind is Kind.LEADER:
        return not st.inp.leader_lost
    return _rear_restored(st.inp, st.p, m)


def _hold_gave_up(st: _Step, m: RecoveryMemory) -> RecoveryOutput:
    leader = m.kind is Kind.LEADER
    return RecoveryOutput(
        zero(
            DriveState.LEADER_LOST if leader else DriveState.STOPPED,
            "leader_lost" if leader else "rear_lost",
        ),
        m,
    )


def _idle(st: _Step, m: RecoveryMemory) -> RecoveryOutput:
    """No episode: lay breadcrumbs; the controller drives (inside the fence)."""
    inp, p = st.inp, st.p
    m = replace(m, incident_t=None, incident_m=0.0)
    if inp.pose is not None and all(math.isfinite(v) for v in inp.pose):
        m = replace(
            m,
            trail=add_crumb(
                m.trail,
                inp.pose[0],
                inp.pose[1],
                inp.rssi_leader_dbm,
                inp.rssi_behind_dbm,
                spacing_m=p.crumb_spacing_m,
                keep=p.trail_len,
            ),
        )
    return fenced(inp, p, m)


@dataclass(frozen=True, slots=True)
class Transition:
    """One row: in one of `phases`, when `when` holds, `then` gives the new memory (the
    table goes on from there) or the step's output (the step ends)."""

    phases: frozenset[Phase]
    when: Callable[[_Step, RecoveryMemory], bool]
    then: Callable[[_Step, RecoveryMemory], RecoveryMemory | RecoveryOutput]
    why: str


_ALWAYS: Callable[[_Step, RecoveryMemory], bool] = lambda st, m: True  # noqa: E731

#: The recovery's transitions, tried top to bottom on every step (h2's state machine as a
#: table). The order is the override order: a gave-up episode first, then what ends an
#: episode, then the rear link before the leader (docs/CONTROL.md section 9).
TRANSITIONS: tuple[Transition, ...] = (
    Transition(
        frozenset({Phase.GAVE_UP}),
        _cleared,
        lambda st, m: replace(m, phase=Phase.IDLE, kind=None),
        "what the episode gave up on came back",
    ),
    Transition(
        frozenset({Phase.GAVE_UP}),
        lambda st, m: m.kind is Kind.LEADER and _rear_broken(st.inp, st.p, m),
        lambda st, m: _start(m, Kind.REAR, st.inp, Phase.BACKUP, chained=False),
        "given up on the leader, the link behind breaks: back up",
    ),
    Transition(frozenset({Phase.GAVE_UP}), _ALWAYS, _hold_gave_up, "given up: wheels zero"),
    Transition(
        frozenset({Phase.WIDEN, Phase.RETRACE}),
        lambda st, m: not st.inp.leader_lost,
        lambda st, m: close(m, Phase.IDLE, "found"),
        "the leader is heard again",
    ),
    Transition(
        frozenset({Phase.BACKUP}),
        lambda st, m: _rear_restored(st.inp, st.p, m),
        lambda st, m: replace(
            close(m, Phase.IDLE, "restored"), fence=m.episode_from, fence_t=st.inp.now_s
        ),
        "the link behind is back: fence off where it broke",
    ),
    Transition(
        frozenset({Phase.WIDEN, Phase.RETRACE}),
        lambda st, m: _rear_broken(st.inp, st.p, m),
        lambda st, m: _start(
            close(m, Phase.IDLE, "preempted"), Kind.REAR, st.inp, Phase.BACKUP, chained=True
        ),
        "the link behind breaks while looking for the leader: it goes first",
    ),
    Transition(
        frozenset({Phase.IDLE}),
        lambda st, m: _rear_broken(st.inp, st.p, m),
        lambda st, m: _start(m, Kind.REAR, st.inp, Phase.BACKUP, chained=st.chained),
        "the link behind breaks: back up along the trail",
    ),
    Transition(
        frozenset({Phase.IDLE}),
        lambda st, m: st.inp.leader_lost,
        lambda st, m: _start(m, Kind.LEADER, st.inp, Phase.WIDEN, chained=st.chained),
        "the leader is lost: widen the scan, then retrace",
    ),
    Transition(frozenset({Phase.IDLE}), _ALWAYS, _idle, "no episode: the controller drives"),
)
