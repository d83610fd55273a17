"""read_bounded: an HTTP answer read in pieces stops at its limit, chunked or not (loopback)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator

import aiohttp
import pytest
from aiohttp import web

from drivers.transport.bounded import CHUNK_BYTES, BodyTooLarge, read_bounded

LIMIT = 256 * 1024


@pytest.fixture
async def server() -> AsyncIterator[tuple[str, dict[str, int]]]:
    sent = {"bytes": 0}

    async def endless(request: web.Request) -> web.StreamResponse:
        resp = web.StreamResponse()  # chunked: no Content-Length
        await resp.prepare(request)
        with pytest.raises((ConnectionResetError, ConnectionError, asyncio.CancelledError)):
            for _ in range(2000):  # 128 MB at most: bounded, but far past the limit
                await resp.write(b"\0" * CHUNK_BYTES)
                sent["bytes"] += CHUNK_BYTES
        return resp

    async def small(request: web.Request) -> web.Response:
        return web.Response(body=b'{"ok": true}')

    async def declared(request: web.Request) -> web.Response:
        return web.Response(body=b"x" * (LIMIT + 1))

    app = web.Application()
    app.router.add_get("/endless", endless)
    app.router.add_get("/small", small)
    app.router.add_get("/declared", declared)
    runner = web.AppRunner(app)
    await runner.setup()
    site = web.TCPSite(runner, "127.0.0.1", 0)
    await site.start()
    port = site._server.sockets[0].getsockname()[1]  # type: ignore[union-attr]
    yield f"http://127.0.0.1:{port}", sent
    await runner.cleanup()


async def test_a_chunked_answer_past_the_limit_is_cut_off(
    server: tuple[str, dict[str, int]],
) -> None:
    base, _ = server
    async with aiohttp.ClientSession() as s:
        async with s.get(base + "/endless") as resp:
            with pytest.raises(BodyTooLarge, match="more than"):
                await read_bounded(resp, LIMIT)
        async with s.get(base + "/small") as resp:
            assert await read_bounded(resp, LIMIT) == b'{"ok": true}'
        async with s.get(base + "/declared") as resp:
            with pytest.raises(BodyTooLarge, match=str(LIMIT + 1)):
                await read_bounded(resp, LIMIT)


@pytest.fixture
async def endless_everywhere() -> AsyncIterator[tuple[str, dict[str, int]]]:
    """A server answering every path with an endless chunked body (a rear radio gone mad)."""
    sent = {"bytes": 0}

    async def endless(request: web.Request) -> web.StreamResponse:
        resp = web.StreamResponse(headers={"Content-Type": "application/json"})
        await resp.prepare(request)
        with contextlib.suppress(ConnectionError, asyncio.CancelledError):
            for _ in range(2000):
                await resp.write(b" " * CHUNK_BYTES)
                sent["bytes"] += CHUNK_BYTES
        return resp

    app = web.Application()
    app.router.add_route("*", "/{tail:.*}", endless)
    runner = web.AppRunner(app)
    await runner.setup()
    site = web.TCPSite(runner, "127.0.0.1", 0)
    await site.start()
    port = site._server.sockets[0].getsockname()[1]  # type: ignore[union-attr]
    yield f"http://127.0.0.1:{port}", sent
    await runner.cleanup()


async def test_the_airos_client_stops_reading_at_its_limit(
    endless_everywhere: tuple[str, dict[str, int]],
) -> None:
    """`await resp.read()` before the size check once took relayd to 3 GB on a 1 GiB answer."""
    from drivers.airos import AirOsClient
    from drivers.airos.client import MAX_BODY_BYTES, AirOsDataError

    base, sent = endless_everywhere
    client = AirOsClient(base, "ubnt", "Pa55-w0rd-XYZZY", timeout_s=30.0)
    try:
        with pytest.raises(AirOsDataError, match="answer of more than"):
            await client.status()
    finally:
        await client.close(logout_budget_s=0.1)
    assert sent["bytes"] < 64 * MAX_BODY_BYTES  # the server was cut off, not read to its end


async def test_the_fleet_poller_stops_reading_at_its_limit(
    endless_everywhere: tuple[str, dict[str, int]],
) -> None:
    from relayd.fleet.config import Relay
    from relayd.fleet.poller import MAX_STATUS_BYTES, RelayPoller

    base, sent = endless_everywhere
    async with aiohttp.ClientSession() as session:
        poller = RelayPoller(Relay("r", base), session, poll_s=1.0, timeout_s=30.0)
        await poller.poll_once()
    assert poller.view.error_kind == "bad_answer", poller.view.error
    assert sent["bytes"] < 64 * MAX_STATUS_BYTES
