"""Self-healing when a link breaks: breadcrumbs and the recovery state machine (pure).

The paper leaves broken links out of scope; this is the backup plan it names as future
work, decided locally by each relay (docs/CONTROL.md section 9). Nothing here does
I/O or reads a clock: `recovery_step` gets one snapshot (`RecoveryInputs`), the
settings and the memory of the step before, and returns either a wheel command that
replaces the follow controller's, or None (the controller's output stands).

- **Breadcrumbs.** While no episode runs, every `crumb_spacing_m` of odometry travel
  adds a crumb: the pose and the RSSI^l / RSSI^b the relay had there. The trail keeps
  the newest `trail_len` crumbs.
- **Leader lost** (the brain's 3-scans-below-lost_rssi rule): WIDEN first (wheels zero
  while `widen_scans` full-range scans complete; the brain widens the window by
  itself while the leader is lost), then RETRACE: back along the trail toward the
  newest crumb where RSSI^l was at or above threshold_l (none: the crumb with the best
  RSSI^l), scanning as it goes. The leader heard again ends the episode ("found").
- **Rear link breaking** (a fresh RSSI^b poll below lost_rssi): BACKUP along the trail
  until RSSI^b is above threshold_b + hysteresis on REAR_RESTORED_POLLS polls in a
  row ("restored"): one upward fade does not end it. It pre-empts a leader episode:
  the chain behind is restored first. For FENCE_S after a restore, the controller may
  not drive forward to within FENCE_M of where the link broke: a relay at a corner
  whose link behind falls off a cliff would otherwise drive straight back over it.
- Both move in **reverse** along crumbs the relay already drove through (known free
  space), so the Yagi keeps facing where the leader went; the rear sonars 9..14 slow,
  steer and stop it like the front ones do going forward, and never let it back into
  an obstacle. The trail is consumed as the relay passes its crumbs.
- **Limits.** An incident ends GAVE_UP (wheels zero; reason "leader_lost" or
  "rear_lost") after `max_time_s` or `max_distance_m` of odometry travel. An incident
  is the run of episodes from the controller losing charge to getting it back: a rear
  episode that pre-empts a leader episode, or a leader episode right after the rear
  is restored, spends what is left of the same budget, so alternating episodes cannot
  add up past the limits. The reverse speed is tapered to the distance left (at most
  remaining / TAPER_S), so a control period under TAPER_S can never carry the relay
  past its distance limit.
- **Stale input never drives.** Any input older than its limit (SIP, RSSI stream,
  scan, RSSI^b when required or backing up) gives zero wheels while an episode runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import StrEnum

from relayd.core.recovery.trail import Crumb, add_crumb, leader_target, reverse_toward
from relayd.core.vocab import DriveState

#: Reverse speed is capped at (distance left) / TAPER_S.
TAPER_S = 1.0
#: Closer to the distance limit than this counts as reached.
LIMIT_SLACK_M = 0.02
#: Rear-AP polls in a row below lost_rssi before the link behind counts as breaking: one.
#: A link whose mean sits just above lost_rssi is already down at any useful rate, and
#: its samples cross lost_rssi only now and then (measured in blind-corner: three in a
#: row almost never came, so the relay stood by a dead link); a needless short backup
#: after a deep fade costs a few decimetres.
REAR_LOST_POLLS = 1
#: ... and above threshold_b + hysteresis before it counts as restored.
REAR_RESTORED_POLLS = 2
#: After the link behind is restored, forward driving stops this close to where it broke ...
FENCE_M = 0.6
#: ... for this long, or until RSSI^b is this far above threshold_b + hysteresis (the node
#: behind came closer): a relay must not drive straight back off the edge it backed from.
FENCE_S = 60.0
FENCE_CLEAR_DB = 10.0


#: Every reason an episode reports (each has a phrase in relayd/api/static/reasons.json).
REASONS = frozenset(
    {
        "widen",
        "retrace",
        "retrace_wait",
        "backup",
        "rear_obstacle",
        "rear_blocked",
        "rear_trail_end",
        "rear_lost",
        "leader_lost",
        "recovery_stale_input",
        "rear_fence",
    }
)


class Phase(StrEnum):
    IDLE = "idle"
    WIDEN = "widen"
    RETRACE = "retrace"
    BACKUP = "backup"
    GAVE_UP = "gave_up"


class Kind(StrEnum):
    LEADER = "leader"
    REAR = "rear"


@dataclass(frozen=True, slots=True)
class RecoveryParams:
    enabled: bool = False
    max_distance_m: float = 8.0
    max_time_s: float = 60.0
    retrace_speed_mm_s: float = 200.0
    backup_speed_mm_s: float = 150.0
    widen_scans: int = 1
    crumb_spacing_m: float = 0.25
    trail_len: int = 200
    reach_m: float = 0.3
    turn_gain_mm_s_deg: float = 3.0
    # From [control] (the brain's params module fills them in).
    threshold_l_dbm: float = -30.0
    threshold_b_dbm: float = -60.0
    hysteresis_db: float = 2.0
    lost_rssi_dbm: float = -85.0
    threshold_o_m: float = 0.8
    stop_distance_m: float = 0.3
    gamma_o_m: float = 1.0
    rear_required: bool = True
    sip_timeout_s: float = 0.5
    rssi_timeout_s: float = 0.5
    rear_timeout_s: float = 3.0
    scan_timeout_s: float | None = None


@dataclass(frozen=True, slots=True)
class RecoveryInputs:
    """One snapshot: ages are seconds since the newest datum (None: never had one)."""

    following: bool  # follow mode, no shutdown
    pose: tuple[float, float, float] | None  # odometry x_mm, y_mm, theta_deg
    sip_age_s: float | None
    rssi_age_s: float | None
    scan_age_s: float | None
    rear_age_s: float | None
    leader_lost: bool
    rssi_leader_dbm: float | None
    rssi_behind_dbm: float | None
    scan_count: int
    sonar_mm: tuple[int | None, ...]
    now_s: float
    #: Rear-AP polls received so far (RSSI^b's sample count): each new one is counted once.
    rear_polls: int = 0
    #: The follow controller's forward speed this step (mean of its wheels).
    forward_mm_s: float = 0.0


@dataclass(frozen=True, slots=True)
class RecoveryMemory:
    trail: tuple[Crumb, ...] = ()
    phase: Phase = Phase.IDLE
    kind: Kind | None = None
    episodes: int = 0
    started_t: float | None = None
    start_scans: int = 0
    distance_m: float = 0.0
    last_pose: tuple[float, float] | None = None
    target: int | None = None  # index into trail of the crumb the retrace aims for
    last_outcome: str | None = None
    incident_t: float | None = None  # when the controller last lost charge (the budget's start)
    incident_m: float = 0.0  # odometry travel since then
    episode_from: tuple[float, float] | None = None  # where the running episode began
    fence: tuple[float, float] | None = None  # where the link behind broke, after a restore
    fence_t: float | None = None
    rear_seen: int = 0  # rear_polls already counted
    rear_low: int = 0  # polls in a row below lost_rssi
    rear_high: int = 0  # polls in a row above threshold_b + hysteresis


@dataclass(frozen=True, slots=True)
class RecoveryCommand:
    left_mm_s: float
    right_mm_s: float
    state: DriveState
    reason: str


@dataclass(frozen=True, slots=True)
class RecoveryOutput:
    command: RecoveryCommand | None  # None: the follow controller's output stands
    memory: RecoveryMemory


def _stale(age: float | None, limit: float | None) -> bool:
    if limit is None:
        return False
    return age is None or not math.isfinite(age) or age > limit


def inputs_stale(inp: RecoveryInputs, p: RecoveryParams, *, need_rear: bool) -> bool:
    """Any input the episode relies on older than its limit (or missing)."""
    if inp.pose is None or not all(math.isfinite(v) for v in inp.pose):
        return True
    if _stale(inp.sip_age_s, p.sip_timeout_s) or _stale(inp.rssi_age_s, p.rssi_timeout_s):
        return True
    # `not <=` so that a NaN age is stale too (a broken clock is no reason to move).
    if (
        p.scan_timeout_s is not None
        and inp.scan_age_s is not None
        and not inp.scan_age_s <= p.scan_timeout_s
    ):
        return True
    rear_needed = need_rear or p.rear_required
    return rear_needed and (_stale(inp.rear_age_s, p.rear_timeout_s) or inp.rssi_behind_dbm is None)


def _close(m: RecoveryMemory, phase: Phase, outcome: str) -> RecoveryMemory:
    return replace(
        m,
        phase=phase,
        last_outcome=outcome,
        target=None,
        kind=m.kind if phase is Phase.GAVE_UP else None,
    )


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
    high = v is not None and v > p.threshold_b_dbm + p.hysteresis_db
    return replace(
        m,
        rear_seen=inp.rear_polls,
        rear_low=m.rear_low + 1 if low else 0,
        rear_high=m.rear_high + 1 if high else 0,
    )


def _rear_broken(inp: RecoveryInputs, p: RecoveryParams, m: RecoveryMemory) -> bool:
    return (
        p.rear_required
        and inp.rssi_behind_dbm is not None
        and not _stale(inp.rear_age_s, p.rear_timeout_s)
        and inp.rssi_behind_dbm < p.lost_rssi_dbm
        and m.rear_low >= REAR_LOST_POLLS
    )


def _rear_restored(inp: RecoveryInputs, p: RecoveryParams, m: RecoveryMemory) -> bool:
    return (
        inp.rssi_behind_dbm is not None
        and inp.rssi_behind_dbm > p.threshold_b_dbm + p.hysteresis_db
        and m.rear_high >= REAR_RESTORED_POLLS
    )


def _zero(state: DriveState, reason: str) -> RecoveryCommand:
    return RecoveryCommand(0.0, 0.0, state, reason)


# Complexity: the override order of the recovery's inputs, read top to bottom (docs/CONTROL.md 8).
def recovery_step(inp: RecoveryInputs, p: RecoveryParams, m: RecoveryMemory) -> RecoveryOutput:  # noqa: C901
    """One decision; see the module docstring."""
    if not p.enabled:
        return RecoveryOutput(None, m)
    if not inp.following:
        if m.phase in (Phase.WIDEN, Phase.RETRACE, Phase.BACKUP):
            m = _close(m, Phase.IDLE, "aborted")
        elif m.phase is Phase.GAVE_UP:
            m = replace(m, phase=Phase.IDLE, kind=None)
        return RecoveryOutput(None, m)

    m = _count_rear(inp, p, m)
    chained = m.phase in (Phase.WIDEN, Phase.RETRACE, Phase.BACKUP)
    # Odometry travel during an episode (the distance limit's measure).
    if (
        m.phase is not Phase.IDLE
        and inp.pose is not None
        and all(math.isfinite(v) for v in inp.pose)
    ):
        here = (inp.pose[0], inp.pose[1])
        if m.last_pose is not None:
            step_m = math.dist(here, m.last_pose) / 1000.0
            m = replace(m, distance_m=m.distance_m + step_m, incident_m=m.incident_m + step_m)
        m = replace(m, last_pose=here)

    # Transitions that end or switch an episode.
    if m.phase is Phase.GAVE_UP:
        cleared = (not inp.leader_lost) if m.kind is Kind.LEADER else _rear_restored(inp, p, m)
        if cleared:
            m = replace(m, phase=Phase.IDLE, kind=None)
        elif m.kind is Kind.LEADER and _rear_broken(inp, p, m):
            m = _start(m, Kind.REAR, inp, Phase.BACKUP, chained=False)
        else:
            reason = "leader_lost" if m.kind is Kind.LEADER else "rear_lost"
            state = DriveState.LEADER_LOST if m.kind is Kind.LEADER else DriveState.STOPPED
            return RecoveryOutput(_zero(state, reason), m)
    if m.phase in (Phase.WIDEN, Phase.RETRACE) and not inp.leader_lost:
        m = _close(m, Phase.IDLE, "found")
    if m.phase is Phase.BACKUP and _rear_restored(inp, p, m):
        m = replace(_close(m, Phase.IDLE, "restored"), fence=m.episode_from, fence_t=inp.now_s)
    if m.phase in (Phase.WIDEN, Phase.RETRACE) and _rear_broken(inp, p, m):
        m = _start(_close(m, Phase.IDLE, "preempted"), Kind.REAR, inp, Phase.BACKUP, chained=True)

    # Starting an episode (the rear first).
    if m.phase is Phase.IDLE:
        if _rear_broken(inp, p, m):
            m = _start(m, Kind.REAR, inp, Phase.BACKUP, chained=chained)
        elif inp.leader_lost:
            m = _start(m, Kind.LEADER, inp, Phase.WIDEN, chained=chained)
        else:
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
            return _fenced(inp, p, m)

    return _run_episode(inp, p, m)


def _fenced(inp: RecoveryInputs, p: RecoveryParams, m: RecoveryMemory) -> RecoveryOutput:
    """The controller in charge, except that it may not drive forward back to where the link
    behind broke (FENCE_M) for FENCE_S after a restore, unless RSSI^b rose well above."""
    if m.fence is None or m.fence_t is None:
        return RecoveryOutput(None, m)
    rb = inp.rssi_behind_dbm
    if inp.now_s - m.fence_t > FENCE_S or (
        rb is not None and rb > p.threshold_b_dbm + p.hysteresis_db + FENCE_CLEAR_DB
    ):
        return RecoveryOutput(None, replace(m, fence=None, fence_t=None))
    if (
        inp.pose is not None
        and inp.forward_mm_s > 0
        and math.dist((inp.pose[0], inp.pose[1]), m.fence) < FENCE_M * 1000.0
    ):
        return RecoveryOutput(_zero(DriveState.STOPPED, "rear_fence"), m)
    return RecoveryOutput(None, m)


def _run_episode(inp: RecoveryInputs, p: RecoveryParams, m: RecoveryMemory) -> RecoveryOutput:
    rear = m.kind is Kind.REAR
    lost_state = DriveState.STOPPED if rear else DriveState.LEADER_LOST
    lost_reason = "rear_lost" if rear else "leader_lost"
    if m.incident_t is None:  # an episode always starts one; a memory built by hand may not
        m = replace(
            m,
            incident_t=m.started_t if m.started_t is not None else inp.now_s,
            incident_m=m.distance_m,
        )
    elapsed = inp.now_s - (m.incident_t if m.incident_t is not None else inp.now_s)
    if elapsed >= p.max_time_s:
        m = _close(m, Phase.GAVE_UP, "gave_up_time")
        return RecoveryOutput(_zero(lost_state, lost_reason), m)
    remaining_m = p.max_distance_m - m.incident_m
    if remaining_m <= LIMIT_SLACK_M:
        m = _close(m, Phase.GAVE_UP, "gave_up_distance")
        return RecoveryOutput(_zero(lost_state, lost_reason), m)
    if inputs_stale(inp, p, need_rear=rear):
        return RecoveryOutput(_zero(DriveState.FAULT, "recovery_stale_input"), m)

    if m.phase is Phase.WIDEN:
        if inp.scan_count - m.start_scans < p.widen_scans:
            return RecoveryOutput(_zero(DriveState.LEADER_LOST, "widen"), m)
        m = replace(m, phase=Phase.RETRACE, target=leader_target(m.trail, p.threshold_l_dbm))

    # Drop the crumbs already reached (the newest first); the trail is consumed going back.
    if inp.pose is None:  # inputs_stale checks it; no pose is never a reason to move
        return RecoveryOutput(_zero(DriveState.FAULT, "recovery_stale_input"), m)
    x, y, _ = inp.pose
    trail = m.trail
    while trail and math.hypot(trail[-1].x_mm - x, trail[-1].y_mm - y) < p.reach_m * 1000.0:
        if m.target is not None and m.target >= len(trail) - 1:
            break  # at the leader's crumb: stay here, scanning
        trail = trail[:-1]
    m = replace(m, trail=trail)
    if m.target is not None and m.target >= len(trail):
        m = replace(m, target=len(trail) - 1 if trail else None)
    at_end = not trail or (
        m.target is not None
        and m.target == len(trail) - 1
        and math.hypot(trail[-1].x_mm - x, trail[-1].y_mm - y) < p.reach_m * 1000.0
    )
    if at_end:
        reason = "rear_trail_end" if rear else "retrace_wait"
        return RecoveryOutput(_zero(DriveState.RECOVERING, reason), m)

    speed = p.backup_speed_mm_s if rear else p.retrace_speed_mm_s
    speed = min(speed, remaining_m * 1000.0 / TAPER_S)
    left, right, why = reverse_toward(
        inp.pose,
        trail[-1],
        speed,
        inp.sonar_mm,
        threshold_o_m=p.threshold_o_m,
        stop_distance_m=p.stop_distance_m,
        gamma_o_m=p.gamma_o_m,
        turn_gain_mm_s_deg=p.turn_gain_mm_s_deg,
    )
    reason = ("backup" if rear else "retrace") if why == "retrace" else why
    return RecoveryOutput(RecoveryCommand(left, right, DriveState.RECOVERING, reason), m)


@dataclass(frozen=True, slots=True)
class RecoveryView:
    """What /status and the live page show of recovery (elapsed whole seconds, distance dm)."""

    enabled: bool
    phase: Phase
    kind: Kind | None
    episodes: int
    elapsed_s: float | None
    distance_m: float | None
    max_distance_m: float
    max_time_s: float
    trail_crumbs: int
    last_outcome: str | None

    def to_json(self) -> dict[str, object]:
        """/status's `recovery` object (the enums as their strings)."""
        return {
            "enabled": self.enabled,
            "phase": str(self.phase),
            "kind": None if self.kind is None else str(self.kind),
            "episodes": self.episodes,
            "elapsed_s": self.elapsed_s,
            "distance_m": self.distance_m,
            "max_distance_m": self.max_distance_m,
            "max_time_s": self.max_time_s,
            "trail_crumbs": self.trail_crumbs,
            "last_outcome": self.last_outcome,
        }


def recovery_view(m: RecoveryMemory, p: RecoveryParams, now_s: float) -> RecoveryView:
    active = m.phase in (Phase.WIDEN, Phase.RETRACE, Phase.BACKUP) and m.started_t is not None
    elapsed = float(math.floor(now_s - m.started_t)) if active and m.started_t is not None else None
    return RecoveryView(
        p.enabled,
        m.phase,
        m.kind,
        m.episodes,
        elapsed,
        round(m.distance_m, 1) if active else None,
        p.max_distance_m,
        p.max_time_s,
        len(m.trail),
        m.last_outcome,
    )
