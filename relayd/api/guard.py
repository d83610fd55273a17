"""The API's accept loop, guarded so that API traffic can never stop the robot.

The API shares the process, its event loop and its file descriptors with the device
drivers. Served the plain way (aiohttp's TCPSite), anyone on the bridge could open
about a thousand idle connections and exhaust the descriptors: the RSSI source then
fails with EMFILE, the robot stops on stale RSSI, and asyncio logs the failed accept
thousands of times a second. So relayd runs its own accept loop in front of aiohttp:

- at most `MAX_CONNECTIONS` API connections. At the cap a new connection evicts the
  connection idle longest (no request in progress for `EVICT_IDLE_S`); with none
  idle, accepting pauses and new connections wait in the kernel's listen backlog,
  which costs the process nothing;
- a connection with no request in progress for `IDLE_TIMEOUT_S` is closed: that
  covers clients that connect and send nothing, send their headers slowly, or keep
  an idle keep-alive connection (TLS handshakes have the same deadline);
- descriptors reserved for the devices: each connection is booked in the process's one
  descriptor account (relayd/runtime/fdbudget.py), shared with every other listener
  (the live Foxglove view); a connection the account cannot take, or whose descriptor
  number reaches the soft RLIMIT_NOFILE minus `FD_RESERVE`, is closed at once and
  accepting pauses;
- accept errors (EMFILE and the like) pause accepting for a second, and every refusal
  is logged at most once a minute with a count, never once per attempt.
  (relayd/api/server.py does the same for asyncio's own accept loop.)

The sockets are then handed to aiohttp's request handler, unchanged, through a thin
protocol that reports when a connection ends; a middleware marks requests in progress.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import socket
import ssl
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, cast

import structlog
from aiohttp import web

from relayd.runtime.fdbudget import FD_RESERVE, FdBudget
from relayd.runtime.ratelimit import LogRateLimit

log = structlog.get_logger(__name__)

#: Concurrent API connections. A relay's clients are a few browsers on the live page,
#: Prometheus and the odd `relayd status`; 100 leaves room for a whole convoy's tools.
MAX_CONNECTIONS = 100
__all__ = ["FD_RESERVE", "MAX_CONNECTIONS", "GuardedServer"]
#: A connection with no request in progress is closed after this long.
IDLE_TIMEOUT_S = 10.0
#: At the cap, a connection idle this long may be closed to admit a new one.
EVICT_IDLE_S = 1.0
#: Accepts per wake-up of the event loop: a connect storm cannot hog a device's turn.
ACCEPT_BATCH = 16
#: Pause after an accept failed for lack of resources (asyncio's own value).
ACCEPT_RETRY_S = 1.0
SWEEP_S = 0.5
#: Refusals and accept errors are logged at most once per this period, with a count.
LOG_EVERY_S = 60.0
#: The API's name in the descriptor account.
BUDGET_OWNER = "api"
_RESOURCE_ERRNOS = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})


@dataclass(slots=True, eq=False)
class _Conn:
    sock: socket.socket
    peer: str
    idle_since: float
    busy: int = 0
    transport: asyncio.Transport | None = None
    handler: asyncio.Protocol | None = None
    task: asyncio.Task[Any] | None = None
    closing: bool = False


class _Relay(asyncio.Protocol):
    """aiohttp's request handler behind a protocol that tells the guard when the connection ends."""

    def __init__(self, guard: GuardedServer, conn: _Conn, inner: asyncio.Protocol) -> None:
        self._guard = guard
        self._conn = conn
        self._inner = inner

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # connect_accepted_socket makes a stream transport (plain or TLS): it can abort.
        self._conn.transport = cast(asyncio.Transport, transport)
        self._conn.handler = self._inner
        self._guard.handlers[self._inner] = self._conn
        self._inner.connection_made(transport)

    def data_received(self, data: bytes) -> None:
        self._inner.data_received(data)

    def eof_received(self) -> bool | None:
        return self._inner.eof_received()

    def connection_lost(self, exc: Exception | None) -> None:
        self._guard.drop(self._conn)
        self._inner.connection_lost(exc)

    def pause_writing(self) -> None:
        self._inner.pause_writing()

    def resume_writing(self) -> None:
        self._inner.resume_writing()


class GuardedServer:
    """The accept loop in front of aiohttp (see the module docstring)."""

    def __init__(
        self,
        *,
        max_connections: int = MAX_CONNECTIONS,
        idle_timeout_s: float = IDLE_TIMEOUT_S,
        evict_idle_s: float = EVICT_IDLE_S,
        fd_limit: int | None = None,
        budget: FdBudget | None = None,
    ) -> None:
        self.max_connections = max_connections
        self.idle_timeout_s = idle_timeout_s
        self.evict_idle_s = evict_idle_s
        #: The process's descriptor account, shared with the other listeners.
        self.budget = budget or FdBudget.for_process()
        #: Accepted descriptors numbered at or above this are refused.
        self.fd_limit = self.budget.fd_limit if fd_limit is None else fd_limit
        self.conns: set[_Conn] = set()
        self.handlers: dict[asyncio.BaseProtocol, _Conn] = {}
        self.counters = {
            "accepted": 0,
            "evicted": 0,
            "idle_closed": 0,
            "refused": 0,
            "accept_errors": 0,
        }
        self._factory: Callable[[], asyncio.Protocol] | None = None
        self._listen: socket.socket | None = None
        self._ssl: ssl.SSLContext | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._reading = False
        self._backoff_until = 0.0
        self._sweeper: asyncio.Task[None] | None = None
        self._limit = LogRateLimit(LOG_EVERY_S)

    # -- aiohttp side -------------------------------------------------------------------

    @web.middleware
    async def middleware(
        self, request: web.Request, handler: Callable[[web.Request], Awaitable[web.StreamResponse]]
    ) -> web.StreamResponse:
        """Marks the connection busy while a request is handled (an event stream stays busy)."""
        conn = self.handlers.get(request.protocol)
        if conn is None:
            return await handler(request)
        conn.busy += 1
        try:
            return await handler(request)
        finally:
            conn.busy -= 1
            conn.idle_since = asyncio.get_running_loop().time()

    # -- life cycle -----------------------------------------------------------------------

    def start(
        self,
        sock: socket.socket,
        factory: Callable[[], asyncio.Protocol],
        ssl_context: ssl.SSLContext | None = None,
    ) -> None:
        self._loop = asyncio.get_running_loop()
        self._listen, self._factory, self._ssl = sock, factory, ssl_context
        sock.setblocking(False)
        self._resume()
        self._sweeper = self._loop.create_task(self._sweep(), name="relayd:api-sweep")

    async def close(self) -> None:
        """Stop accepting; connections are left to aiohttp's shutdown, stragglers closed after."""
        self._pause()
        if self._listen is not None:
            self._listen.close()
            self._listen = None
        if self._sweeper is not None:
            self._sweeper.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._sweeper
            self._sweeper = None

    def abort_all(self) -> None:
        for conn in list(self.conns):
            if conn.task is not None and not conn.task.done():
                conn.task.cancel()
            if conn.transport is not None:
                conn.transport.abort()
            else:
                conn.sock.close()
            self.drop(conn)

    # -- accepting ------------------------------------------------------------------------

    def _resume(self) -> None:
        if not self._reading and self._listen is not None and self._loop is not None:
            self._loop.add_reader(self._listen.fileno(), self._on_readable)
            self._reading = True

    def _pause(self) -> None:
        if self._reading and self._listen is not None and self._loop is not None:
            self._loop.remove_reader(self._listen.fileno())
        self._reading = False

    def _backoff(self, now: float) -> None:
        self._pause()
        self._backoff_until = now + ACCEPT_RETRY_S

    def _active(self) -> int:
        return sum(1 for c in self.conns if not c.closing)

    def _note(self, event: str, now: float, key: str, **kw: Any) -> None:
        count = self._limit.hit(key, now)
        if count is not None:
            log.warning(event, count=count, every_s=LOG_EVERY_S, **kw)

    def _on_readable(self) -> None:
        if self._loop is None or self._listen is None:
            return  # not started, or closed: nothing to accept on
        now = self._loop.time()
        for _ in range(ACCEPT_BATCH):
            if self._active() >= self.max_connections and not self._evict(now):
                self._pause()  # the rest wait in the listen backlog; resumed when a slot frees
                self._note(
                    "api_connections_at_cap", now, "cap", max_connections=self.max_connections
                )
                return
            try:
                sock, addr = self._listen.accept()
            except (BlockingIOError, InterruptedError, ConnectionAbortedError):
                return
            except OSError as exc:
                self.counters["accept_errors"] += 1
                self._note("api_accept_failed", now, f"accept:{exc.errno}", error=str(exc))
                if exc.errno in _RESOURCE_ERRNOS:
                    self._backoff(now)
                return
            if sock.fileno() >= self.fd_limit or not self.budget.take(BUDGET_OWNER):
                sock.close()
                self.counters["refused"] += 1
                self._note(
                    "api_connection_refused",
                    now,
                    "fds",
                    fd_limit=self.fd_limit,
                    reason="descriptors reserved for the devices",
                )
                self._backoff(now)
                return
            sock.setblocking(False)
            peer = str(addr[0]) if isinstance(addr, tuple) else str(addr)
            conn = _Conn(sock=sock, peer=peer, idle_since=now)
            self.conns.add(conn)
            self.counters["accepted"] += 1
            conn.task = self._loop.create_task(self._connect(conn))

    async def _connect(self, conn: _Conn) -> None:
        if self._loop is None or self._factory is None:
            conn.sock.close()  # the guard closed before this connection was set up
            self.drop(conn)
            return
        factory = self._factory
        try:
            await self._loop.connect_accepted_socket(
                lambda: _Relay(self, conn, factory()),
                sock=conn.sock,
                ssl=self._ssl,
                ssl_handshake_timeout=self.idle_timeout_s if self._ssl is not None else None,
            )
        except Exception as exc:  # noqa: BLE001 - whatever a client did, it must not escape the task
            # A failed TLS handshake or a peer gone before we started: nothing to serve.
            log.debug(
                "api_connection_setup_failed", peer=conn.peer, error=str(exc) or type(exc).__name__
            )
            conn.sock.close()
            self.drop(conn)

    def _evict(self, now: float) -> bool:
        """Close the connection idle longest, if one has been idle long enough; True if one was."""
        idle = [
            c
            for c in self.conns
            if not c.closing
            and c.busy == 0
            and c.transport is not None
            and now - c.idle_since >= self.evict_idle_s
        ]
        if not idle:
            return False
        victim = min(idle, key=lambda c: c.idle_since)
        self.counters["evicted"] += 1
        self._close(victim)
        return True

    def _close(self, conn: _Conn) -> None:
        conn.closing = True
        if conn.transport is not None:
            conn.transport.close()

    def drop(self, conn: _Conn) -> None:
        if conn in self.conns:
            self.conns.remove(conn)
            self.budget.give(BUDGET_OWNER)
        if conn.handler is not None:
            self.handlers.pop(conn.handler, None)
        if (
            self._loop is not None
            and not self._reading
            and self._loop.time() >= self._backoff_until
            and self._active() < self.max_connections
        ):
            self._resume()

    async def _sweep(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            await asyncio.sleep(SWEEP_S)
            now = loop.time()
            for conn in list(self.conns):
                if (
                    not conn.closing
                    and conn.busy == 0
                    and conn.transport is not None
                    and now - conn.idle_since > self.idle_timeout_s
                ):
                    self.counters["idle_closed"] += 1
                    self._close(conn)
            if not self._reading and now >= self._backoff_until:
                # At the cap, resume once someone could be evicted; the accept path re-checks.
                self._resume()
