"""The serial session with a servo controller: one port, one request at a time.

`ServoSession` owns the serial port that both servos (scan and link) share: every
command goes through one `asyncio.Lock`, a request registers its reply waiter before
writing, a reply is exactly the length the back-end says, and `max_timeouts`
unanswered requests in a row turn into a disconnect, so `run()` reconnects with
backoff (the loop itself is `Reconnect.run`, drivers/transport/reconnect.py). A port given up is closed, bounded,
before the next one opens (its flock). `health()` reports all of it. What the commands
mean, servos in degrees, is `PanTilt` (base.py) and the back-ends.
"""

from __future__ import annotations

import abc
import asyncio
import contextlib
from typing import ClassVar

import structlog

from drivers.transport.backoff import Backoff
from drivers.transport.clock import REAL_CLOCK, Clock
from drivers.transport.health import DeviceHealth, LinkState
from drivers.transport.link import LinkError, close_link, open_link
from drivers.transport.reconnect import Failure, Reconnect, expecting

log = structlog.get_logger(__name__)

#: Replies are awaited at least this long in *wall* seconds: pty and USB latency do
#: not shrink when the simulator runs its clock faster than real time.
MIN_REAL_REPLY_S = 0.05
#: Bytes kept while waiting for a reply; anything beyond is line noise.
MAX_RX_BUFFER = 256


class PanTiltError(Exception):
    """A servo command could not be carried out: not connected, no reply, bad reply."""


#: What ends a connection as device trouble; anything else is a bug.
_describe = expecting(PanTiltError, LinkError)


class ReplyError(ValueError):
    """A controller reply that does not decode (wrong length, impossible value)."""


class _SerialProtocol(asyncio.Protocol):
    """One connection's events, forwarded to its session; never raises into the event loop.

    A fresh protocol per connection: the serial transport reports connection_lost
    from a background task, possibly after the driver has reconnected, and a late
    report from an old port must not be taken for the loss of the new one.
    """

    def __init__(self, owner: ServoSession) -> None:
        self._owner = owner
        #: Set by connection_lost: this connection's port is really closed.
        self.closed = asyncio.Event()

    def data_received(self, data: bytes) -> None:
        if self._owner._proto is self:
            self._owner._on_data(data)
        else:
            self._owner.counters["stray_bytes"] += len(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self.closed.set()
        # A port given up earlier that has finished closing is no news about the current one.
        if self._owner._proto is self:
            self._owner._on_lost(exc)


class ServoSession(abc.ABC):
    """The connection to one serial servo controller: connect, request/reply, reconnect.

    Call `run()` as a long-lived task (it connects, polls the controller for health,
    and reconnects with backoff), or `connect()` once for a one-shot tool. A subclass
    says how to prove the controller answers (`_on_connected`) and how to poll it
    (`_poll`), and sends its frames with `_write` and `_request`.
    """

    protocol_name: ClassVar[str] = ""

    def __init__(
        self,
        url: str,
        baud: int,
        *,
        clock: Clock = REAL_CLOCK,
        reply_timeout_s: float = 0.25,
        max_timeouts: int = 3,
        poll_s: float = 1.0,
        backoff: Backoff | None = None,
    ) -> None:
        self.url = url
        self.baud = int(baud)
        self._clock = clock
        self.reply_timeout_s = reply_timeout_s
        self.max_timeouts = max_timeouts
        self.poll_s = poll_s
        self._backoff = backoff or Backoff(initial_s=0.2, maximum_s=5.0)
        self._log = log.bind(device="pantilt", protocol=self.protocol_name, port=url)
        self._reconnect = Reconnect(
            self._log, "pantilt_connect_failed", backoff=self._backoff, clock=clock, url=url
        )
        self._lock = asyncio.Lock()
        self._transport: asyncio.Transport | None = None
        self._proto: _SerialProtocol | None = None
        # Links given up (silent controller) whose port may not be closed yet.
        self._dropped: list[tuple[asyncio.Transport, _SerialProtocol]] = []
        # Connected = port open AND the controller answered the handshake.
        self._ready = False
        self._handshaking = False
        self._lost = asyncio.Event()
        self._lost.set()
        self._rx = bytearray()
        self._waiter: tuple[int, asyncio.Future[bytes]] | None = None
        self._consecutive_timeouts = 0
        self._closed = False
        self._close_requested = asyncio.Event()
        self._ever_connected = False
        self.last_error: str | None = None
        #: Clock time of the controller's last complete reply (its proof of life).
        self.last_reply_t: float | None = None
        # "clamped" counts PanTilt's angles beyond a servo's limits: one dict for health().
        self.counters: dict[str, int] = {
            "commands": 0,
            "timeouts": 0,
            "errors": 0,
            "reconnects": 0,
            "clamped": 0,
            "stray_bytes": 0,
        }

    @abc.abstractmethod
    async def _on_connected(self) -> None:
        """Prove the controller answers and restore per-connection settings."""

    @abc.abstractmethod
    async def _poll(self) -> None:
        """Periodic health check while connected (a silent controller is dropped)."""

    @property
    def connected(self) -> bool:
        return self._transport is not None and self._ready

    @property
    def answering(self) -> bool:
        """Connected, and the latest request got its reply (no timeout since)."""
        return self.connected and self._consecutive_timeouts == 0

    async def connect(self) -> None:
        """Open the port once and check that the controller answers."""
        if self.connected:
            return
        # The previous port must be closed (its flock released) before we open again.
        await self._close_dropped()
        transport, proto = await open_link(self.url, self.baud, lambda: _SerialProtocol(self))
        self._transport, self._proto = transport, proto
        self._lost.clear()
        self._rx.clear()
        self._consecutive_timeouts = 0
        self._handshaking = True
        try:
            await self._on_connected()
        except BaseException:
            await self._drop()
            raise
        finally:
            self._handshaking = False
        self._ready = True
        if self._ever_connected:
            self.counters["reconnects"] += 1
        self._ever_connected = True
        self._log.info("pantilt_connected", reconnects=self.counters["reconnects"])

    async def run(self) -> None:
        """Connect, poll, reconnect with backoff, until `close()`; raises only CancelledError."""
        self._closed = False
        self._close_requested.clear()
        try:
            # A replugged adapter is retried as soon as its path is back.
            await self._reconnect.run(
                self.connect,
                self._serve,
                stop=self._close_requested,
                describe=_describe,
                on_failure=self._failed,
            )
        finally:
            await self._drop()

    async def close(self) -> None:
        """Close the port; a running `run()` returns instead of reconnecting."""
        self._closed = True
        self._reconnect.close()
        self._close_requested.set()
        await self._drop()

    # ---- session internals ---------------------------------------------------------

    async def _serve(self) -> None:
        # The handshake has just proved the controller answers: first poll after poll_s.
        while self.connected and not self._closed:
            with contextlib.suppress(TimeoutError):
                async with self._clock.timeout(self.poll_s):
                    await self._lost.wait()
            if self.connected and not self._closed:
                with contextlib.suppress(PanTiltError):
                    await self._poll()
        if not self._closed:
            self._log.warning("pantilt_link_lost", error=self.last_error)

    def _failed(self, exc: Exception, failure: Failure, text: str) -> None:
        # A PanTiltError was counted where it was raised; a bug is loud (logged with
        # its traceback) but must not end the servo task.
        if isinstance(exc, LinkError) or failure.unexpected:
            self._note_error(text)

    async def _drop(self) -> None:
        self._ready = False
        transport, self._transport = self._transport, None
        proto, self._proto = self._proto, None
        self._fail_waiter(PanTiltError("connection closed"))
        try:
            if transport is not None and proto is not None:
                self._dropped.append((transport, proto))
            # Wait for the port to really close before anyone reopens it (flock), and
            # close it ourselves if the transport's background close does not come.
            await self._close_dropped()
        finally:
            self._lost.set()

    async def _close_dropped(self) -> None:
        while self._dropped:
            # Taken off the list first: close() and run() may both be closing ports.
            transport, proto = self._dropped.pop(0)
            if not await close_link(transport, proto.closed, abort=True):
                self._log.warning("pantilt_close_forced")

    def _note_error(self, message: str) -> None:
        self.counters["errors"] += 1
        self.last_error = message

    def _fail_waiter(self, exc: Exception) -> None:
        if self._waiter is not None and not self._waiter[1].done():
            self._waiter[1].set_exception(exc)

    def _on_data(self, data: bytes) -> None:
        waiter = self._waiter
        if waiter is None or waiter[1].done():
            self.counters["stray_bytes"] += len(data)
            return
        self._rx += data
        if len(self._rx) > MAX_RX_BUFFER:
            self.counters["stray_bytes"] += len(self._rx) - MAX_RX_BUFFER
            del self._rx[:-MAX_RX_BUFFER]
        size, fut = waiter
        if len(self._rx) >= size:
            reply = bytes(self._rx[:size])
            extra = len(self._rx) - size
            self._rx.clear()
            if extra:
                self.counters["stray_bytes"] += extra
            fut.set_result(reply)

    def _on_lost(self, exc: Exception | None) -> None:
        self._proto = None
        if self._transport is not None:
            self._note_error(f"link lost: {exc}" if exc else "link closed")
        self._transport = None
        self._ready = False
        self._fail_waiter(PanTiltError(f"link lost: {exc}" if exc else "link closed"))
        self._lost.set()

    def _require_transport(self) -> asyncio.Transport:
        if (
            self._transport is None
            or self._transport.is_closing()
            or not (self._ready or self._handshaking)
        ):
            raise PanTiltError(f"pan-tilt controller on {self.url} is not connected")
        return self._transport

    async def _write(self, frame: bytes) -> None:
        """Send a command that has no reply."""
        async with self._lock:
            self._require_transport().write(frame)
            self.counters["commands"] += 1

    async def _request(self, frame: bytes, reply_len: int) -> bytes:
        """Send `frame` and return exactly `reply_len` reply bytes, or raise PanTiltError."""
        async with self._lock:
            transport = self._require_transport()
            fut: asyncio.Future[bytes] = asyncio.get_running_loop().create_future()
            # A late reply to an earlier, timed-out request must not answer this one.
            self._rx.clear()
            self._waiter = (reply_len, fut)
            timeout_s = max(self.reply_timeout_s, MIN_REAL_REPLY_S * self._clock.speed)
            try:
                transport.write(frame)
                self.counters["commands"] += 1
                async with self._clock.timeout(timeout_s):
                    reply = await fut
            except TimeoutError:
                self._on_timeout(frame)
                raise PanTiltError(
                    f"no reply to {frame!r} within {self.reply_timeout_s} s from {self.url}"
                ) from None
            finally:
                self._waiter = None
                self._rx.clear()
        self._consecutive_timeouts = 0
        self._backoff.reset()
        self.last_reply_t = self._clock.now()
        return reply

    def _on_timeout(self, frame: bytes) -> None:
        self.counters["timeouts"] += 1
        self._consecutive_timeouts += 1
        self._note_error(f"no reply to {frame!r}")
        self._log.warning(
            "pantilt_reply_timeout", frame=frame.hex(" "), consecutive=self._consecutive_timeouts
        )
        if self._consecutive_timeouts >= self.max_timeouts and self._transport is not None:
            self._log.warning("pantilt_silent_dropping_link", timeouts=self._consecutive_timeouts)
            self._note_error(f"controller silent: {self._consecutive_timeouts} unanswered requests")
            self._consecutive_timeouts = 0
            self._ready = False
            transport, self._transport = self._transport, None
            proto, self._proto = self._proto, None
            if not transport.is_closing():
                # (Aborting a closing serial transport would start a second close task.)
                transport.abort()
            if proto is not None:
                # connect() waits for this port to close (bounded) before it reopens.
                self._dropped.append((transport, proto))
            # Wake _serve: this link is over (its own connection_lost is ignored now).
            self._lost.set()

    def _reply_error(self, exc: ReplyError) -> PanTiltError:
        self._note_error(f"bad reply: {exc}")
        self._log.warning("pantilt_bad_reply", error=str(exc))
        return PanTiltError(f"bad reply from {self.url}: {exc}")

    def health(self) -> DeviceHealth:
        """The servo controller's health now (see drivers.transport.health)."""
        if self._closed:
            state = LinkState.CLOSED
        elif self.connected:
            state = LinkState.UP if self._consecutive_timeouts == 0 else LinkState.STALE
        else:
            state = (
                LinkState.DOWN
                if self.counters["errors"] or self.counters["timeouts"]
                else LinkState.CONNECTING
            )
        return DeviceHealth(
            device="pantilt",
            state=state,
            last_error=self.last_error,
            errors=self.counters["timeouts"] + self.counters["errors"],
            reconnects=self.counters["reconnects"],
            last_rx_t=self.last_reply_t,
            counters=self.counters,
        )
