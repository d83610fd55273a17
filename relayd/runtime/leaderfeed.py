"""The leader relay's feed: its GET /path polled, each answer a `LeaderPath` event on the bus.

A relay following a relay (`[control] leader_url`) follows where its leader drove. This
is the one task that reads it: every `poll_s` one GET {leader_url}/path with a timeout,
the answer read in pieces up to `MAX_PATH_BYTES` (drivers/transport/bounded.py),
checked against the Path schema (relayd/api/status.py OwnPath) and published as a
frozen, timestamped `LeaderPath` (our clock at receipt). The loop is the shared
reconnect helper (drivers/transport/reconnect.py): a failure (no answer, refused, not a
path document) backs off, capped at a few seconds, and is logged once per streak. What
a missing or stale feed means for the pursuit is the brain's (relayd/core/trail/feed.py):
it judges by the pose's time, so a feed that answers with an old pose is stale too.

`PathClient` is the fetch alone, so the simulator on virtual time hands in one that
reads the leader relay's daemon in this process (relayd/sim/inproc.py).
"""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import Callable
from typing import Any, Protocol

import aiohttp
import structlog

from drivers.transport.backoff import Backoff
from drivers.transport.bounded import BodyTooLarge, read_bounded
from drivers.transport.clock import Clock
from drivers.transport.health import DeviceHealth, LinkState
from drivers.transport.reconnect import Failure, Reconnect
from relayd.core.events import Event, LeaderPath

log = structlog.get_logger(__name__)

#: A path of 600 points is ~25 kB of JSON; anything past this is not a relay's answer.
MAX_PATH_BYTES = 256 * 1024
#: Points in one answer (the relay publishes its newest 600).
MAX_POINTS = 2000


class FeedError(Exception):
    """The leader's answer is not usable (HTTP status, size, not a path document)."""


class PathClient(Protocol):
    """One GET /path: the body's bytes, or an exception."""

    async def fetch(self) -> bytes: ...

    async def close(self) -> None: ...


class HttpPathClient:
    """GET {url}/path over HTTP (one session, kept between polls)."""

    def __init__(self, url: str) -> None:
        self.url = url.rstrip("/") + "/path"
        self._session: aiohttp.ClientSession | None = None

    async def fetch(self) -> bytes:
        if self._session is None:
            self._session = aiohttp.ClientSession()
        async with self._session.get(self.url) as resp:
            if resp.status != 200:
                raise FeedError(f"HTTP {resp.status}")
            return await read_bounded(resp, MAX_PATH_BYTES)

    async def close(self) -> None:
        if self._session is not None:
            await self._session.close()
            self._session = None


def _number(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise FeedError(f"{where}: not a finite number: {v!r}")
    return float(v)


def parse_path(body: bytes, t: float) -> LeaderPath:
    """A GET /path answer as the event; FeedError names what is wrong with it."""
    try:
        doc = json.loads(body)
    except (ValueError, UnicodeDecodeError) as exc:
        raise FeedError(f"not JSON: {exc}") from None
    if not isinstance(doc, dict) or "pose" not in doc or not isinstance(doc.get("points"), list):
        raise FeedError("not a path document (pose, points)")
    raw = doc["points"]
    if len(raw) > MAX_POINTS:
        raise FeedError(f"{len(raw)} points (at most {MAX_POINTS})")
    points: list[tuple[float, float, float]] = []
    for k, p in enumerate(raw):
        if not isinstance(p, list) or len(p) != 3:
            raise FeedError(f"points[{k}]: not [t, x_m, y_m]")
        where = f"points[{k}]"
        points.append((_number(p[0], where), _number(p[1], where), _number(p[2], where)))
    pose = doc["pose"]
    if pose is None:
        return LeaderPath(t, None, tuple(points))
    if not isinstance(pose, dict):
        raise FeedError("pose: not an object")
    tp, x, y, th = (_number(pose.get(k), f"pose.{k}") for k in ("t", "x_m", "y_m", "theta_deg"))
    return LeaderPath(t, (tp, x, y, th), tuple(points))


def _describe(exc: Exception) -> Failure:
    if isinstance(exc, FeedError | BodyTooLarge):
        return Failure(kind="bad_answer")
    if isinstance(exc, TimeoutError):
        return Failure(kind="no_answer", text="no answer in time")
    if isinstance(exc, aiohttp.ClientError | OSError):
        return Failure(kind="unreachable")
    return Failure(unexpected=True)


class LeaderFeedTask:
    """Polls the leader relay's path until cancelled; `publish` gets each good answer."""

    def __init__(
        self,
        url: str,
        *,
        poll_s: float,
        clock: Clock,
        publish: Callable[[Event], None],
        client: PathClient | None = None,
        timeout_s: float | None = None,
    ) -> None:
        self.url = url
        self.poll_s = poll_s
        self.timeout_s = min(2.0, max(0.5, 2.0 * poll_s)) if timeout_s is None else timeout_s
        self.client: PathClient = client or HttpPathClient(url)
        self._clock = clock
        self._publish = publish
        self._reconnect = Reconnect(
            log.bind(url=url),
            "leader_feed_failed",
            backoff=Backoff(initial_s=poll_s, maximum_s=max(5.0, 4.0 * poll_s)),
            clock=clock,
            remind_s=60.0,
        )
        self._stop = asyncio.Event()  # never set: the task ends by being cancelled
        self.polls = 0
        self.errors = 0
        self.last_t: float | None = None

    def health(self) -> DeviceHealth:
        up = self._reconnect.failures == 0 and self.last_t is not None
        return DeviceHealth(
            device="leader_feed",
            state=LinkState.UP
            if up
            else (LinkState.CONNECTING if self.last_t is None else LinkState.DOWN),
            last_error=self._reconnect.last_error,
            errors=self.errors,
            reconnects=self._reconnect.reconnects,
            last_rx_t=self.last_t,
            counters={"polls": self.polls, "errors": self.errors},
        )

    async def run(self) -> None:
        try:
            await self._reconnect.run(
                self.poll_once,
                self._serve,
                stop=self._stop,
                describe=_describe,
                on_failure=self._failed,
            )
        finally:
            await self.client.close()

    def _failed(self, _exc: Exception, _failure: Failure, _text: str) -> None:
        self.errors += 1

    async def _serve(self) -> None:
        next_t = self._clock.now()
        while True:
            next_t = max(next_t + self.poll_s, self._clock.now())
            await self._clock.sleep(next_t - self._clock.now())
            await self.poll_once()

    async def poll_once(self) -> None:
        """One GET /path, published; raises what went wrong (the loop counts it)."""
        self.polls += 1
        async with self._clock.timeout(self.timeout_s):
            body = await self.client.fetch()
        now = self._clock.now()
        event = parse_path(body, now)
        self.last_t = now
        self._publish(event)
