"""DNS rebinding: a foreign Host or Origin is refused on every route, naming why."""

from __future__ import annotations

from typing import Any

import pytest
from aiohttp.test_utils import TestClient, TestServer

from relayd.api import make_app
from relayd.api.hostcheck import request_problem, split_host
from relayd.core.vocab import Mode
from relayd.runtime.state import RelayState
from tests.api.test_app import TOKEN, FakeControls
from tests.support import ManualClock

AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.mark.parametrize(
    ("host", "name"),
    [
        ("relay1.local:8080", "relay1.local"),
        ("[::1]:8080", "::1"),
        ("[fe80::1]", "fe80::1"),
        ("LOCALHOST.", "localhost"),
        ("127.0.0.1", "127.0.0.1"),
        ("a:b", None),
        ("[::1", None),
        ("", None),
    ],
)
def test_split_host(host: str, name: str | None) -> None:
    assert split_host(host) == name


def test_request_problem_rules() -> None:
    allowed = frozenset({"relay1.local"})
    assert request_problem("10.0.0.7:8080", None, allowed) is None
    assert request_problem("relay1.local", "http://relay1.local:8080", allowed) is None
    assert request_problem("localhost:8080", "http://localhost:8080", allowed) is None
    assert "evil.example" in (request_problem("evil.example", None, allowed) or "")
    # Same-site check: an IP-literal page elsewhere is another site.
    assert "10.9.9.9" in (request_problem("10.0.0.7", "http://10.9.9.9", allowed) or "")
    assert "null" in (request_problem("10.0.0.7", "null", allowed) or "")
    assert request_problem(None, None, allowed) is not None


async def _client(allowed: tuple[str, ...] = ()) -> tuple[TestClient[Any, Any], FakeControls]:
    clock = ManualClock(100.0)
    state = RelayState()
    controls = FakeControls(state)
    app = make_app(state, controls, clock=clock, token=TOKEN, allowed_hosts=allowed)
    client: TestClient[Any, Any] = TestClient(TestServer(app, host="127.0.0.1"))
    await client.start_server()
    return client, controls


@pytest.mark.parametrize("path", ["/status", "/healthz", "/", "/openapi.json", "/events"])
async def test_a_foreign_host_is_refused_on_every_route(path: str) -> None:
    client, _ = await _client()
    try:
        r = await client.get(path, headers={"Host": "rebind.attacker.example"})
        assert r.status == 421
        body = await r.json()
        assert body["field"] == "Host"
        assert "rebind.attacker.example" in body["error"]
        assert "allowed_hosts" in body["error"]
    finally:
        await client.close()


async def test_a_foreign_origin_cannot_stop_the_robot() -> None:
    client, controls = await _client()
    try:
        r = await client.post(
            "/api/mode", json={"mode": "hold"}, headers={"Origin": "http://attacker.example"}
        )
        assert r.status == 403
        body = await r.json()
        assert body["field"] == "Origin" and "attacker.example" in body["error"]
        assert controls.modes == []
    finally:
        await client.close()


async def test_the_right_host_and_origin_pass_and_a_listed_name_too() -> None:
    client, controls = await _client(allowed=("relay1.local",))
    try:
        port = client.port
        origin = {"Origin": f"http://127.0.0.1:{port}"}
        r = await client.post("/api/mode", json={"mode": "hold"}, headers=origin)
        assert r.status == 200, await r.text()
        assert controls.modes[-1] == Mode.HOLD
        named = {"Host": "relay1.local:8080", "Origin": "http://relay1.local:8080"}
        r = await client.get("/status", headers=named)
        assert r.status == 200
        r = await client.post("/api/mode", json={"mode": "follow"}, headers={**named, **AUTH})
        assert r.status == 200, await r.text()
    finally:
        await client.close()
