"""One task per relay polls its /status; a slow or dead relay only ever delays itself.

Each `RelayPoller` owns its loop: GET /status with its own timeout, keep the last good
document and when it came, or the error of the last attempt. The fleet page reads
the pollers' memory and never waits on a relay. A relay that refuses connections is
known at the next poll; one that accepts and says nothing (a paused process, a dead
link that still completes TCP handshakes on a bridge) is known after `timeout_s`.
Times are the fleet machine's clock; the relays' clocks are never compared with it.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import aiohttp
import structlog

from drivers.transport.bounded import read_bounded
from drivers.transport.clock import REAL_CLOCK, Clock
from relayd.fleet.config import Relay

log = structlog.get_logger(__name__)

#: A relay's /status is a few kB; a peer streaming more is refused (it would take the
#: fleet server's memory with it).
MAX_STATUS_BYTES = 1 << 20

#: One pose a second for five minutes: the trail on the fleet map.
TRAIL_PERIOD_S = 1.0
TRAIL_LEN = 300


@dataclass(slots=True)
class RelayView:
    """What the fleet knows of one relay right now."""

    relay: Relay
    doc: dict[str, Any] | None = None
    ok_t: float | None = None  # when `doc` arrived
    attempt_t: float | None = None  # when the last attempt ended
    error: str | None = None  # of the last attempt; None after a success
    error_kind: str | None = None  # "no_answer", "unreachable" or "bad_answer"
    latency_s: float | None = None
    polls: int = 0
    failures: int = 0
    trail: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=TRAIL_LEN))
    trail_t: float | None = None


class RelayPoller:
    """Poll one relay forever on its own task."""

    def __init__(
        self,
        relay: Relay,
        session: aiohttp.ClientSession,
        *,
        poll_s: float,
        timeout_s: float,
        clock: Clock = REAL_CLOCK,
    ) -> None:
        self.view = RelayView(relay)
        self.session = session
        self.poll_s = poll_s
        self.timeout_s = timeout_s
        self.clock = clock

    async def poll_once(self) -> None:
        view, relay = self.view, self.view.relay
        t0 = self.clock.now()
        try:
            async with (
                asyncio.timeout(self.timeout_s),
                self.session.get(relay.url + "/status") as resp,
            ):
                if resp.status != 200:
                    raise RuntimeError(f"HTTP {resp.status}")
                doc = json.loads(await read_bounded(resp, MAX_STATUS_BYTES))
            if not isinstance(doc, dict) or "state" not in doc:
                raise RuntimeError("not a relayd status document")
        except TimeoutError:
            self._failed("no_answer", f"no answer within {self.timeout_s:g} s")
            return
        except (aiohttp.ClientConnectorError, ConnectionError) as exc:
            self._failed("unreachable", short_error(exc))
            return
        except (aiohttp.ClientError, ValueError, RuntimeError, OSError) as exc:
            self._failed("bad_answer", short_error(exc))
            return
        now = self.clock.now()
        if view.error is not None and view.polls:
            log.info("fleet_relay_back", relay=relay.name, after=view.error)
        view.doc, view.ok_t, view.attempt_t, view.error, view.error_kind = doc, now, now, None, None
        view.latency_s = now - t0
        view.polls += 1
        self._trail(doc, now)

    def _failed(self, kind: str, message: str) -> None:
        view = self.view
        if view.error != message:
            log.warning(
                "fleet_relay_down",
                relay=view.relay.name,
                url=view.relay.url,
                kind=kind,
                error=message,
            )
        view.error, view.error_kind, view.attempt_t = message, kind, self.clock.now()
        view.failures += 1
        view.polls += 1

    def _trail(self, doc: dict[str, Any], now: float) -> None:
        view = self.view
        pose = doc.get("pose") or {}
        x, y = pose.get("x_mm"), pose.get("y_mm")
        if not (
            isinstance(x, int | float)
            and isinstance(y, int | float)
            and math.isfinite(x)
            and math.isfinite(y)
        ):
            return
        if view.trail_t is None or now - view.trail_t >= TRAIL_PERIOD_S:
            view.trail.append((float(x), float(y)))
            view.trail_t = now

    async def run(self) -> None:
        while True:
            started = self.clock.now()
            try:
                await self.poll_once()
            except Exception:  # a poller must outlive any surprise in one answer
                log.exception("fleet_poll_error", relay=self.view.relay.name)
            await self.clock.sleep(max(0.0, self.poll_s - (self.clock.now() - started)))


def short_error(exc: BaseException) -> str:
    """A one-line cause: "Connection refused" rather than aiohttp's paragraph."""
    if isinstance(exc, aiohttp.ClientConnectorError):
        text = exc.os_error.strerror or str(exc.os_error) or type(exc.os_error).__name__
    else:
        text = str(exc) or type(exc).__name__
    return text if len(text) <= 160 else text[:157] + "..."


class Fleet:
    """All pollers, their tasks and the one HTTP session they share (no shared lock or queue)."""

    def __init__(
        self,
        relays: tuple[Relay, ...],
        *,
        poll_s: float,
        timeout_s: float,
        stale_after_s: float = 2.0,
        clock: Clock = REAL_CLOCK,
    ) -> None:
        self.relays = relays
        self.poll_s, self.timeout_s, self.stale_after_s = poll_s, timeout_s, stale_after_s
        self.clock = clock
        self.session: aiohttp.ClientSession | None = None
        self.pollers: list[RelayPoller] = []
        self._tasks: list[asyncio.Task[None]] = []

    async def start(self) -> None:
        # Per-host connection limits would let one hung relay hold sockets others need: none.
        self.session = aiohttp.ClientSession(
            connector=aiohttp.TCPConnector(limit=0, limit_per_host=4)
        )
        self.pollers = [
            RelayPoller(
                r, self.session, poll_s=self.poll_s, timeout_s=self.timeout_s, clock=self.clock
            )
            for r in self.relays
        ]
        self._tasks = [
            asyncio.create_task(p.run(), name=f"fleet-poll-{p.view.relay.name}")
            for p in self.pollers
        ]

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._tasks = []
        if self.session is not None:
            await self.session.close()
            self.session = None

    def views(self) -> list[RelayView]:
        return [p.view for p in self.pollers]
