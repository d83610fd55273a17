"""The gate in front of the live Foxglove server: a client cap, a handshake deadline,
the shared descriptor account, and log lines at a bounded rate.

The Foxglove SDK's WebSocket server accepts every TCP connection it is offered and
keeps it, with no cap and no deadline for the handshake: a thousand connections that
never sent a byte once took the process to its descriptor limit, a device could not
reopen, and the SDK's accept loop died for good without a word. The SDK has no
setting for any of that, so relayd listens on `[foxglove]`'s address itself and
relays to the SDK, which listens on an ephemeral loopback port:

- at most `MAX_CLIENTS` clients; beyond that a new connection is closed at once;
- a client must send its whole WebSocket upgrade request (at most `MAX_REQUEST_BYTES`)
  within `HANDSHAKE_S`, or it is closed;
- each client costs `FDS_PER_CLIENT` descriptors (its socket, ours to the SDK and the
  SDK's end of it), booked in the process's one descriptor account
  (relayd/runtime/fdbudget.py) that the API books in too: a client the account cannot
  take is closed at once, so the devices keep their reserve whoever fills the rest;
- refusals are logged at most once a minute with a count;
- the SDK's listener is watched: when it stops accepting, the live server restarts it
  (`on_upstream_refused`) and /status shows the count and the reason (health "foxglove").

The gate runs its own event loop on a thread of its own, as the SDK runs on its own
threads: relaying a viewer's bytes never takes a turn of the daemon's loop. It relays
with flow control both ways (a client that stops reading pauses our reads from the SDK,
whose own bounded backlog then drops that client's oldest messages). Its loop's own
reports (a failed accept under descriptor exhaustion) are rate-limited like the rest.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
from collections.abc import Callable
from typing import Any, cast

import structlog

from relayd.runtime.fdbudget import FdBudget
from relayd.runtime.ratelimit import LogRateLimit

log = structlog.get_logger(__name__)

#: Live viewers at once: a relay has an operator or two, not a crowd.
MAX_CLIENTS = 8
#: Seconds a new connection has to send its whole upgrade request.
HANDSHAKE_S = 5.0
#: An upgrade request longer than this is not a Foxglove app's.
MAX_REQUEST_BYTES = 16 * 1024
#: The client's socket, ours to the SDK, and the SDK's end of that connection.
FDS_PER_CLIENT = 3
#: The gate's name in the descriptor account.
BUDGET_OWNER = "foxglove"
LOG_EVERY_S = 60.0
#: Our reads from either side pause while the other side has this much unsent.
HIGH_WATER = 256 * 1024


class _Front(asyncio.Protocol):
    """A viewer's connection: held until its upgrade request is whole, then relayed."""

    def __init__(self, gate: LiveGate) -> None:
        self.gate = gate
        self.transport: asyncio.Transport | None = None
        self.back: _Back | None = None
        self.request = bytearray()
        self.booked = False
        self.timer: asyncio.TimerHandle | None = None
        self.closed = False

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.Transport, transport)
        self.transport.set_write_buffer_limits(high=HIGH_WATER)
        gate = self.gate
        sock = transport.get_extra_info("socket")
        fileno = sock.fileno() if sock is not None else -1
        why = gate.admit(self, fileno)
        if why is not None:
            gate.refused(why)
            self.transport.abort()
            return
        self.booked = True
        self.timer = asyncio.get_running_loop().call_later(gate.handshake_s, self._late)

    def _late(self) -> None:
        if self.back is None and not self.closed:
            self.gate.note("foxglove_handshake_timeout", "late", handshake_s=self.gate.handshake_s)
            self.gate.counters["late"] += 1
            self.close()

    def data_received(self, data: bytes) -> None:
        if self.back is not None and self.back.transport is not None:
            self.back.transport.write(data)
            return
        self.request += data
        if len(self.request) > self.gate.max_request_bytes:
            self.gate.refused("request too long")
            self.close()
        elif b"\r\n\r\n" in self.request and self.back is None:
            self.back = _Back(self)
            task = asyncio.get_running_loop().create_task(self.gate.connect_upstream(self.back))
            self.gate.tasks.add(task)  # held until done: the loop keeps only a weak reference
            task.add_done_callback(self.gate.tasks.discard)

    def upstream_ready(self) -> None:
        if self.timer is not None:
            self.timer.cancel()
        if self.back is not None and self.back.transport is not None:
            self.back.transport.write(bytes(self.request))
        self.request.clear()

    def pause_writing(self) -> None:
        if self.back is not None and self.back.transport is not None:
            self.back.transport.pause_reading()

    def resume_writing(self) -> None:
        if self.back is not None and self.back.transport is not None:
            self.back.transport.resume_reading()

    def connection_lost(self, exc: Exception | None) -> None:  # noqa: ARG002 - asyncio's signature
        self.close()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        if self.timer is not None:
            self.timer.cancel()
        if self.transport is not None:
            self.transport.abort()
        if self.back is not None and self.back.transport is not None:
            self.back.transport.abort()
        self.gate.release(self)


class _Back(asyncio.Protocol):
    """Our connection to the SDK on loopback, for one viewer."""

    def __init__(self, front: _Front) -> None:
        self.front = front
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.Transport, transport)
        self.transport.set_write_buffer_limits(high=HIGH_WATER)
        if self.front.closed:
            self.transport.abort()
            return
        self.front.upstream_ready()

    def data_received(self, data: bytes) -> None:
        if self.front.transport is not None and not self.front.closed:
            self.front.transport.write(data)

    def pause_writing(self) -> None:
        if self.front.transport is not None:
            self.front.transport.pause_reading()

    def resume_writing(self) -> None:
        if self.front.transport is not None:
            self.front.transport.resume_reading()

    def connection_lost(self, exc: Exception | None) -> None:  # noqa: ARG002 - asyncio's signature
        self.front.close()


class LiveGate:
    """Listens on `[foxglove]`'s address and relays admitted clients to `upstream_port`."""

    def __init__(
        self,
        budget: FdBudget,
        upstream_port: int,
        *,
        on_upstream_refused: Callable[[], int | None] | None = None,
        max_clients: int = MAX_CLIENTS,
        handshake_s: float = HANDSHAKE_S,
        max_request_bytes: int = MAX_REQUEST_BYTES,
    ) -> None:
        self.budget = budget
        self.upstream_port = upstream_port
        #: Called when the SDK refuses a connection: restarts it, returns its new port (or None).
        self.on_upstream_refused = on_upstream_refused
        self.max_clients = max_clients
        self.handshake_s = handshake_s
        self.max_request_bytes = max_request_bytes
        self.clients: set[_Front] = set()
        self.tasks: set[asyncio.Task[None]] = set()
        self.counters = {"accepted": 0, "refused": 0, "late": 0, "upstream_failed": 0}
        self.last_error: str | None = None
        self._server: asyncio.Server | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._limit = LogRateLimit(LOG_EVERY_S)

    @property
    def listening(self) -> bool:
        return (
            self._thread is not None
            and self._thread.is_alive()
            and self._server is not None
            and self._server.is_serving()
        )

    def start(self, sock: socket.socket) -> None:
        """Serve on an already bound, listening socket, from the gate's own thread."""
        ready = threading.Event()
        failed: list[BaseException] = []

        def serve() -> None:
            loop = asyncio.new_event_loop()
            self._loop = loop
            loop.set_exception_handler(self._loop_report)
            try:
                self._server = loop.run_until_complete(
                    loop.create_server(lambda: _Front(self), sock=sock)
                )
            except BaseException as exc:  # noqa: BLE001 - handed to start()'s caller
                failed.append(exc)
                ready.set()
                loop.close()
                return
            ready.set()
            try:
                loop.run_forever()
            finally:
                self._server.close()
                for front in list(self.clients):
                    front.close()
                with contextlib.suppress(Exception):
                    loop.run_until_complete(asyncio.sleep(0))
                loop.close()

        self._thread = threading.Thread(target=serve, name="relayd:foxglove-gate", daemon=True)
        self._thread.start()
        ready.wait(5.0)
        if failed:
            raise failed[0]

    def close(self) -> None:
        loop, thread = self._loop, self._thread
        if loop is not None and thread is not None and thread.is_alive():
            with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                loop.call_soon_threadsafe(loop.stop)
            thread.join(2.0)

    def _loop_report(self, loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        """The gate loop's own reports (accept failing for lack of descriptors, ...), rate-limited."""
        message = str(context.get("message", "?"))
        count = self._limit.hit(f"loop:{message}", loop.time())
        if count is not None:
            log.warning(
                "foxglove_gate_report",
                message=message,
                error=str(context.get("exception")),
                count=count,
                every_s=LOG_EVERY_S,
            )

    # -- what the protocols ask ------------------------------------------------------

    def admit(self, front: _Front, fileno: int) -> str | None:
        """None if the client is taken (and booked); otherwise why not."""
        if len(self.clients) >= self.max_clients:
            return f"{self.max_clients} clients already"
        if not self.budget.admits(fileno) or not self.budget.take(BUDGET_OWNER, FDS_PER_CLIENT):
            return "descriptors reserved for the devices"
        self.clients.add(front)
        self.counters["accepted"] += 1
        return None

    def release(self, front: _Front) -> None:
        if front in self.clients:
            self.clients.remove(front)
            self.budget.give(BUDGET_OWNER, FDS_PER_CLIENT)

    def refused(self, why: str) -> None:
        self.counters["refused"] += 1
        self.note("foxglove_connection_refused", why, reason=why)

    def note(self, event: str, key: str, **kw: Any) -> None:
        count = self._limit.hit(key, asyncio.get_running_loop().time())
        if count is not None:
            log.warning(event, count=count, every_s=LOG_EVERY_S, **kw)

    async def connect_upstream(self, back: _Back) -> None:
        loop = asyncio.get_running_loop()
        for attempt in range(2):
            try:
                await loop.create_connection(lambda: back, "127.0.0.1", self.upstream_port)
                return
            except OSError as exc:
                self.counters["upstream_failed"] += 1
                self.last_error = f"the Foxglove server refused a connection: {exc}"
                self.note("foxglove_upstream_failed", "upstream", error=str(exc))
                port = None
                if attempt == 0 and self.on_upstream_refused is not None:
                    with contextlib.suppress(Exception):
                        port = self.on_upstream_refused()
                if port is None:
                    break
                self.upstream_port = port
        back.front.close()
