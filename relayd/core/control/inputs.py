"""What one control step reads, hands on and decides: the law's typed route.

`ControlInputs` is one snapshot of everything the controller looks at (the brain builds
it from the events it folded), `ControlMemory` what a step hands to the next (its one
writer is relayd.core.control.law.control_step), `ControlOutput` the wheel command and
why. Kept apart from the law so that a reader sees the route before the rules.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from relayd.core.avoid.state import AvoidState
from relayd.core.control.search import SearchState
from relayd.core.scan.estimator import SonarReading
from relayd.core.trail.blocked import BlockedState
from relayd.core.vocab import DriveState, Mode


@dataclass(frozen=True, slots=True)
class ControlInputs:
    """One snapshot of everything the controller looks at."""

    mode: Mode
    sip_age_s: float | None  # None: no SIP yet
    rssi_age_s: float | None  # age of the newest fresh RSSI sample; None: none yet
    scan_servo_ok: bool
    # Latest scan bearing, already corrected into the current robot frame; None before the first scan.
    bearing_deg: float | None
    prev_bearing_deg: float | None  # the scan before (B'), same frame
    rssi_leader_dbm: float | None
    rssi_behind_dbm: float | None
    rear_age_s: float | None  # age of RSSI^b; None: never received
    front_sonar: tuple[SonarReading, ...]
    leader_lost: bool
    manual_left_mm_s: float | None = None
    manual_right_mm_s: float | None = None
    manual_age_s: float | None = None
    #: Time of this step (s, the caller's clock) and the odometry pose (mm, mm, deg):
    #: the escape's progress watchdog and limits need them; None disables the escape.
    t_s: float | None = None
    odom: tuple[float, float, float] | None = None
    #: The backward-looking rear sonars (`ring.rear_readings`): the escape backs off
    #: only when they show room behind.
    rear_sonar: tuple[SonarReading, ...] = ()
    #: The least distance (m) the front sonars allow the leader (`rangecue.leader_floor_m`);
    #: None: no floor (bearing off the nose, unsure, ring not read).
    leader_floor_m: float | None = None
    #: While the leader is lost: where the scans last put it, in this frame (None: nowhere).
    search_bearing_deg: float | None = None
    #: Trail pursuit: the target's bearing on the trail (None: steer by the scan bearing),
    #: and whether the relay caught up with the trail's head (it then holds and scans).
    trail_steer_deg: float | None = None
    trail_caught_up: bool = False
    #: How far along the trail the head still is (m; else to the leader's estimate).
    trail_remaining_m: float | None = None
    #: A detour round what the sonar map shows in the straight way (relayd/core/plan):
    #: the bearing of its path's lookahead point (None: the way is clear, no detour).
    detour_steer_deg: float | None = None


@dataclass(frozen=True, slots=True)
class ControlMemory:
    """What one control step hands to the next."""

    #: Stop-rule latch: True while the link rule allows driving (hysteresis).
    link_drive: bool = False
    #: Previous steering angle used for the D term in situation 1.
    prev_steer_deg: float | None = None
    #: The escape state machine (relayd/core/avoid/escape.py); reset whenever the robot may not drive.
    avoid: AvoidState = field(default_factory=AvoidState)
    #: True while the sonar floor overrules "leader_near" (its hysteresis).
    sonar_release: bool = False
    #: The lost leader's search (relayd/core/control/search.py); reset once the leader is found, and by
    #: hold, manual and every fault.
    search: SearchState = field(default_factory=SearchState)
    trail_block: BlockedState = field(default_factory=BlockedState)
    #: A detour's progress watch: where (mm) and when it last got 0.3 m on (steer.py).
    detour_anchor: tuple[float, float, float] | None = None
    #: When the leader was lost (s); None while it is found.
    lost_t: float | None = None


@dataclass(frozen=True, slots=True)
class ControlOutput:
    """The wheel command of one step and why."""

    left_mm_s: float
    right_mm_s: float
    state: DriveState
    reason: str  # short snake_case cause
    situation: int
    memory: ControlMemory


def stopped(state: DriveState, reason: str, situation: int, memory: ControlMemory) -> ControlOutput:
    """Wheels at zero, and the memory of a step that did not follow."""
    return ControlOutput(0.0, 0.0, state, reason, situation, not_driving(memory))


def not_driving(memory: ControlMemory) -> ControlMemory:
    """The memory of a step that did not follow: no D-term angle, no escape, no release."""
    return replace(memory, prev_steer_deg=None, avoid=AvoidState(), sonar_release=False)
