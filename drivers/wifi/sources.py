"""RSSI sources for the Yagi's Wi-Fi adapter: /proc/net/wireless and `iw` text here,
nl80211 in `nl80211.py`.

All three sit behind `RssiSource`: `await read()` gives one `RssiSample` now,
`stream(sample_hz)` gives samples on the clock. The base class owns the rules the
daemon relies on, so every source behaves the same:

* freshness: `fresh=True` only when the source saw a new update since the previous
  `read()` of the same object (a changed counter/line, never a timer);
* plausibility: impossible levels (0, -128, -256, positive, below `min_dbm`) are
  counted in `rejected` and never passed on (`rssi_dbm=None, fresh=False`);
* failure: a missing interface or a failing read sets `available=False` /
  `last_error`, counts in `errors`, returns an empty sample, and is retried on the
  next read. Nothing but cancellation escapes `read()` or `stream()`.
"""

from __future__ import annotations

import abc
import asyncio
import os
from collections.abc import AsyncIterator, Hashable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import structlog

from drivers.transport.clock import REAL_CLOCK, Clock
from drivers.transport.health import DeviceHealth, LinkState
from drivers.wifi.parsers import (
    RSSI_MIN_DBM,
    parse_iw_link,
    parse_iw_stations,
    parse_proc_net_wireless,
    plausible_rssi_dbm,
    wrap_u8_dbm,
)
from drivers.wifi.records import RssiSample

log = structlog.get_logger(__name__)

PROC_NET_WIRELESS = "/proc/net/wireless"


class InterfaceMissing(Exception):
    """The wireless interface is not there (unplugged adapter, renamed, wrong name)."""


class SourceError(Exception):
    """A read failed for another reason (timeout, tool error, unreadable file)."""


@dataclass(frozen=True, slots=True)
class Observation:
    """What one poll of the device showed, before the base class judges it.

    `level_dbm` None means "associated to nothing / no level". `update_key` is
    anything that changes when the device received a new frame (counters, the text
    line); `updated` is False when the device itself says the value is old.
    """

    level_dbm: float | None
    update_key: Hashable
    updated: bool = True


class RssiSource(abc.ABC):
    """Common behaviour of the RSSI sources; subclasses implement `_observe()`."""

    kind: ClassVar[str]

    def __init__(
        self, interface: str, *, clock: Clock = REAL_CLOCK, min_dbm: float = RSSI_MIN_DBM
    ) -> None:
        self.interface = interface
        self.clock = clock
        self.min_dbm = min_dbm
        self.samples = 0  # fresh, accepted samples
        self.rejected = 0  # updates carrying an impossible value
        self.errors = 0  # reads that failed (interface missing, I/O, timeout)
        self.reads = 0
        self.available = False
        self.associated = False
        self.last_error: str | None = None
        #: Clock time of the last fresh, accepted sample (None before any).
        self.last_sample_t: float | None = None
        self._prev_key: Hashable = None
        self._have_prev = False

    @property
    def _log(self) -> Any:
        # Bound at use, not in __init__: the daemon may configure structlog after
        # building its sources, and a bound logger freezes the configuration.
        return log.bind(source=self.kind, interface=self.interface)

    @property
    def counters(self) -> dict[str, int]:
        return {
            "reads": self.reads,
            "samples": self.samples,
            "rejected": self.rejected,
            "errors": self.errors,
        }

    def health(self) -> DeviceHealth:
        """The adapter's health now (see drivers.transport.health).

        UP while the interface is there and associated; STALE when it is there but
        not associated (no level to read); DOWN when reads fail.
        """
        if self.available:
            state = LinkState.UP if self.associated else LinkState.STALE
        else:
            state = LinkState.DOWN if self.errors else LinkState.CONNECTING
        return DeviceHealth(
            device="wifi",
            state=state,
            last_error=self.last_error,
            errors=self.errors + self.rejected,
            reconnects=0,
            last_rx_t=self.last_sample_t,
            counters=self.counters,
        )

    @abc.abstractmethod
    async def _observe(self) -> Observation:
        """Poll the device once; raise InterfaceMissing or SourceError on failure."""

    async def close(self) -> None:
        """Release resources (sockets); the source can still be read afterwards."""
        return

    async def read(self) -> RssiSample:
        """One sample now. Never raises except on cancellation."""
        t = self.clock.now()
        self.reads += 1
        try:
            obs = await self._observe()
        except InterfaceMissing as exc:
            return self._fail(t, f"interface missing: {exc}", vanished=True)
        except SourceError as exc:
            return self._fail(t, str(exc), vanished=False)
        except Exception as exc:  # noqa: BLE001 - a bad read must never end the scanner task
            self._log.exception("wifi_read_unexpected_error")
            return self._fail(t, f"{type(exc).__name__}: {exc}", vanished=False)
        if not self.available:
            self._log.info("wifi_source_available")
        self.available = True
        self.last_error = None
        return self._judge(t, obs)

    def _fail(self, t: float, message: str, *, vanished: bool) -> RssiSample:
        self.errors += 1
        if message != self.last_error:
            self._log.warning("wifi_read_failed", error=message)
        else:
            self._log.debug("wifi_read_failed", error=message)
        self.last_error = message
        if vanished:
            self.available = False
            self.associated = False
            # Whatever the interface shows when it comes back is new to us.
            self._have_prev = False
        return RssiSample(t, None, False)

    def _judge(self, t: float, obs: Observation) -> RssiSample:
        new = obs.updated and (not self._have_prev or obs.update_key != self._prev_key)
        self._prev_key = obs.update_key
        self._have_prev = True
        if obs.level_dbm is None:
            if self.associated:
                self._log.warning("wifi_not_associated")
            self.associated = False
            self.last_error = "not associated"
            return RssiSample(t, None, False)
        self.associated = True
        level = wrap_u8_dbm(float(obs.level_dbm))
        good = plausible_rssi_dbm(level, min_dbm=self.min_dbm)
        if not new:
            return RssiSample(t, level if good else None, False)
        if not good:
            self.rejected += 1
            self._log.info("wifi_rssi_rejected", raw=obs.level_dbm, dbm=level)
            return RssiSample(t, None, False)
        self.samples += 1
        self.last_sample_t = t
        return RssiSample(t, level, True)

    async def stream(self, sample_hz: float) -> AsyncIterator[RssiSample]:
        """Samples at `sample_hz` on the clock, forever; never raises but CancelledError."""
        if not sample_hz > 0:
            raise ValueError(f"sample_hz must be > 0, got {sample_hz!r}")
        period = 1.0 / sample_hz
        deadline = self.clock.now()
        while True:
            yield await self.read()
            deadline += period
            delay = deadline - self.clock.now()
            if delay < 0:
                # Fell behind (slow read, busy loop): restart the grid, don't burst.
                deadline = self.clock.now()
                delay = 0.0
            await self.clock.sleep(delay)


# --------------------------------------------------------------------------------------


class ProcfsSource(RssiSource):
    """The level column of /proc/net/wireless (or any file in that format).

    A sample is new when the level carries the '.' UPDATED mark and the interface's
    row differs from the previous read: cfg80211 prints the mark on every read, so the
    mark alone cannot tell a repeat; a changed row (level or a drop/failure counter)
    can. The fake `ProcfsWriter` bumps a counter on every update for this reason.
    """

    kind = "procfs"

    def __init__(
        self,
        interface: str,
        *,
        path: str | os.PathLike[str] = PROC_NET_WIRELESS,
        clock: Clock = REAL_CLOCK,
        min_dbm: float = RSSI_MIN_DBM,
    ) -> None:
        super().__init__(interface, clock=clock, min_dbm=min_dbm)
        self.path = Path(path)

    async def _observe(self) -> Observation:
        # A small text file (procfs or tmpfs): reading it inline is faster than a thread hop.
        try:
            text = self.path.read_text(encoding="ascii", errors="replace")
        except FileNotFoundError as exc:
            # No /proc/net/wireless at all means no wireless extension device either.
            raise InterfaceMissing(f"{self.path} does not exist") from exc
        except OSError as exc:
            raise SourceError(f"cannot read {self.path}: {exc}") from exc
        row = parse_proc_net_wireless(text).get(self.interface)
        if row is None:
            raise InterfaceMissing(f"{self.interface} not listed in {self.path}")
        if not row.level_updated and row.level == 0:
            # Not associated (or not in managed mode): the kernel prints zeros, no marks.
            return Observation(None, row.line, updated=False)
        return Observation(row.level, row.line, updated=row.level_updated)


# --------------------------------------------------------------------------------------


class IwSource(RssiSource):
    """`iw` text through a subprocess: diagnostics and a fallback without netlink code.

    `mode="link"` runs `iw dev IF link`, `"dump"` `iw dev IF station dump`, `"get"`
    `iw dev IF station get BSSID`. New = the rx packet / beacon counters or the signal
    changed.
    """

    kind = "iw"

    def __init__(
        self,
        interface: str,
        *,
        clock: Clock = REAL_CLOCK,
        min_dbm: float = RSSI_MIN_DBM,
        iw_path: str = "iw",
        mode: str = "link",
        bssid: str | None = None,
        timeout_s: float = 1.0,
    ) -> None:
        super().__init__(interface, clock=clock, min_dbm=min_dbm)
        if mode not in ("link", "dump", "get"):
            raise ValueError(f"iw mode must be link, dump or get, got {mode!r}")
        if mode == "get" and not bssid:
            raise ValueError("iw mode 'get' needs the bssid")
        self.iw_path = iw_path
        self.mode = mode
        self.bssid = bssid
        self.timeout_s = timeout_s

    def command(self) -> list[str]:
        base = [self.iw_path, "dev", self.interface]
        if self.mode == "link":
            return [*base, "link"]
        if self.mode == "dump":
            return [*base, "station", "dump"]
        return [*base, "station", "get", str(self.bssid)]

    async def _run(self) -> str:
        argv = self.command()
        try:
            proc = await asyncio.create_subprocess_exec(
                *argv,
                stdin=asyncio.subprocess.DEVNULL,
                stdout=asyncio.subprocess.PIPE,
                stderr=asyncio.subprocess.PIPE,
                env={**os.environ, "LC_ALL": "C"},
            )
        except OSError as exc:
            raise SourceError(f"cannot run {self.iw_path}: {exc}") from exc
        try:
            async with self.clock.timeout(self.timeout_s):
                out, err = await proc.communicate()
        except TimeoutError as exc:
            proc.kill()
            await proc.wait()
            raise SourceError(f"{' '.join(argv)} timed out after {self.timeout_s} s") from exc
        except asyncio.CancelledError:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
            raise
        stderr = err.decode("utf-8", "replace").strip()
        if "No such device" in stderr or "No such device" in out.decode("utf-8", "replace"):
            raise InterfaceMissing(stderr or "No such device")
        if proc.returncode != 0:
            raise SourceError(f"{' '.join(argv)} exited {proc.returncode}: {stderr[:200]}")
        return out.decode("utf-8", "replace")

    async def _observe(self) -> Observation:
        text = await self._run()
        if self.mode == "link":
            link = parse_iw_link(text)
            if link is None:
                raise SourceError(f"unrecognised `iw link` output: {text[:80]!r}")
            if not link.connected:
                return Observation(None, None, updated=False)
            return Observation(
                link.signal_dbm,
                (link.rx_packets, link.signal_dbm),
                updated=link.signal_dbm is not None,
            )
        stations = parse_iw_stations(text)
        if self.bssid is not None:
            stations = [s for s in stations if s.mac.lower() == self.bssid.lower()]
        if not stations:
            return Observation(None, None, updated=False)
        # Several peers (not the managed-mode case): the one heard most recently.
        sta = min(
            stations,
            key=lambda s: s.inactive_time_ms if s.inactive_time_ms is not None else 1 << 62,
        )
        key = (sta.mac, sta.rx_packets, sta.beacon_rx, sta.signal_dbm)
        return Observation(sta.signal_dbm, key, updated=sta.signal_dbm is not None)
