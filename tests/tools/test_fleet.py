"""relayd fleet without a browser: config, the chain document, polling and hold-all.

Relays here are real relayd API apps (`make_app` on a demo state), a closed port, and
a server that accepts and never answers (what a paused relay looks like on the wire).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.transport.clock import REAL_CLOCK
from relayd.api import make_app, start_api
from relayd.api.demo import DemoControls, populate
from relayd.cli.fleet import settings_from_args
from relayd.config.model import ConfigError
from relayd.core.vocab import Mode
from relayd.fleet.chain import NO_ORIGIN, fleet_document, hops, link_status
from relayd.fleet.config import Relay, normalise_url, parse_fleet, relay_from_arg
from relayd.fleet.poller import Fleet, RelayView
from relayd.fleet.server import hold_one
from relayd.runtime.state import RelayState
from tests.support import until

TOKEN = "fleet-test-token-0123456789"


# -- config ------------------------------------------------------------------------------


def test_fleet_config_resolves_each_relays_token(tmp_path: Path) -> None:
    tf = tmp_path / "r2.token"
    tf.write_text("from-a-file\n")
    data = {
        "robot": {"port": "ignored"},
        "fleet": {
            "port": 9000,
            "relay": [
                {"url": "192.168.1.31:8080", "name": "r1", "token": "inline", "origin": [0, 0, 90]},
                {"url": "http://192.168.1.32:8080/status", "name": "r2", "token_file": str(tf)},
                {"url": "http://192.168.1.33:8080/", "token_env": "R3_TOKEN"},
                {"url": "http://192.168.1.34:8080"},
            ],
        },
    }
    fs = parse_fleet(data, {"R3_TOKEN": "from-env"})
    assert fs.port == 9000 and fs.bind == "127.0.0.1"
    assert [(r.name, r.url, r.token) for r in fs.relays] == [
        ("r1", "http://192.168.1.31:8080", "inline"),
        ("r2", "http://192.168.1.32:8080", "from-a-file"),
        ("192.168.1.33:8080", "http://192.168.1.33:8080", "from-env"),
        ("192.168.1.34:8080", "http://192.168.1.34:8080", None),
    ]
    assert fs.relays[0].origin == (0.0, 0.0, 90.0)
    assert "inline" not in repr(fs.relays[0])


@pytest.mark.parametrize(
    ("fleet", "needle"),
    [
        ({"relay": [{"url": "ftp://x"}]}, "fleet.relay.0.url"),
        ({"relay": [{"url": "http://a", "token": "x", "token_file": "/y"}]}, "at most one"),
        ({"relay": [{"url": "http://a", "tokn": "x"}]}, "tokn"),
        ({"relay": [{"url": "http://a", "token_env": "NOPE"}]}, "NOPE is not set"),
        ({"relay": [{"url": "http://a", "token_file": "/nonexistent/t"}]}, "cannot read"),
        (
            {"relay": [{"url": "http://a", "name": "x"}, {"url": "http://b", "name": "x"}]},
            "two relays",
        ),
        ({"relay": [{"url": "http://a", "origin": [0, 0]}]}, "origin"),
        ({"timeout_s": 0}, "timeout_s"),
    ],
)
def test_fleet_config_errors_name_the_key(fleet: dict[str, Any], needle: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_fleet({"fleet": fleet}, {})
    assert needle in "\n".join(info.value.errors)


def test_relay_arguments() -> None:
    assert relay_from_arg("10.0.0.5:8080") == Relay("10.0.0.5:8080", "http://10.0.0.5:8080")
    assert relay_from_arg("r1=http://10.0.0.5:8080/", "t") == Relay(
        "r1", "http://10.0.0.5:8080", "t"
    )
    for bad in ("mailto:x", "http://h:1/?a=b", "ftp://h", "http://:80"):
        with pytest.raises(ValueError):
            normalise_url(bad)
    with pytest.raises(ConfigError, match="--relay"):
        relay_from_arg("r1=http://h:port")


def _args(**kw: Any) -> argparse.Namespace:
    base: dict[str, Any] = {
        "relay": [],
        "config": None,
        "token_file": None,
        "bind": None,
        "port": None,
        "poll_s": None,
        "timeout_s": None,
        "allowed_host": [],
    }
    return argparse.Namespace(**{**base, **kw})


def test_command_line_and_config_combine(tmp_path: Path) -> None:
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(
        '[fleet]\nport = 9100\n[[fleet.relay]]\nname = "a"\nurl = "http://10.0.0.1:8080"\n'
    )
    tok = tmp_path / "tok"
    tok.write_text("T\n")
    fs = settings_from_args(
        _args(config=str(cfg), relay=["b=10.0.0.2:8080"], token_file=str(tok), timeout_s=0.3)
    )
    assert [r.name for r in fs.relays] == ["a", "b"] and fs.relays[1].token == "T"
    assert fs.port == 9100 and fs.timeout_s == 0.3
    with pytest.raises(ConfigError, match="no relays"):
        settings_from_args(_args())
    with pytest.raises(ConfigError, match="two relays"):
        settings_from_args(_args(relay=["http://h:1", "http://h:1"]))


# -- the chain document -------------------------------------------------------------------


def _doc(
    name: str,
    front: float | None,
    rear: float | None,
    rl: float | None = -45.0,
    pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> dict[str, Any]:
    links = {}
    if front is not None:
        links["front"] = {"signal_dbm": front}
    if rear is not None:
        links["rear"] = {"signal_dbm": rear}
    return {
        "robot": name,
        "state": "driving",
        "mode": "follow",
        "reason": "driving",
        "battery_v": 12.5,
        "rssi_leader_dbm": rl,
        "rssi_behind_dbm": rear,
        "bearing_deg": 10.0,
        "links": links,
        "pose": {"x_mm": pose[0], "y_mm": pose[1], "theta_deg": pose[2]},
        "wheels_mm_s": {"left": 100.0, "right": 120.0},
        "thresholds": {},
    }


def _view(
    name: str,
    doc: dict[str, Any] | None,
    ok_t: float | None = 100.0,
    origin: tuple[float, float, float] | None = None,
    error: str | None = None,
) -> RelayView:
    v = RelayView(Relay(name, f"http://{name}", None, origin), doc=doc, ok_t=ok_t)
    if error:
        v.error, v.error_kind = error, error
    return v


def test_hops_use_both_ends_and_only_current_data() -> None:
    views = [
        _view("r1", _doc("r1", -50.0, -60.0, rl=-40.0)),
        _view("r2", _doc("r2", -70.0, -66.0)),
        _view("r3", _doc("r3", -52.0, -58.0), ok_t=90.0),
    ]  # ten seconds old: not current
    out = hops(views, now=100.5, stale_after_s=2.0)
    assert [(h["from"], h["to"]) for h in out] == [
        ("leader", "r1"),
        ("r1", "r2"),
        ("r2", "r3"),
        ("r3", "command center"),
    ]
    assert out[0]["rssi_dbm"] == -50.0 and out[0]["est_mbps"] == 27.0  # 54 Mb/s PHY x 0.5
    assert {m["by"] for m in out[0]["measurements"]} == {"r1 front radio", "r1 Yagi (RSSI^l)"}
    assert out[1]["rssi_dbm"] == -70.0 and out[1]["est_mbps"] == 18.0  # the weaker end: 36 Mb/s
    assert [m["by"] for m in out[2]["measurements"]] == ["r2 rear radio"]  # r3 is stale
    assert out[3]["rssi_dbm"] is None and out[3]["est_mbps"] is None  # only r3 sees it: unknown


def test_link_status_and_relay_summary() -> None:
    assert link_status(_view("a", None, ok_t=None), 0.0, 2.0) == "connecting"
    assert link_status(_view("a", _doc("a", 1, 1)), 101.9, 2.0) == "live"
    assert link_status(_view("a", _doc("a", 1, 1)), 102.1, 2.0) == "stale"
    assert link_status(_view("a", _doc("a", 1, 1), error="no_answer"), 100.1, 2.0) == "no_answer"
    doc = fleet_document(
        [
            _view(
                "a",
                {
                    **_doc("a", -50, -64),
                    "reason": "rear_weak",
                    "thresholds": {"threshold_b_dbm": -60.0},
                },
            )
        ],
        100.2,
        2.0,
    )
    r = doc["relays"][0]
    assert r["current"] and r["age_s"] == 0.2 and r["battery_v"] == 12.5
    assert r["reason_text"] == "stopped: the link behind is weak (\u221264 dBm \u2264 \u221260)"


def test_map_places_relays_by_their_origin() -> None:
    v1 = _view("r1", _doc("r1", -50, -55, pose=(1000.0, 0.0, 0.0)), origin=(2.0, 3.0, 90.0))
    v1.trail.extend([(0.0, 0.0), (1000.0, 0.0)])
    v2 = _view("r2", _doc("r2", -50, -55))
    m = fleet_document([v1, v2], 100.0, 2.0)["map"]
    (placed,) = m["relays"]
    # One metre forward on a robot that started facing +y lands one metre up the map.
    assert (placed["x_m"], placed["y_m"], placed["heading_deg"]) == pytest.approx((2.0, 4.0, 90.0))
    assert placed["leader_deg"] == pytest.approx(100.0)
    assert placed["trail"] == [[2.0, 3.0], [2.0, 4.0]]
    assert m["unplaced"] == [{"name": "r2", "why": NO_ORIGIN}]
    assert NO_ORIGIN.startswith("no origin configured") and "--relay" in NO_ORIGIN


# -- polling and hold-all against real relay APIs ------------------------------------------


@contextlib.asynccontextmanager
async def relay_api(name: str, token: str | None = TOKEN) -> AsyncIterator[tuple[str, RelayState]]:
    state = RelayState()
    populate(state, REAL_CLOCK)
    state.robot_name = name
    runner, port = await start_api(
        make_app(state, DemoControls(state), clock=REAL_CLOCK, token=token), "127.0.0.1", 0
    )
    try:
        yield f"http://127.0.0.1:{port}", state
    finally:
        await runner.cleanup()


@contextlib.asynccontextmanager
async def silent_server() -> AsyncIterator[str]:
    """Accepts connections and reads requests, never answers: a paused relay."""
    conns: list[asyncio.StreamWriter] = []

    async def hold(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        conns.append(writer)
        with contextlib.suppress(Exception):
            await reader.read()

    server = await asyncio.start_server(hold, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        for w in conns:
            w.close()
        server.close()


def closed_port_url() -> str:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"http://127.0.0.1:{s.getsockname()[1]}"


async def test_a_silent_relay_never_delays_the_others() -> None:
    async with relay_api("good") as (good_url, _), silent_server() as silent_url:
        relays = (
            Relay("good", good_url),
            Relay("silent", silent_url),
            Relay("gone", closed_port_url()),
        )
        fleet = Fleet(relays, poll_s=0.1, timeout_s=1.0, stale_after_s=2.0)
        await fleet.start()
        try:
            t0 = time.monotonic()
            good, silent, gone = fleet.views()
            await until(
                lambda: silent.error_kind is not None and good.polls >= 10,
                "the silent relay's timeout and ten polls of the good one",
                10.0,
            )
            elapsed = time.monotonic() - t0
            assert gone.error_kind == "unreachable"
            assert silent.error_kind == "no_answer" and "within 1 s" in (silent.error or "")
            # The good relay kept its own pace while the silent one hung for a whole second.
            assert good.polls >= 10 and good.error is None
            assert elapsed < 5
            doc = fleet_document(fleet.views(), fleet.clock.now(), 2.0)
            assert [r["link"] for r in doc["relays"]] == ["live", "no_answer", "unreachable"]
            assert doc["relays"][0]["robot"] == "good"
        finally:
            await fleet.stop()


async def test_hold_one_reports_every_outcome() -> None:
    async with (
        relay_api("a") as (url, state),
        silent_server() as silent_url,
        aiohttp.ClientSession() as s,
    ):
        state.mode = Mode.FOLLOW
        ok = await hold_one(s, Relay("a", url, TOKEN), 2.0)
        assert ok["ok"] and ok["status"] == 200 and state.mode is Mode.HOLD
        # A stop needs no token: a wrong one or none stops the relay all the same.
        state.mode = Mode.FOLLOW
        bad = await hold_one(s, Relay("a", url, "wrong-token"), 2.0)
        assert bad["ok"] and state.mode is Mode.HOLD
        state.mode = Mode.FOLLOW
        none = await hold_one(s, Relay("a", url, None), 2.0)
        assert none["ok"] and none["message"] == "hold accepted" and state.mode is Mode.HOLD
        gone = await hold_one(s, Relay("g", closed_port_url(), TOKEN), 2.0)
        assert gone["message"].startswith("unreachable: hold NOT sent")
        t0 = time.monotonic()
        slow = await hold_one(s, Relay("s", silent_url, TOKEN), 0.5)
        assert slow["message"] == "no answer within 0.5 s: hold NOT confirmed"
        assert time.monotonic() - t0 < 2.0


async def test_hold_all_endpoint_needs_json() -> None:
    from aiohttp.test_utils import TestClient, TestServer

    from relayd.fleet.config import FleetSettings
    from relayd.fleet.server import make_fleet_app

    async with relay_api("a") as (url, state):
        state.mode = Mode.FOLLOW
        app = make_fleet_app(FleetSettings(relays=(Relay("a", url, TOKEN),), poll_s=0.2))
        async with TestClient(TestServer(app)) as client:
            form = await client.post(
                "/api/hold-all",
                data="x=1",
                headers={"Content-Type": "application/x-www-form-urlencoded"},
            )
            assert form.status == 415 and state.mode is Mode.FOLLOW
            resp = await client.post("/api/hold-all", json={})
            body = await resp.json()
            assert body["ok"] and body["results"][0]["message"] == "hold accepted"
            assert state.mode is Mode.HOLD
            page = await client.get("/")
            assert "default-src 'self'" in page.headers["Content-Security-Policy"]

            async def held() -> bool:
                doc = await (await client.get("/fleet.json")).json()
                return bool(
                    doc["relays"][0]["link"] == "live" and doc["relays"][0]["mode"] == "hold"
                )

            await until(held, "the fleet page showing the relay live and held", poll_s=0.05)
            assert TOKEN not in await (await client.get("/fleet.json")).text()


async def test_relayd_fleet_command_serves_the_page() -> None:
    import sys

    async with relay_api("cli-relay") as (url, _):
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "relayd",
            "fleet",
            "--relay",
            f"one={url}",
            "--port",
            "0",
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
        )
        try:
            assert proc.stdout is not None
            line = (await asyncio.wait_for(proc.stdout.readline(), 30)).decode()
            assert "1 relay(s), page at http://127.0.0.1:" in line, line
            page = line.rsplit(" ", 1)[1].strip()
            async with aiohttp.ClientSession() as s:

                async def live() -> dict[str, Any] | None:
                    async with s.get(page + "fleet.json") as resp:
                        doc: dict[str, Any] = await resp.json()
                    return doc if doc["relays"][0]["link"] == "live" else None

                doc = await until(live, "the relay live on the fleet page", poll_s=0.05)
            assert doc["relays"][0]["robot"] == "cli-relay"
        finally:
            proc.terminate()
            await proc.wait()
        bad = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "relayd", "fleet", stderr=asyncio.subprocess.PIPE
        )
        _, err = await bad.communicate()
        assert bad.returncode == 2 and b"no relays" in err


_json_values = st.recursive(
    st.none() | st.booleans() | st.floats(allow_nan=True) | st.integers() | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner, max_size=3)
    ),
    max_leaves=12,
)
_keys = st.sampled_from(
    [
        "links",
        "pose",
        "wheels_mm_s",
        "thresholds",
        "rssi_leader_dbm",
        "reason",
        "state",
        "battery_v",
    ]
)


@given(st.dictionaries(_keys, _json_values, max_size=6))
@settings(max_examples=150, deadline=None)
def test_one_odd_relay_never_blanks_the_fleet(overrides: dict[str, Any]) -> None:
    """A relay whose /status has lists where objects belong, or 1e308, is shown as bad; the
    healthy relay beside it stays (a bad one once made /fleet.json answer 500)."""
    odd = _view("odd", {**_doc("odd", -50.0, -60.0), **overrides})
    good = _view("good", _doc("good", -52.0, -58.0))
    doc = fleet_document([odd, good], 100.2, 2.0)
    json.dumps(doc)  # a valid document
    by_name = {r["name"]: r for r in doc["relays"]}
    assert by_name["good"]["current"] and by_name["good"]["link"] == "live"
    assert by_name["odd"]["link"] in ("live", "bad_answer")


def test_the_two_documents_that_once_blanked_the_page() -> None:
    for odd_doc in (
        {**_doc("odd", -50.0, -60.0), "links": ["front", "rear"]},
        {**_doc("odd", -50.0, -60.0), "rssi_leader_dbm": 1e308, "reason": "leader_near"},
    ):
        doc = fleet_document(
            [_view("odd", odd_doc), _view("good", _doc("good", -52, -58))], 100.2, 2.0
        )
        assert [r["name"] for r in doc["relays"]] == ["odd", "good"]
        assert doc["relays"][1]["current"]


async def test_the_fleet_page_refuses_a_foreign_host_or_origin() -> None:
    """DNS rebinding: a page the operator visits must not reach hold-all through its own name."""
    from aiohttp.test_utils import TestClient, TestServer

    from relayd.fleet.config import FleetSettings
    from relayd.fleet.server import make_fleet_app

    async with relay_api("a") as (url, state):
        state.mode = Mode.FOLLOW
        fleet = FleetSettings(relays=(Relay("a", url, TOKEN),), allowed_hosts=("cc.lab",))
        async with TestClient(TestServer(make_fleet_app(fleet))) as client:
            for path in ("/", "/fleet.json", "/static/fleet.js"):
                resp = await client.get(path, headers={"Host": "evil.example:8090"})
                assert resp.status == 421, path
                assert "evil.example" in (await resp.json())["error"]
            resp = await client.post(
                "/api/hold-all", json={}, headers={"Host": "evil.example:8090"}
            )
            assert resp.status == 421 and state.mode is Mode.FOLLOW
            resp = await client.post(
                "/api/hold-all", json={}, headers={"Origin": "http://evil.example"}
            )
            assert resp.status == 403 and state.mode is Mode.FOLLOW
            # A listed name passes, as do IP literals and localhost.
            for host in ("cc.lab:8090", "localhost", "127.0.0.1:8090"):
                assert (await client.get("/fleet.json", headers={"Host": host})).status == 200
            resp = await client.post(
                "/api/hold-all",
                json={},
                headers={"Host": "cc.lab:8090", "Origin": "http://cc.lab:8090"},
            )
            assert resp.status == 200 and state.mode is Mode.HOLD


def test_a_fleet_page_bound_beyond_loopback_warns_that_hold_all_is_open() -> None:
    from relayd.cli.fleet import bind_warnings

    assert bind_warnings("127.0.0.1") == [] and bind_warnings("::1") == []
    (line,) = bind_warnings("0.0.0.0")
    assert line.startswith("--bind 0.0.0.0:") and "hold-all" in line and "no token" in line
    assert bind_warnings("192.168.1.10")


def test_fleet_allowed_hosts_from_config_and_command_line(tmp_path: Path) -> None:
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(
        '[fleet]\nallowed_hosts = ["cc.lab"]\n[[fleet.relay]]\nurl = "http://10.0.0.1:8080"\n'
    )
    args = _args(config=str(cfg), allowed_host=["cc2.lab"])
    assert settings_from_args(args).allowed_hosts == ("cc.lab", "cc2.lab")
