"""Device health as /status and /metrics show it, read from the drivers when asked.

Nothing copies driver counters into the state on a timer any more (a copy every 0.5 s
once overwrote the supervisor's failure counts). Each device has a *health source*, a
function read at snapshot time that asks the driver's own `health()`; the
supervisor's counts (task failures) live beside it in `RelayState.health` and are
added on top (`relayd.runtime.state.merge_health`), so neither side can overwrite the other.

`device_health` adapts a driver's `drivers.transport.health.DeviceHealth` (the one health
record, which /status and /metrics read too) to what the daemon knows around the driver.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Protocol

from drivers.transport.health import DeviceHealth, LinkState
from relayd.core.events import DeviceStatus

HealthSource = Callable[[], DeviceHealth]


class HasHealth(Protocol):
    def health(self) -> DeviceHealth: ...


def device_status(h: DeviceHealth) -> DeviceStatus:
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
    # Connected but not usable reads as STALE: /status and /metrics show it not connected.
    state = LinkState.STALE if h.state is LinkState.UP and not usable else h.state
    return replace(
        h,
        state=state,
        last_rx_t=h.last_rx_t if last_data_t is None else last_data_t,
        errors=h.errors + extra_errors,
    )
