"""The API's guarded accept loop (relayd/api/guard.py), with small limits so it runs fast.

tests/api/test_flood.py shows the whole daemon surviving a flood; this file pins each
rule on its own: idle and slow-header connections are closed at the deadline, busy ones
(an event stream) are not; at the cap a new connection evicts the one idle longest, or
waits in the backlog when none is idle; a descriptor inside the devices' reserve is
refused; refusals and asyncio's accept errors are logged once, with a count.

On virtual time (the guard's deadlines are loop time; the sockets are real and polled on
every turn): a deadline is passed by letting the loop's clock run past it, which takes no
wall time and cannot come late on a loaded machine.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from typing import Any

import pytest
import structlog

from relayd.api import make_app, start_api
from relayd.api.guard import GuardedServer
from relayd.api.server import install_accept_error_limit
from relayd.runtime.state import RelayState
from tests.support import LoopClock, until

IDLE_S = 0.6
EVICT_S = 0.2

pytestmark = pytest.mark.virtual_time


def now() -> float:
    return asyncio.get_running_loop().time()


class _Controls:
    def set_mode(self, mode: Any) -> None: ...

    def manual_drive(self, left_mm_s: float, right_mm_s: float) -> None: ...


@contextlib.asynccontextmanager
async def serving(guard: GuardedServer) -> AsyncIterator[int]:
    app = make_app(RelayState(), _Controls(), clock=LoopClock(), token=None, sse_heartbeat_s=0.1)
    server, port = await start_api(app, "127.0.0.1", 0, guard=guard)
    try:
        yield port
    finally:
        await server.cleanup()


async def connect(port: int) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    return await asyncio.open_connection("127.0.0.1", port)


async def get(port: int, path: str = "/status", timeout_s: float = 5.0) -> bytes:
    reader, writer = await connect(port)
    try:
        writer.write(
            f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n".encode()
        )
        return await asyncio.wait_for(reader.read(), timeout_s)
    finally:
        writer.close()


async def closed_by_server(reader: asyncio.StreamReader, timeout_s: float) -> float:
    """Seconds until the server closed the connection (EOF or reset)."""
    t0 = now()
    with contextlib.suppress(ConnectionError):
        assert await asyncio.wait_for(reader.read(), timeout_s) == b""
    return now() - t0


async def test_idle_and_slow_header_connections_are_closed_at_the_deadline() -> None:
    guard = GuardedServer(max_connections=10, idle_timeout_s=IDLE_S, evict_idle_s=EVICT_S)
    async with serving(guard) as port:
        idle_r, _idle_w = await connect(port)
        slow_r, slow_w = await connect(port)
        slow_w.write(b"GET /status HTTP/1.1\r\nHost: re")

        async def trickle() -> None:
            with contextlib.suppress(ConnectionError):
                for _ in range(100):
                    slow_w.write(b"a")
                    await slow_w.drain()
                    await asyncio.sleep(0.05)

        trickler = asyncio.create_task(trickle())
        assert await closed_by_server(idle_r, 10.0) >= IDLE_S * 0.8
        assert await closed_by_server(slow_r, 10.0) < 5.0  # bytes trickling in do not keep it alive
        trickler.cancel()
        assert b"200 OK" in await get(port)


async def test_an_event_stream_is_busy_and_stays_open() -> None:
    guard = GuardedServer(max_connections=10, idle_timeout_s=IDLE_S, evict_idle_s=EVICT_S)
    async with serving(guard) as port:
        reader, writer = await connect(port)
        writer.write(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        t0 = now()
        while now() - t0 < IDLE_S * 3:
            assert await asyncio.wait_for(reader.readline(), 5.0)  # heartbeats keep coming
        writer.close()


async def test_at_the_cap_a_new_connection_evicts_the_one_idle_longest() -> None:
    guard = GuardedServer(max_connections=3, idle_timeout_s=30.0, evict_idle_s=EVICT_S)
    async with serving(guard) as port:
        held = []
        for n in range(1, 4):
            held.append(await connect(port))
            await until(lambda n=n: len(guard.conns) == n, f"connection {n} accepted")
            await asyncio.sleep(0.01)  # virtual: each accepted at its own time, one is the oldest
        await asyncio.sleep(EVICT_S * 1.5)  # virtual: past the eviction age
        t0 = now()
        assert b"200 OK" in await get(port)
        assert now() - t0 < 2.0
        assert guard.counters["evicted"] >= 1
        assert await closed_by_server(held[0][0], 5.0) < 5.0  # the oldest went
        assert len(guard.conns) <= 3


async def test_at_the_cap_with_every_connection_busy_a_new_one_waits() -> None:
    guard = GuardedServer(max_connections=2, idle_timeout_s=30.0, evict_idle_s=EVICT_S)
    async with serving(guard) as port:
        streams = []
        for _ in range(2):
            r, w = await connect(port)
            w.write(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            assert await asyncio.wait_for(r.readline(), 5.0)
            streams.append((r, w))
        waiting = asyncio.create_task(get(port, timeout_s=30.0))
        await asyncio.sleep(1.0)
        assert not waiting.done()  # in the listen backlog, costing the process nothing
        assert len(guard.conns) == 2
        streams[0][1].close()
        assert b"200 OK" in await asyncio.wait_for(waiting, 10.0)
        streams[1][1].close()


async def test_descriptors_in_the_devices_reserve_are_refused_and_logged_once() -> None:
    guard = GuardedServer(max_connections=10, idle_timeout_s=IDLE_S, fd_limit=0)
    with structlog.testing.capture_logs() as logs:
        async with serving(guard) as port:
            for _ in range(5):
                reader, _w = await connect(port)
                assert await closed_by_server(reader, 5.0) < 5.0
    assert guard.counters["refused"] >= 1
    refused = [e for e in logs if e["event"] == "api_connection_refused"]
    assert len(refused) == 1 and refused[0]["count"] == 1, refused


async def test_asyncio_accept_errors_are_rate_limited() -> None:
    loop = asyncio.get_running_loop()
    old = loop.get_exception_handler()
    seen: list[dict[str, Any]] = []
    loop.set_exception_handler(lambda _lp, ctx: seen.append(ctx))
    try:
        install_accept_error_limit(loop)
        with structlog.testing.capture_logs() as logs:
            for _ in range(1000):
                loop.call_exception_handler(
                    {
                        "message": "socket.accept() out of system resource",
                        "exception": OSError(24, "Too many open files"),
                    }
                )
            loop.call_exception_handler({"message": "something else"})
    finally:
        loop.set_exception_handler(old)
    assert [e["count"] for e in logs if e["event"] == "accept_failed"] == [1]
    assert [c["message"] for c in seen] == ["something else"]  # others go where they went before


@pytest.mark.parametrize("busy", [False, True])
async def test_keep_alive_connection_serves_many_requests(busy: bool) -> None:
    guard = GuardedServer(max_connections=2, idle_timeout_s=IDLE_S, evict_idle_s=EVICT_S)
    async with serving(guard) as port:
        reader, writer = await connect(port)
        for _ in range(5):
            writer.write(b"GET /status HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            status = await asyncio.wait_for(reader.readline(), 5.0)
            assert b"200" in status
            while (line := await asyncio.wait_for(reader.readline(), 5.0)) != b"\r\n":
                if line.lower().startswith(b"content-length"):
                    length = int(line.split(b":")[1])
            await reader.readexactly(length)
            await asyncio.sleep(IDLE_S / 3 if busy else 0)
        writer.close()
