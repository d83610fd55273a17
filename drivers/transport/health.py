"""A driver's own account of its device's health, as one frozen value.

Every long-running driver (robot base, pan-tilt, airOS poller, RSSI source) answers
`health()` with a `DeviceHealth`: a snapshot the daemon reads as it is, instead of
copying attributes one by one on a timer (a copy once overwrote counts kept by
someone else). A snapshot is immutable, so a reader may keep it, compare it with the
next one or hand it to another task without a lock.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from types import MappingProxyType


class LinkState(StrEnum):
    """Where a driver's link to its device stands."""

    #: Never connected yet, or reconnecting after a clean end; no failure so far.
    CONNECTING = "connecting"
    #: Connected and the device answers.
    UP = "up"
    #: Connected, but the device has gone quiet (no data within its limit).
    STALE = "stale"
    #: The last attempt failed; retrying on backoff.
    DOWN = "down"
    #: Shut down on purpose; it will not reconnect.
    CLOSED = "closed"


def _frozen_counters(counters: Mapping[str, int]) -> Mapping[str, int]:
    return MappingProxyType(dict(counters))


@dataclass(frozen=True, slots=True)
class DeviceHealth:
    """One device's health at one moment.

    `connected` is the one flag an operator needs: the device is connected *and*
    its data are usable now (state UP). `errors` is the driver's count of failures of
    any kind since it started, `reconnects` the sessions opened after the first,
    `last_rx_t` the clock time of the last data from the device (None before any).
    `counters` holds the driver's detailed counters, read-only.
    """

    device: str
    state: LinkState
    last_error: str | None = None
    errors: int = 0
    reconnects: int = 0
    last_rx_t: float | None = None
    counters: Mapping[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "counters", _frozen_counters(self.counters))

    @property
    def connected(self) -> bool:
        return self.state is LinkState.UP

    def age_s(self, now: float) -> float | None:
        """Seconds since the device last sent data, None before it ever did."""
        return None if self.last_rx_t is None else max(0.0, now - self.last_rx_t)
