"""The leader relay's feed task (relayd/runtime/leaderfeed.py): each good GET /path answer is a
frozen, timestamped LeaderPath on the bus; a bad one is refused naming what is wrong; a leader
that stops answering is backed off and its health says so; the body is read bounded."""

from __future__ import annotations

import asyncio
import json
import math
from typing import Any

import pytest
from aiohttp import web

from drivers.transport.bounded import BodyTooLarge
from drivers.transport.health import LinkState
from relayd.core.events import Event, LeaderPath
from relayd.runtime.leaderfeed import (
    MAX_PATH_BYTES,
    FeedError,
    HttpPathClient,
    LeaderFeedTask,
    parse_path,
)
from relayd.runtime.vtime import LoopClock
from tests.support import running, until

DOC = {
    "pose": {"t": 12.5, "x_m": 1.25, "y_m": -0.5, "theta_deg": 90.0},
    "points": [[10.0, 0.0, 0.0], [11.0, 0.1, 0.0], [12.0, 1.2, -0.4]],
}


def test_an_answer_becomes_a_frozen_event() -> None:
    ev = parse_path(json.dumps(DOC).encode(), 100.0)
    assert ev == LeaderPath(
        100.0, (12.5, 1.25, -0.5, 90.0), ((10.0, 0.0, 0.0), (11.0, 0.1, 0.0), (12.0, 1.2, -0.4))
    )
    with pytest.raises(AttributeError):
        ev.t = 3.0  # type: ignore[misc]
    assert parse_path(b'{"pose": null, "points": []}', 1.0) == LeaderPath(1.0, None, ())


@pytest.mark.parametrize(
    ("body", "names"),
    [
        (b"<html>", "not JSON"),
        (b"[]", "not a path document"),
        (b'{"pose": null}', "not a path document"),
        (b'{"pose": 3, "points": []}', "pose: not an object"),
        (b'{"pose": {"t": 1, "x_m": NaN, "y_m": 0, "theta_deg": 0}, "points": []}', "pose.x_m"),
        (b'{"pose": {"t": 1, "x_m": 0, "y_m": 0}, "points": []}', "pose.theta_deg"),
        (b'{"pose": null, "points": [[1, 2]]}', "points[0]"),
        (b'{"pose": null, "points": [[1, 2, true]]}', "points[0]"),
        (json.dumps({"pose": None, "points": [[0, 0, 0]] * 2001}).encode(), "2001 points"),
    ],
)
def test_a_bad_answer_is_refused_naming_what_is_wrong(body: bytes, names: str) -> None:
    with pytest.raises(FeedError, match=names.replace("[", r"\[").replace("]", r"\]")):
        parse_path(body, 0.0)


class Scripted:
    """A PathClient that answers, then fails for a while, then answers again."""

    def __init__(self, fail_from: int, fail_until: int) -> None:
        self.calls = 0
        self.fail = range(fail_from, fail_until)
        self.closed = False

    async def fetch(self) -> bytes:
        self.calls += 1
        if self.calls in self.fail:
            raise ConnectionRefusedError("refused")
        doc: dict[str, Any] = dict(DOC)
        doc["pose"] = {**DOC["pose"], "t": float(self.calls)}  # type: ignore[dict-item]
        return json.dumps(doc).encode()

    async def close(self) -> None:
        self.closed = True


@pytest.mark.virtual_time
async def test_the_task_publishes_backs_off_and_recovers() -> None:
    got: list[Event] = []
    client = Scripted(4, 8)
    clock = LoopClock()
    task = LeaderFeedTask(
        "http://10.0.0.2:8080", poll_s=0.5, clock=clock, publish=got.append, client=client
    )
    assert task.health().state is LinkState.CONNECTING
    async with running(task):
        await until(lambda: client.calls >= 5, "the leader to stop answering")
        assert task.health().state is LinkState.DOWN
        assert task.health().last_error == "refused"
        await until(lambda: len(got) >= 6, "the leader back")
        assert task.health().state is LinkState.UP
    assert client.closed
    times = [e.t for e in got]
    assert times == sorted(times) and all(isinstance(e, LeaderPath) for e in got)
    # Three answers 0.5 s apart, then the failures back off (0.5, 1, 2, 4 s) before the fourth.
    assert math.isclose(times[1] - times[0], 0.5, abs_tol=0.01)
    assert times[3] - times[2] > 5.0
    assert task.errors == 4


async def test_the_http_client_reads_the_path_and_stops_at_the_limit() -> None:
    async def path(_: web.Request) -> web.Response:
        return web.json_response(DOC)

    async def endless(request: web.Request) -> web.StreamResponse:
        resp = web.StreamResponse()
        await resp.prepare(request)
        chunk = b" " * 65536
        for _ in range(2 * MAX_PATH_BYTES // len(chunk) + 2):
            await resp.write(chunk)
        return resp

    servers = []
    for handler in (path, endless):
        app = web.Application()
        app.router.add_get("/path", handler)
        runner = web.AppRunner(app)
        await runner.setup()
        site = web.TCPSite(runner, "127.0.0.1", 0)
        await site.start()
        servers.append(runner)
    ports = [r.addresses[0][1] for r in servers]
    try:
        good = HttpPathClient(f"http://127.0.0.1:{ports[0]}/")
        assert json.loads(await good.fetch()) == DOC
        await good.close()
        bad = HttpPathClient(f"http://127.0.0.1:{ports[1]}")
        with pytest.raises(BodyTooLarge):
            await asyncio.wait_for(bad.fetch(), 10.0)
        await bad.close()
    finally:
        for r in servers:
            await r.cleanup()
