"""The words the core and everything around it share: modes, drive states, reason codes, scans.

Each code that crosses a boundary (the API, the trace, the metrics, the live page's
phrasebook) is a StrEnum member here, defined once; a member is its string, so documents
and traces read the same as before. tests/core/test_reasons.py checks the phrasebook
(relayd/api/static/reasons.json), the metrics and the code against `Reason`.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum


class Mode(StrEnum):
    FOLLOW = "follow"
    HOLD = "hold"
    MANUAL = "manual"


class DriveState(StrEnum):
    DRIVING = "driving"
    STOPPED = "stopped"
    AVOIDING = "avoiding"
    LEADER_LOST = "leader_lost"
    #: Self-healing a broken link (relayd.core.recovery.machine): backing along the trail.
    RECOVERING = "recovering"
    FAULT = "fault"


class Reason(StrEnum):
    """Why the wheels do what they do: /status's `reason`, the trace's, a metric's label.

    The plain-language phrase of each is in relayd/api/static/reasons.json.
    """

    # driving and following
    DRIVING = "driving"
    STARTING = "starting"
    AVOIDING = "avoiding"
    OBSTACLE = "obstacle"
    BLOCKED = "blocked"
    BACKUP = "backup"
    LEADER_NEAR = "leader_near"
    LEADER_FAR_SONAR = "leader_far_sonar"
    LEADER_LOST = "leader_lost"
    LEADER_SEARCH = "leader_search"
    REAR_WEAK = "rear_weak"
    WIDEN = "widen"
    # trail pursuit (relayd.core.trail)
    TRAIL_HEAD = "trail_head"
    TRAIL_BLOCKED = "trail_blocked"
    # round what the sonar map shows in the way (relayd.core.plan)
    DETOUR = "detour"
    # operator
    HOLD = "hold"
    MANUAL = "manual"
    DEADMAN = "deadman"
    SHUTDOWN = "shutdown"
    # inputs missing or stale: wheels at zero
    NO_SIP = "no_sip"
    NO_SCAN_YET = "no_scan_yet"
    SCAN_STALE = "scan_stale"
    SCAN_SERVO = "scan_servo"
    RSSI_STALE = "rssi_stale"
    REAR_LINK_STALE = "rear_link_stale"
    CONTROLLER_ERROR = "controller_error"
    # retreat to where the link held (relayd.core.link.retreat)
    RETREAT = "retreat"
    RETREAT_HOLD = "retreat_hold"
    RETREAT_STALE_INPUT = "retreat_stale_input"
    # self-healing (relayd.core.recovery)
    REAR_LOST = "rear_lost"
    RETRACE = "retrace"
    RETRACE_WAIT = "retrace_wait"
    REJOINING = "rejoining"
    REAR_BLOCKED = "rear_blocked"
    REAR_FENCE = "rear_fence"
    REAR_OBSTACLE = "rear_obstacle"
    REAR_TRAIL_END = "rear_trail_end"
    RECOVERY_ERROR = "recovery_error"
    RECOVERY_STALE_INPUT = "recovery_stale_input"


#: Where a relay is meant to end a run (docs/CONTROL.md 5): stopped by the paper's link
#: rule (the link ahead strong, or the link behind at its limit, fixed or learned), or still
#: following its leader. Any other end (avoiding, blocked, lost, searching, a fault) means
#: it gave up or is stuck: a run that ends so is not a clean run.
LINK_RULE_ENDS = frozenset(
    {
        Reason.LEADER_NEAR,
        Reason.REAR_WEAK,
        Reason.RETREAT_HOLD,  # the adaptive limit's hold, where the hop met its target
        Reason.DRIVING,
        Reason.LEADER_FAR_SONAR,  # following: the sonar says the leader is farther
        Reason.DETOUR,  # following, round a mapped obstacle (relayd.core.plan)
        Reason.TRAIL_HEAD,  # following: caught up with the trail's head, scanning
    }
)


@dataclass(frozen=True, slots=True)
class ScanRecord:
    """One finished scan: what the Yagi heard where, and what the estimator made of it."""

    t: float
    angles_deg: tuple[float, ...]
    rssi_dbm: tuple[float, ...]
    bearing_deg: float
    rssi_leader_dbm: float
    situation: int
    period_s: float | None = None
