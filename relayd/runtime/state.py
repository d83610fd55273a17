"""The one state object every reader reads.

One writer: `relayd.runtime.statewriter.StateWriter` applies the brain's actions and the
events' raw device data; the HTTP API, the metrics collector, the live page and the
simulator's trace only read it. Device health is not copied in: `health_sources`
are read when a snapshot is taken (see `relayd.runtime.health`), and `health` holds only the
supervisor's own failure records, added on top; both are the drivers' one `DeviceHealth`. Everything here is plain data on the
event loop thread: no locks, and a reader never waits for a device.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Protocol, TypedDict

from drivers.transport.health import DeviceHealth, LinkState
from relayd import __version__
from relayd.core.geometry import SONAR_COUNT
from relayd.core.vocab import DriveState, Mode, ScanRecord

if TYPE_CHECKING:
    from relayd.core.link.model import LinkModelStatus
    from relayd.core.recovery.view import RecoveryView


class RecordingStatus(TypedDict):
    """/status's `recording` object."""

    enabled: bool
    state: str  # off, recording, stopped, failed
    path: str | None
    files: int
    bytes: int
    events: int
    dropped: int
    error: str | None


@dataclass(frozen=True, slots=True)
class LinkInfo:
    """Link quality of one airOS radio, as last polled."""

    signal_dbm: float | None = None
    rssi: float | None = None
    noise_dbm: float | None = None
    ccq_pct: float | None = None
    tx_mbps: float | None = None
    rx_mbps: float | None = None
    t: float | None = None


class Controls(Protocol):
    """What the API may ask of the daemon (the controller task implements it)."""

    def set_mode(self, mode: Mode) -> None: ...

    def manual_drive(self, left_mm_s: float, right_mm_s: float) -> None:
        """Raise `ModeError` unless in manual mode; the command expires after the dead-man time."""


class ModeError(RuntimeError):
    """A request that the current mode does not allow (API: 409)."""


@dataclass(slots=True)
class RelayState:
    """Everything relayd knows right now. Times are clock seconds (see drivers.transport.clock)."""

    started_t: float = 0.0
    mode: Mode = Mode.FOLLOW
    state: DriveState = DriveState.STOPPED
    reason: str = "starting"
    bearing_deg: float | None = None
    #: The bearing's standard deviation from the tracking filter (None: WCA, or no track).
    bearing_sd_deg: float | None = None
    link_bearing_deg: float | None = None
    rssi_leader_dbm: float | None = None
    rssi_behind_dbm: float | None = None
    situation: int = 0
    wheels_left_mm_s: float = 0.0
    wheels_right_mm_s: float = 0.0
    x_mm: float | None = None
    y_mm: float | None = None
    theta_deg: float | None = None
    battery_v: float | None = None
    motors_enabled: bool = False
    sonar_mm: list[int | None] = field(default_factory=lambda: [None] * SONAR_COUNT)
    last_scan: ScanRecord | None = None
    scan_count: int = 0
    links: dict[str, LinkInfo] = field(default_factory=dict)
    #: The supervisor's failure records per device (task failures), added to the driver's view.
    health: dict[str, DeviceHealth] = field(default_factory=dict)
    #: Per device, a function returning the driver's own view of its health, read at snapshot time.
    health_sources: dict[str, Callable[[], DeviceHealth]] = field(default_factory=dict, repr=False)
    loop_tick_t: float | None = None
    #: The recorder's status (relayd.record), read at snapshot time; None: no recorder here.
    recording_source: Callable[[], RecordingStatus] | None = field(default=None, repr=False)
    robot_name: str | None = None
    #: The operator's name for this robot (config `robot.display_name`), e.g. "relay 2 (east)".
    display_name: str | None = None
    thresholds: dict[str, float] = field(default_factory=dict)
    #: The rear-link model's state (relayd.core.link.model), None until its first sample.
    link_model: LinkModelStatus | None = None
    #: The recovery state machine as /status shows it; None while recovery is disabled.
    recovery: RecoveryView | None = None
    #: The leader's trail (relayd/core/trail) as /status shows it, read at snapshot time.
    trail_source: Callable[[], dict[str, Any]] | None = field(default=None, repr=False)
    #: The online pattern learner's progress (`[scan] learn_pattern`), read at snapshot time.
    pattern_source: Callable[[], dict[str, object] | None] | None = field(default=None, repr=False)
    #: This relay's own odometry pose and path (GET /path), read at request time.
    path_source: Callable[[], dict[str, Any]] | None = field(default=None, repr=False)
    #: Bumped on every change a live view cares about; `changed` is set with it.
    revision: int = 0
    changed: asyncio.Event = field(default_factory=asyncio.Event, repr=False)

    def record_failure(self, device: str, message: str) -> DeviceHealth:
        """The supervisor's record of one more failed task of `device`, with its message."""
        old = self.health.get(device) or DeviceHealth(device, LinkState.DOWN)
        new = self.health[device] = replace(old, errors=old.errors + 1, last_error=message)
        return new

    def health_now(self) -> dict[str, DeviceHealth]:
        """Every device's health now: the driver's view plus the supervisor's failure records."""
        out: dict[str, DeviceHealth] = {}
        for name, source in self.health_sources.items():
            out[name] = merge_health(source(), self.health.get(name))
        for name, supervised in self.health.items():
            if name not in out:
                out[name] = supervised
        return out

    def touch(self) -> None:
        """Tell live readers (SSE, trace) that something changed."""
        self.revision += 1
        self.changed.set()
        self.changed = asyncio.Event()

    def snapshot(self, now: float) -> dict[str, Any]:
        """The /status document. No secret is ever stored here, so none can leak."""
        scan = self.last_scan
        return {
            "version": __version__,
            "robot": self.robot_name,
            "display_name": self.display_name,
            "uptime_s": round(now - self.started_t, 3),
            "mode": str(self.mode),
            "state": str(self.state),
            "reason": self.reason,
            "bearing_deg": self.bearing_deg,
            "bearing_sd_deg": self.bearing_sd_deg,
            "link_bearing_deg": self.link_bearing_deg,
            "rssi_leader_dbm": self.rssi_leader_dbm,
            "rssi_behind_dbm": self.rssi_behind_dbm,
            "situation": self.situation,
            "wheels_mm_s": {"left": self.wheels_left_mm_s, "right": self.wheels_right_mm_s},
            "pose": {"x_mm": self.x_mm, "y_mm": self.y_mm, "theta_deg": self.theta_deg},
            "battery_v": self.battery_v,
            "motors_enabled": self.motors_enabled,
            "sonar_mm": list(self.sonar_mm),
            "last_scan": None
            if scan is None
            else {
                "t": scan.t,
                "age_s": round(now - scan.t, 3),
                "angles": list(scan.angles_deg),
                "rssi": list(scan.rssi_dbm),
                "bearing_deg": scan.bearing_deg,
                "rssi_leader_dbm": scan.rssi_leader_dbm,
                "period_s": scan.period_s,
            },
            "scan_count": self.scan_count,
            "links": {
                name: {
                    "signal_dbm": li.signal_dbm,
                    "rssi": li.rssi,
                    "noise_dbm": li.noise_dbm,
                    "ccq_pct": li.ccq_pct,
                    "tx_mbps": li.tx_mbps,
                    "rx_mbps": li.rx_mbps,
                    "age_s": None if li.t is None else round(now - li.t, 3),
                }
                for name, li in self.links.items()
            },
            "health": {
                name: {
                    "connected": h.connected,
                    "age_s": None if (a := h.age_s(now)) is None else round(a, 3),
                    "errors": h.errors,
                    "reconnects": h.reconnects,
                    "last_error": h.last_error,
                }
                for name, h in self.health_now().items()
            },
            "thresholds": dict(self.thresholds),
            "link_model": None if self.link_model is None else self.link_model.to_json(),
            "recording": None if self.recording_source is None else self.recording_source(),
            "recovery": None if self.recovery is None else self.recovery.to_json(),
            "trail": None if self.trail_source is None else self.trail_source(),
            "pattern_learned": None if self.pattern_source is None else self.pattern_source(),
        }


def merge_health(source: DeviceHealth, supervised: DeviceHealth | None) -> DeviceHealth:
    """The driver's view plus the supervisor's failure count and message (neither replaces the other)."""
    if supervised is None:
        return source
    return replace(
        source,
        errors=source.errors + supervised.errors,
        reconnects=source.reconnects + supervised.reconnects,
        last_error=source.last_error or supervised.last_error,
    )
