"""Device health as /status and /metrics show it, read from the drivers when asked.

Nothing copies driver counters into the state on a timer any more (a copy every 0.5 s
once overwrote the supervisor's failure counts). Each device has a *health source*, a
function read at snapshot time; the supervisor's own counts (task failures) live
beside it in `RelayState.health` and are added on top, so neither side can overwrite
the other.

`device_health` is the one adapter between a driver and a `DeviceHealth`: when the
drivers grow their own `health()`, this is the only place that changes.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Protocol

from relayd.state import DeviceHealth

HealthSource = Callable[[], DeviceHealth]


class RobotLike(Protocol):
    @property
    def connected(self) -> bool: ...
    @property
    def stale(self) -> bool: ...
    @property
    def counters(self) -> dict[str, int]: ...
    @property
    def last_error(self) -> str | None: ...


class PanTiltLike(Protocol):
    @property
    def connected(self) -> bool: ...
    @property
    def counters(self) -> dict[str, int]: ...
    @property
    def last_error(self) -> str | None: ...
    @property
    def last_reply_t(self) -> float | None: ...


class PollerLike(Protocol):
    @property
    def state(self) -> str: ...
    @property
    def counters(self) -> dict[str, int]: ...
    @property
    def last_error(self) -> str | None: ...
    @property
    def last_update_t(self) -> float | None: ...


class RssiSourceLike(Protocol):
    @property
    def available(self) -> bool: ...
    @property
    def errors(self) -> int: ...
    @property
    def rejected(self) -> int: ...
    @property
    def last_error(self) -> str | None: ...


def _sum(counters: Mapping[str, int], *keys: str) -> int:
    return sum(int(counters.get(k, 0)) for k in keys)


def robot_health(robot: RobotLike, last_sip_t: float | None) -> DeviceHealth:
    c = robot.counters
    return DeviceHealth(
        connected=bool(robot.connected) and not bool(robot.stale),
        last_data_t=last_sip_t,
        errors=sum(int(v) for k, v in c.items() if k.endswith(("errors", "resyncs"))),
        reconnects=int(c.get("reconnects", 0)),
        last_error=robot.last_error,
    )


def pantilt_health(pt: PanTiltLike, servo_ok: bool, extra_errors: int = 0) -> DeviceHealth:
    c = pt.counters
    return DeviceHealth(
        connected=bool(pt.connected) and servo_ok,
        last_data_t=pt.last_reply_t,
        errors=_sum(c, "timeouts", "errors") + extra_errors,
        reconnects=int(c.get("reconnects", 0)),
        last_error=pt.last_error,
    )


def poller_health(poller: PollerLike) -> DeviceHealth:
    c = poller.counters
    return DeviceHealth(
        connected=poller.state == "ok",
        last_data_t=poller.last_update_t,
        errors=int(c.get("errors", 0)),
        reconnects=int(c.get("relogins", 0)),
        last_error=poller.last_error,
    )


def wifi_health(source: RssiSourceLike, last_fresh_t: float | None) -> DeviceHealth:
    return DeviceHealth(
        connected=bool(source.available),
        last_data_t=last_fresh_t,
        errors=int(source.errors) + int(source.rejected),
        last_error=source.last_error,
    )
