"""The nl80211 RSSI source: GET_STATION dumps through pyroute2's asyncio socket.

`station_reading` and `observe_stations` turn NL80211_CMD_NEW_STATION messages (or
plain `{'attrs': [...]}` dicts) into what `RssiSource` judges; `Nl80211Source` is the
daemon's default source.
"""

from __future__ import annotations

import asyncio
import errno
import socket
from collections.abc import AsyncIterable, Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from drivers.transport.clock import REAL_CLOCK, Clock
from drivers.wifi.parsers import RSSI_MIN_DBM
from drivers.wifi.sources import InterfaceMissing, Observation, RssiSource, SourceError


@dataclass(frozen=True, slots=True)
class StationReading:
    """The fields of one nl80211 station-info message that the RSSI source uses."""

    mac: str | None
    signal_dbm: int | None
    signal_avg_dbm: int | None
    chain_signal_dbm: tuple[int, ...]
    rx_packets: int | None
    beacon_rx: int | None
    inactive_time_ms: int | None


@runtime_checkable
class _NetlinkMessage(Protocol):
    """What relayd uses of a decoded pyroute2 netlink message."""

    def get_attr(self, name: str) -> Any: ...


def _get_attr(msg: Any, name: str) -> Any:
    """`get_attr` for pyroute2 messages, or a lookup in a plain `{'attrs': [...]}` dict."""
    if msg is None:
        return None
    if isinstance(msg, _NetlinkMessage):
        return msg.get_attr(name)
    if isinstance(msg, dict):
        for pair in msg.get("attrs", ()):
            if len(pair) >= 2 and pair[0] == name:
                return pair[1]
    return None


def _as_int(value: Any) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def station_reading(msg: Any) -> StationReading:
    """Extract a `StationReading` from an NL80211_CMD_NEW_STATION message (or dict)."""
    info = _get_attr(msg, "NL80211_ATTR_STA_INFO")
    chains = _get_attr(info, "NL80211_STA_INFO_CHAIN_SIGNAL")
    mac = _get_attr(msg, "NL80211_ATTR_MAC")
    return StationReading(
        mac=mac if isinstance(mac, str) else None,
        signal_dbm=_as_int(_get_attr(info, "NL80211_STA_INFO_SIGNAL")),
        signal_avg_dbm=_as_int(_get_attr(info, "NL80211_STA_INFO_SIGNAL_AVG")),
        chain_signal_dbm=tuple(c for c in chains if isinstance(c, int))
        if isinstance(chains, list | tuple)
        else (),
        rx_packets=_as_int(_get_attr(info, "NL80211_STA_INFO_RX_PACKETS")),
        beacon_rx=_as_int(_get_attr(info, "NL80211_STA_INFO_BEACON_RX")),
        inactive_time_ms=_as_int(_get_attr(info, "NL80211_STA_INFO_INACTIVE_TIME")),
    )


def observe_stations(msgs: Sequence[Any], bssid: str | None = None) -> Observation:
    """Turn a station dump into an Observation: the AP's last-frame signal + counters."""
    readings = [station_reading(m) for m in msgs]
    if bssid is not None:
        readings = [r for r in readings if r.mac and r.mac.lower() == bssid.lower()]
    if not readings:
        return Observation(None, None, updated=False)
    sta = min(
        readings, key=lambda r: r.inactive_time_ms if r.inactive_time_ms is not None else 1 << 62
    )
    key = (sta.mac, sta.rx_packets, sta.beacon_rx, sta.signal_dbm)
    return Observation(sta.signal_dbm, key, updated=sta.signal_dbm is not None)


def _netlink_errno(exc: BaseException) -> int | None:
    from pyroute2.netlink.exceptions import NetlinkError

    if isinstance(exc, NetlinkError):
        return int(exc.code)
    if isinstance(exc, OSError):
        return exc.errno
    return None


class StationDumper(Protocol):
    """What this source uses of pyroute2's `AsyncIW` (pyroute2 ships no type information)."""

    def close(self) -> None: ...

    async def get_stations(self, ifindex: int) -> AsyncIterable[Any]: ...


def _default_iw_factory() -> StationDumper:
    from pyroute2 import AsyncIW  # pyroute2 >= 0.9.3: the asyncio nl80211 socket

    iw: StationDumper = AsyncIW()
    return iw


class Nl80211Source(RssiSource):
    """nl80211 GET_STATION dump through pyroute2's `AsyncIW` (the default source).

    The signal is `NL80211_STA_INFO_SIGNAL` (last frame, no averaging: right for a
    sweeping Yagi); a sample is new when RX_PACKETS / BEACON_RX / the signal changed.
    The netlink socket is opened lazily and dropped after any failure, so an adapter
    that comes back is picked up on the next read.
    """

    kind = "nl80211"

    def __init__(
        self,
        interface: str,
        *,
        clock: Clock = REAL_CLOCK,
        min_dbm: float = RSSI_MIN_DBM,
        bssid: str | None = None,
        timeout_s: float = 0.5,
        iw_factory: Callable[[], StationDumper] = _default_iw_factory,
        ifindex_of: Callable[[str], int] = socket.if_nametoindex,
    ) -> None:
        super().__init__(interface, clock=clock, min_dbm=min_dbm)
        self.bssid = bssid
        self.timeout_s = timeout_s
        self._iw_factory = iw_factory
        self._ifindex_of = ifindex_of
        self._iw: StationDumper | None = None

    async def close(self) -> None:
        iw, self._iw = self._iw, None
        if iw is not None:
            try:
                iw.close()
            except Exception as exc:  # noqa: BLE001 - closing a dead socket is best effort
                self._log.debug("nl80211_close_failed", error=str(exc))

    async def _dump(self, ifindex: int) -> list[Any]:
        if self._iw is None:
            self._iw = self._iw_factory()
        async with self.clock.timeout(self.timeout_s):
            return [m async for m in await self._iw.get_stations(ifindex)]

    async def _observe(self) -> Observation:
        try:
            ifindex = self._ifindex_of(self.interface)
        except OSError as exc:
            raise InterfaceMissing(f"{self.interface}: {exc.strerror or exc}") from exc
        try:
            msgs = await self._dump(ifindex)
        except TimeoutError as exc:
            await self.close()
            raise SourceError(f"nl80211 station dump timed out after {self.timeout_s} s") from exc
        except (asyncio.CancelledError, KeyboardInterrupt):
            raise
        except Exception as exc:
            await self.close()
            # pyroute2's NetlinkError carries the kernel's errno as `code`; an OSError as errno.
            code = _netlink_errno(exc)
            if code == errno.ENODEV:
                raise InterfaceMissing(f"{self.interface}: nl80211 says no such device") from exc
            if code == errno.ENOENT:
                raise InterfaceMissing(
                    "nl80211 is not available (no cfg80211 wireless "
                    "device or generic netlink family)"
                ) from exc
            if code == errno.EOPNOTSUPP:
                raise InterfaceMissing(f"{self.interface} is not a wireless interface") from exc
            raise SourceError(f"nl80211 station dump failed: {type(exc).__name__}: {exc}") from exc
        return observe_stations(msgs, self.bssid)
