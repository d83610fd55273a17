"""Device health as /status and /metrics show it, read from the drivers when asked.

Nothing copies driver counters into the state on a timer any more (a copy every 0.5 s
once overwrote the supervisor's failure counts). Each device has a *health source*, a
function read at snapshot time that asks the driver's own `health()`; the
supervisor's counts (task failures) live beside it in `RelayState.health` and are
added on top (`relayd.runtime.state.merge_health`), so neither side can overwrite the other.

`device_health` is the one adapter from a driver's `drivers.transport.health.DeviceHealth` to
the daemon's view of it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from drivers.transport.health import DeviceHealth as DriverHealth
from drivers.transport.health import LinkState
from relayd.core.events import DeviceStatus
from relayd.runtime.state import DeviceHealth

HealthSource = Callable[[], DeviceHealth]


class HasHealth(Protocol):
    def health(self) -> DriverHealth: ...


def device_status(h: DriverHealth) -> DeviceStatus:
    """What a driver's health means on the bus: UP when its data are usable, FAULT when its
    last attempt failed (it retries on backoff), DOWN otherwise (connecting, quiet, closed)."""
    if h.state is LinkState.UP:
        return DeviceStatus.UP
    if h.state is LinkState.DOWN:
        return DeviceStatus.FAULT
    return DeviceStatus.DOWN


def device_health(
    driver: HasHealth,
    *,
    usable: bool = True,
    extra_errors: int = 0,
    last_data_t: float | None = None,
) -> DeviceHealth:
    """The driver's health now. `usable=False` marks a connected device the daemon cannot
    use (the scan servo not answering the scanner); `extra_errors` are failures counted
    around the driver (the link servo's); `last_data_t` overrides the driver's last
    reception time when the daemon knows better (the last *fresh* RSSI sample)."""
    h = driver.health()
    return DeviceHealth(
        connected=h.connected and usable,
        last_data_t=h.last_rx_t if last_data_t is None else last_data_t,
        errors=h.errors + extra_errors,
        reconnects=h.reconnects,
        last_error=h.last_error,
    )
