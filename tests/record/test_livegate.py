"""The gate in front of the live Foxglove server: its client cap, its handshake deadline,
the descriptor account it shares with the API, its log lines at a bounded rate, and the
SDK's listener started again when it dies (and shown in /status).

Each of these fails on a server without the gate: the SDK alone keeps every connection,
waits for a handshake for ever, books nothing, and its listener, once dead, stays dead.
"""

from __future__ import annotations

import asyncio
import contextlib
import resource
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest
import structlog

from relayd.api import make_app, start_api
from relayd.api.guard import GuardedServer
from relayd.config.load import parse_settings
from relayd.daemon import Daemon
from relayd.fakes.rig import FakeRig
from relayd.record.live import SUBPROTOCOL, LiveServer
from relayd.record.livegate import FDS_PER_CLIENT
from relayd.runtime.bus import Bus
from relayd.runtime.fdbudget import FdBudget
from relayd.runtime.state import RelayState
from tests.support import LoopClock, until

BASE = {"control": {"rear_link": "ignore"}}


@contextlib.asynccontextmanager
async def live_server(budget: FdBudget, **gate: Any) -> AsyncIterator[LiveServer]:
    settings = parse_settings({**BASE, "foxglove": {"enabled": True, "port": 0}})
    live = LiveServer(Bus(), settings, LoopClock(), budget=budget)
    for key, value in gate.items():
        setattr(live.gate, key, value)
    live.start()
    try:
        yield live
    finally:
        live.close()


async def closed_within(reader: asyncio.StreamReader, timeout_s: float) -> bool:
    """True if the server closed the connection (EOF or reset) within `timeout_s`."""
    try:
        return await asyncio.wait_for(reader.read(), timeout_s) == b""
    except ConnectionError:
        return True
    except TimeoutError:
        return False


async def handshake(port: int) -> None:
    """A Foxglove app's WebSocket handshake through the gate (raises if it is not accepted)."""
    async with (
        aiohttp.ClientSession() as session,
        session.ws_connect(f"ws://127.0.0.1:{port}/", protocols=[SUBPROTOCOL]) as ws,
    ):
        assert ws.protocol == SUBPROTOCOL
        msg = await ws.receive(timeout=5)
        assert msg.type == aiohttp.WSMsgType.TEXT and "serverInfo" in msg.data


def big_budget() -> FdBudget:
    return FdBudget(capacity=10_000, fd_limit=1 << 20)


async def test_clients_beyond_the_cap_are_closed_at_once_and_logged_at_a_bounded_rate() -> None:
    async with live_server(big_budget(), max_clients=3, handshake_s=30.0) as live:
        port = live.port or 0
        held = [await asyncio.open_connection("127.0.0.1", port) for _ in range(3)]
        await until(lambda: len(live.gate.clients) == 3, "three clients held", 5)
        with structlog.testing.capture_logs() as logs:
            extra = [await asyncio.open_connection("127.0.0.1", port) for _ in range(20)]
            for reader, _w in extra:
                assert await closed_within(reader, 5.0), "a client beyond the cap was kept"
        assert live.gate.counters["refused"] == 20
        refusals = [e for e in logs if e["event"] == "foxglove_connection_refused"]
        assert len(refusals) == 1, refusals  # one line for twenty, not twenty
        # The three held ones are still open.
        for reader, _w in held:
            assert not await closed_within(reader, 0.2)
        for _r, w in held + extra:
            w.close()


async def test_a_client_that_sends_no_handshake_is_closed_at_the_deadline() -> None:
    budget = big_budget()
    async with live_server(budget, handshake_s=0.3) as live:
        reader, writer = await asyncio.open_connection("127.0.0.1", live.port or 0)
        writer.write(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # never the blank line
        assert await closed_within(reader, 5.0)
        assert live.gate.counters["late"] == 1
        await until(lambda: budget.in_use == 0, "the descriptors given back", 5)
        writer.close()
        # A real client still gets through, well within the deadline.
        await handshake(live.port or 0)


async def test_one_descriptor_account_for_the_api_and_the_live_view() -> None:
    """The live view's clients use the account up: the API refuses, whatever its descriptor
    numbers (low ones pass the old number check); a viewer leaving gives the room back."""
    budget = FdBudget(capacity=2 * FDS_PER_CLIENT + 1, fd_limit=1 << 20)
    app = make_app(RelayState(), _Controls(), clock=LoopClock(), token=None)
    api, api_port = await start_api(app, "127.0.0.1", 0, guard=GuardedServer(budget=budget))
    try:
        async with live_server(budget, handshake_s=30.0) as live:
            viewers = [await asyncio.open_connection("127.0.0.1", live.port or 0) for _ in range(2)]
            await until(lambda: budget.held.get("foxglove") == 2 * FDS_PER_CLIENT, "booked", 5)
            # One descriptor left: one API connection, not two.
            _r1, w1 = await asyncio.open_connection("127.0.0.1", api_port)
            await until(lambda: budget.held.get("api") == 1, "the API's connection booked", 5)
            r2, w2 = await asyncio.open_connection("127.0.0.1", api_port)
            assert await closed_within(r2, 5.0), "the API took a descriptor the account had not"
            # A third viewer is refused too: the API holds the last descriptor.
            r3, w3 = await asyncio.open_connection("127.0.0.1", live.port or 0)
            assert await closed_within(r3, 5.0)
            for _r, w in viewers:
                w.close()
            await until(lambda: budget.held.get("foxglove") == 0, "the viewers' room back", 5)
            for w in (w1, w2, w3):
                w.close()
    finally:
        await api.cleanup()


async def test_a_dead_sdk_listener_is_started_again_and_shown(tmp_path: Path) -> None:
    async with FakeRig(tmp_path) as rig:
        doc = rig.config_doc(log={"level": "warning"})
        doc["foxglove"] = {"enabled": True, "port": 0}
        daemon = Daemon(parse_settings(doc), env=rig.env)
        await daemon.start()
        try:
            live = daemon.live
            assert live is not None and live.port
            assert daemon.state.health_now()["foxglove"].connected
            # The SDK's listener dies (as it once did under EMFILE); the gate stays.
            assert live._server is not None
            live._server.stop()
            await handshake(live.port)  # restarted on the next client's connection
            async with (
                aiohttp.ClientSession() as session,
                session.get(f"http://127.0.0.1:{daemon.api_port}/status") as resp,
            ):
                health = (await resp.json())["health"]["foxglove"]
            assert health["connected"] and health["reconnects"] == 1, health
            assert health["errors"] >= 1 and "refused" in (health["last_error"] or ""), health
        finally:
            await daemon.shutdown()


def test_the_process_budget_leaves_the_devices_their_reserve() -> None:
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    budget = FdBudget.for_process(256)
    assert budget.fd_limit == 256 - 64
    assert 0 < budget.capacity <= 256 - 64
    assert budget.take("api", budget.capacity) and not budget.take("foxglove", 1)
    budget.give("api", 1)
    assert budget.take("foxglove", 1)
    with pytest.raises(ValueError, match="does not hold"):
        budget.give("foxglove", 2)
    assert soft > 0


class _Controls:
    def set_mode(self, mode: Any) -> None: ...

    def manual_drive(self, left_mm_s: float, right_mm_s: float) -> None: ...


async def test_a_flood_of_silent_connections_costs_the_process_a_bounded_count_of_descriptors() -> (
    None
):
    """The red team's flood: connections that never send a handshake. Without the gate the
    SDK kept all of them (1,023 of 1,024 descriptors); here at most the cap is held, and
    each for no longer than the deadline."""
    from relayd.record.livegate import MAX_CLIENTS
    from relayd.runtime.fdbudget import open_fds

    budget = big_budget()
    async with live_server(budget, handshake_s=0.5) as live:
        before = open_fds()
        flood = [await asyncio.open_connection("127.0.0.1", live.port or 0) for _ in range(150)]
        await until(lambda: live.gate.counters["refused"] >= 150 - MAX_CLIENTS, "refusals", 10)
        # Ours: the 150 client ends this test holds, plus at most the cap's worth server-side.
        assert open_fds() - before <= 150 + MAX_CLIENTS * FDS_PER_CLIENT
        assert len(live.gate.clients) <= MAX_CLIENTS
        await until(lambda: not live.gate.clients, "the held ones closed at the deadline", 10)
        assert budget.in_use == 0
        for _r, w in flood:
            w.close()
