"""read_bounded: an HTTP answer read in pieces stops at its limit, chunked or not (loopback)."""

from __future__ import annotations

import asyncio
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
