"""The recovery's vocabulary: phases, settings, inputs, memory, and a step's verdict.

relayd.core.recovery.machine (the transition table) and relayd.core.recovery.episode (what
a running episode does) read and write these; docs/CONTROL.md section 9 has the design.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import StrEnum

from relayd.core.control.law import ControlParams
from relayd.core.recovery.trail import TrailPoint
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
    #: The controller's params, the same value the law drives by: its thresholds, stop
    #: distances and staleness limits (the brain hands in the rear limit in force).
    control: ControlParams = field(default_factory=ControlParams)
    lost_rssi_dbm: float = -85.0
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
    trail: tuple[TrailPoint, ...] = ()
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


def stale(age: float | None, limit: float | None) -> bool:
    if limit is None:
        return False
    return age is None or not math.isfinite(age) or age > limit


def inputs_stale(inp: RecoveryInputs, p: RecoveryParams, *, need_rear: bool) -> bool:
    """Any input the episode relies on older than its limit (or missing)."""
    if inp.pose is None or not all(math.isfinite(v) for v in inp.pose):
        return True
    if stale(inp.sip_age_s, p.control.sip_timeout_s) or stale(
        inp.rssi_age_s, p.control.rssi_timeout_s
    ):
        return True
    # `not <=` so that a NaN age is stale too (a broken clock is no reason to move).
    if (
        p.scan_timeout_s is not None
        and inp.scan_age_s is not None
        and not inp.scan_age_s <= p.scan_timeout_s
    ):
        return True
    rear_needed = need_rear or p.control.rear_link_required
    return rear_needed and (
        stale(inp.rear_age_s, p.control.rear_timeout_s) or inp.rssi_behind_dbm is None
    )


def close(m: RecoveryMemory, phase: Phase, outcome: str) -> RecoveryMemory:
    return replace(
        m,
        phase=phase,
        last_outcome=outcome,
        target=None,
        kind=m.kind if phase is Phase.GAVE_UP else None,
    )


def zero(state: DriveState, reason: str) -> RecoveryCommand:
    return RecoveryCommand(0.0, 0.0, state, reason)
