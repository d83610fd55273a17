"""The typed vocabulary of relayd's one event route: events in, actions out.

Device shells turn I/O into *events* and publish them on the bus (`relayd.runtime.bus`); the
brain (`relayd.core.brain`) takes events in order and returns *actions*; the shells turn
actions back into I/O. Every event carries `t`, the clock second it happened (the
brain reads no clock: this is its only time). All are frozen and slotted: cheap to
make at 10-50 Hz, safe to hand to any number of subscribers.

Where a driver already has a frozen record of the data (the ARCOS `Sip`, the Wi-Fi
`RssiSample`, the airOS `LinkQuality`), the event carries it as its payload instead of
copying its fields.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from drivers.airos.model import LinkQuality
from drivers.arcos.sip import Sip
from drivers.wifi.records import RssiSample
from relayd.core.link.model import LinkModelStatus
from relayd.core.recovery.view import RecoveryView
from relayd.core.scan.estimator import ScanEstimate
from relayd.core.vocab import DriveState, Mode, ScanRecord

# -- events ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SipEvent:
    """One server information packet from the base (odometry, sonar, motor flags)."""

    t: float
    sip: Sip
    #: The whole sonar ring after this SIP (a SIP carries only the sonars it updated).
    sonar_mm: tuple[int | None, ...]


@dataclass(frozen=True, slots=True)
class RssiEvent:
    """One read of the Yagi's RSSI source (fresh or not)."""

    t: float
    sample: RssiSample


@dataclass(frozen=True, slots=True)
class ServoPosition:
    """The scan servo reached (or was commanded to) this angle."""

    t: float
    channel: int
    angle_deg: float
    moving: bool


@dataclass(frozen=True, slots=True)
class ScanReady:
    """The scanner is ready for its next sweep (the brain answers with a `ScanPlan`).

    Planned at this moment, not when the last sweep ended, so a turn of the robot
    in between is already in the window's centre.
    """

    t: float


@dataclass(frozen=True, slots=True)
class ScanSampleEvent:
    """One scan sample: where the Yagi pointed (robot frame) when it heard `rssi_dbm`."""

    t: float
    angle_deg: float
    rssi_dbm: float


@dataclass(frozen=True, slots=True)
class ScanDone:
    """The sweep of the last `ScanPlan` ended (`samples` of its samples were taken)."""

    t: float
    started_t: float
    samples: int


class LinkSide(StrEnum):
    REAR = "rear"
    FRONT = "front"


@dataclass(frozen=True, slots=True)
class LinkEvent:
    """One poll of an airOS radio."""

    t: float
    side: LinkSide
    quality: LinkQuality


class DeviceStatus(StrEnum):
    UP = "up"
    DOWN = "down"
    FAULT = "fault"


@dataclass(frozen=True, slots=True)
class DeviceEvent:
    """A device came up, went down (no data, link lost) or failed (e.g. no answer)."""

    t: float
    device: str
    status: DeviceStatus
    detail: str | None = None


@dataclass(frozen=True, slots=True)
class ModeCommand:
    """The operator asks for a mode."""

    t: float
    mode: Mode


@dataclass(frozen=True, slots=True)
class DriveCommand:
    """The operator's manual wheel speeds (manual mode only; expires after the dead-man time)."""

    t: float
    left_mm_s: float
    right_mm_s: float


@dataclass(frozen=True, slots=True)
class Tick:
    """The control timer: runs the fail-safes when nothing else happens (silence must stop the robot)."""

    t: float


@dataclass(frozen=True, slots=True)
class LeaderPath:
    """One answer of the leader relay's GET /path (its odometry frame, its clock's times).

    `t` is when this relay received it (our clock); `pose` is the leader's newest pose
    (t_s, x_m, y_m, theta_deg), None before its first SIP; `points` its driven path
    (t_s, x_m, y_m), oldest first.
    """

    t: float
    pose: tuple[float, float, float, float] | None
    points: tuple[tuple[float, float, float], ...]


@dataclass(frozen=True, slots=True)
class Shutdown:
    """The daemon stops: never command the wheels again."""

    t: float


Event = (
    SipEvent
    | RssiEvent
    | ServoPosition
    | ScanReady
    | ScanSampleEvent
    | ScanDone
    | LinkEvent
    | DeviceEvent
    | ModeCommand
    | DriveCommand
    | Tick
    | LeaderPath
    | Shutdown
)

# -- actions ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class WheelCommand:
    """Wheel speeds to command. `stop`: the urgent stop (jumps any queue).

    `sip_t` is the time of the SIP whose handling produced this command, None when a
    timer, a scan or the operator caused it: only SIP-caused commands have a control
    latency.
    """

    left_mm_s: float
    right_mm_s: float
    stop: bool
    sip_t: float | None


@dataclass(frozen=True, slots=True)
class ServoTarget:
    """Point a servo channel at an angle (the link antenna at the leader)."""

    channel: int
    angle_deg: float


@dataclass(frozen=True, slots=True)
class ScanPlan:
    """The next sweep: these angles in this order (robot frame)."""

    angles_deg: tuple[float, ...]


@dataclass(frozen=True, slots=True)
class Decision:
    """One control step's outcome, for the state (wheels, state, reason, situation, mode)."""

    t: float
    left_mm_s: float
    right_mm_s: float
    state: DriveState
    reason: str
    situation: int
    mode: Mode
    #: The state or the reason differs from the step before (a log line, a live-view update).
    changed: bool


@dataclass(frozen=True, slots=True)
class RearLink:
    """RSSI^b as the controller now sees it (None: unknown or stale)."""

    rssi_behind_dbm: float | None


@dataclass(frozen=True, slots=True)
class ScanResult:
    """A finished scan and its estimate, for the state, the metrics and the logs."""

    record: ScanRecord
    estimate: ScanEstimate


@dataclass(frozen=True, slots=True)
class LinkModelView:
    """The rear limit in force and the rear-link model's state (relayd.core.link.model), for /status."""

    threshold_b_dbm: float
    model: LinkModelStatus


@dataclass(frozen=True, slots=True)
class RecoveryReport:
    """The recovery state machine's phase and progress changed (relayd.core.recovery.machine)."""

    view: RecoveryView


Action = (
    WheelCommand
    | ServoTarget
    | ScanPlan
    | Decision
    | ScanResult
    | RearLink
    | RecoveryReport
    | LinkModelView
)
