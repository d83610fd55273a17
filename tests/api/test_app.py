"""The HTTP API against make_app on a populated RelayState and a recording fake Controls."""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import AsyncIterator
from typing import Any

import pytest
from aiohttp import ClientSession, web
from aiohttp.test_utils import TestClient, TestServer
from prometheus_client.parser import text_string_to_metric_families

from drivers.transport.health import DeviceHealth, LinkState
from relayd.api import make_app, start_api
from relayd.api.demo import populate
from relayd.core.vocab import DriveState, Mode
from relayd.runtime.metrics import Metrics
from relayd.runtime.state import ModeError, RelayState
from tests.support import ManualClock

TOKEN = "s3cr3t-token-do-not-leak"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


class FakeControls:
    """Records calls; refuses to drive outside manual mode like the controller does."""

    def __init__(self, state: RelayState) -> None:
        self.state = state
        self.modes: list[Mode] = []
        self.drives: list[tuple[float, float]] = []

    def set_mode(self, mode: Mode) -> None:
        self.modes.append(mode)
        self.state.mode = mode

    def manual_drive(self, left_mm_s: float, right_mm_s: float) -> None:
        if self.state.mode is not Mode.MANUAL:
            raise ModeError(f"manual drive refused in {self.state.mode} mode")
        self.drives.append((left_mm_s, right_mm_s))


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock(1000.0)


@pytest.fixture
def state(clock: ManualClock) -> RelayState:
    st = RelayState()
    populate(st, clock)
    st.started_t = clock.t - 42.0
    return st


@pytest.fixture
def controls(state: RelayState) -> FakeControls:
    return FakeControls(state)


async def _client(app: web.Application) -> TestClient[Any, Any]:
    client: TestClient[Any, Any] = TestClient(TestServer(app, host="127.0.0.1"))
    await client.start_server()
    return client


@pytest.fixture
async def client(
    state: RelayState, controls: FakeControls, clock: ManualClock
) -> AsyncIterator[TestClient[Any, Any]]:
    c = await _client(
        make_app(
            state, controls, clock=clock, token=TOKEN, sse_heartbeat_s=0.1, sse_min_interval_s=0.0
        )
    )
    yield c
    await c.close()


@pytest.fixture
async def open_client(
    state: RelayState, controls: FakeControls, clock: ManualClock
) -> AsyncIterator[TestClient[Any, Any]]:
    """An app with no token configured."""
    c = await _client(make_app(state, controls, clock=clock, token=None))
    yield c
    await c.close()


# --- /status -----------------------------------------------------------------------------

SPEC_FIELDS = {
    "mode",
    "state",
    "reason",
    "bearing_deg",
    "rssi_leader_dbm",
    "rssi_behind_dbm",
    "situation",
    "wheels_mm_s",
    "pose",
    "battery_v",
    "sonar_mm",
    "last_scan",
    "links",
    "health",
    "uptime_s",
    "version",
}


async def test_status_body_is_reused_only_while_nothing_changed(
    client: TestClient[Any, Any], state: RelayState, clock: ManualClock
) -> None:
    """A poll flood renders the snapshot at most once per STATUS_REUSE_S of an unchanged state."""
    from relayd.api.app import STATUS_REUSE_S

    first = await (await client.get("/status")).json()
    state.battery_v = 11.1  # written without touch(): no revision, so the body is reused
    clock.advance(STATUS_REUSE_S / 2)
    assert await (await client.get("/status")).json() == first
    state.reason = "changed"
    state.touch()  # any state change renders anew at once
    doc = await (await client.get("/status")).json()
    assert doc["reason"] == "changed" and doc["battery_v"] == 11.1
    state.battery_v = 12.5
    clock.advance(1.01 * STATUS_REUSE_S)  # and so does time: nothing lags by more than this
    doc = await (await client.get("/status")).json()
    assert doc["battery_v"] == 12.5
    assert doc["uptime_s"] == pytest.approx(first["uptime_s"] + 1.51 * STATUS_REUSE_S, abs=1e-3)


async def test_status_has_every_spec_field(client: TestClient[Any, Any], state: RelayState) -> None:
    resp = await client.get("/status")
    assert resp.status == 200
    assert resp.content_type == "application/json"
    doc = await resp.json()
    assert set(doc) >= SPEC_FIELDS
    assert doc["mode"] == "follow" and doc["state"] == "driving"
    assert doc["uptime_s"] == pytest.approx(42.0)
    assert doc["wheels_mm_s"] == {"left": 180.0, "right": 220.0}
    assert doc["pose"] == {"x_mm": 1250.0, "y_mm": -300.0, "theta_deg": 12.0}
    assert len(doc["sonar_mm"]) == 16 and doc["sonar_mm"][7] == 650
    assert state.last_scan is not None
    assert doc["last_scan"]["angles"] == list(state.last_scan.angles_deg)
    assert doc["last_scan"]["rssi"] == list(state.last_scan.rssi_dbm)
    assert set(doc["links"]) == {"front", "rear"}
    assert {"signal_dbm", "ccq_pct", "tx_mbps", "rx_mbps"} <= set(doc["links"]["front"])
    assert set(doc["health"]["base"]) >= {"connected", "age_s", "errors"}
    assert doc["thresholds"]["threshold_l_dbm"] == -30.0
    assert doc["link_bearing_deg"] == state.link_bearing_deg


async def test_status_turns_non_finite_numbers_into_null(
    client: TestClient[Any, Any], state: RelayState
) -> None:
    state.rssi_behind_dbm = math.nan
    state.bearing_deg = math.inf
    resp = await client.get("/status")
    text = await resp.text()
    doc = json.loads(text, parse_constant=lambda c: pytest.fail(f"invalid JSON constant {c}"))
    assert doc["rssi_behind_dbm"] is None and doc["bearing_deg"] is None


async def test_no_response_contains_the_token(client: TestClient[Any, Any]) -> None:
    cases: list[tuple[str, str, dict[str, Any]]] = [
        ("GET", "/status", {}),
        ("GET", "/healthz", {}),
        ("GET", "/metrics", {}),
        ("GET", "/openapi.json", {}),
        ("GET", "/", {}),
        ("POST", "/api/mode", {"json": {"mode": "hold"}, "headers": AUTH}),
        (
            "POST",
            "/api/mode",
            {"json": {"mode": "hold"}, "headers": {"Authorization": "Bearer nope"}},
        ),
        ("POST", "/api/drive", {"json": {"left_mm_s": TOKEN, "right_mm_s": 0}, "headers": AUTH}),
    ]
    for method, path, kwargs in cases:
        resp = await client.request(method, path, **kwargs)
        body = await resp.text()
        assert TOKEN not in body, path
        assert all(TOKEN not in v for v in resp.headers.values()), path


# --- /healthz ----------------------------------------------------------------------------


async def test_healthz_ok_when_loop_ticked_recently(
    client: TestClient[Any, Any], state: RelayState, clock: ManualClock
) -> None:
    state.loop_tick_t = clock.t - 0.2
    resp = await client.get("/healthz")
    assert resp.status == 200
    doc = await resp.json()
    assert doc["ok"] is True and doc["loop_age_s"] == pytest.approx(0.2)


async def test_healthz_503_when_loop_stalled(
    client: TestClient[Any, Any], state: RelayState, clock: ManualClock
) -> None:
    state.loop_tick_t = clock.t - 1.5
    resp = await client.get("/healthz")
    assert resp.status == 503
    doc = await resp.json()
    assert doc["ok"] is False and "stalled" in doc["reason"]
    assert doc["loop_age_s"] == pytest.approx(1.5)


async def test_healthz_503_before_first_tick(
    client: TestClient[Any, Any], state: RelayState
) -> None:
    state.loop_tick_t = None
    resp = await client.get("/healthz")
    assert resp.status == 503
    assert "not ticked" in (await resp.json())["reason"]


# --- /metrics ----------------------------------------------------------------------------


async def test_metrics_text(state: RelayState, controls: FakeControls, clock: ManualClock) -> None:
    metrics = Metrics(state, clock)
    metrics.sip_received()
    metrics.observe_control_latency(0.0007)
    metrics.observe_scan_period(1.6)
    state.health_sources["base"] = lambda: DeviceHealth("base", LinkState.UP, reconnects=1)
    c = await _client(make_app(state, controls, clock=clock, token=TOKEN, metrics=metrics))
    try:
        resp = await c.get("/metrics")
        assert resp.status == 200
        assert resp.headers["Content-Type"].startswith("text/plain")
        text = await resp.text()
    finally:
        await c.close()
    names = {fam.name for fam in text_string_to_metric_families(text)}
    for name in (
        "relayd_control_latency_seconds",
        "relayd_sips_received",
        "relayd_scan_period_seconds",
        "relayd_bearing_degrees",
        "relayd_rssi_dbm",
        "relayd_wheel_speed_meters_per_second",
        "relayd_device_connected",
        "relayd_device_errors",
        "relayd_device_reconnects",
        "relayd_build_info",
    ):
        assert name in names, name
    assert "relayd_sips_received_total 1.0" in text
    assert 'relayd_device_reconnects_total{device="base"} 1.0' in text
    assert 'relayd_rssi_dbm{peer="behind"} -52.0' in text
    assert 'relayd_build_info{version="0.1.0"} 1.0' in text
    assert "relayd_control_latency_seconds_count 1.0" in text


# --- /openapi.json -----------------------------------------------------------------------


def _resolve_refs(node: Any, doc: dict[str, Any]) -> None:
    if isinstance(node, dict):
        ref = node.get("$ref")
        if ref is not None:
            target: Any = doc
            for part in ref.removeprefix("#/").split("/"):
                target = target[part]
        for value in node.values():
            _resolve_refs(value, doc)
    elif isinstance(node, list):
        for value in node:
            _resolve_refs(value, doc)


async def test_openapi_lists_every_route(client: TestClient[Any, Any]) -> None:
    resp = await client.get("/openapi.json")
    assert resp.status == 200
    doc = json.loads(await resp.text())
    assert doc["openapi"].startswith("3.0.")
    routes = {
        (r.method.lower(), r.resource.canonical)
        for r in client.app.router.routes()
        if r.resource is not None
        and not r.resource.canonical.startswith("/static")
        and r.method != "HEAD"
    }
    documented = {(m, p) for p, ops in doc["paths"].items() for m in ops}
    assert routes == documented
    for ops in doc["paths"].values():
        for op in ops.values():
            assert op["responses"], op
    _resolve_refs(doc, doc)  # every $ref points at something
    drive = doc["components"]["schemas"]["DriveRequest"]
    assert drive["additionalProperties"] is False
    assert set(drive["required"]) == {"left_mm_s", "right_mm_s"}


# --- control endpoints -------------------------------------------------------------------


@pytest.mark.parametrize(
    ("path", "body"),
    # Anything but a stop: "hold" needs no token (test_a_stop_needs_no_token).
    [("/api/mode", {"mode": "follow"}), ("/api/drive", {"left_mm_s": 0, "right_mm_s": 0})],
)
async def test_control_disabled_without_token(
    open_client: TestClient[Any, Any], path: str, body: dict[str, Any], controls: FakeControls
) -> None:
    for headers in ({}, {"Authorization": "Bearer anything"}, {"Authorization": "Bearer "}):
        resp = await open_client.post(path, json=body, headers=headers)
        assert resp.status == 403
        assert "disabled" in (await resp.json())["error"]
    assert controls.modes == [] and controls.drives == []


@pytest.mark.parametrize(
    ("path", "body"),
    # Anything but a stop: "hold" needs no token (test_a_stop_needs_no_token).
    [("/api/mode", {"mode": "follow"}), ("/api/drive", {"left_mm_s": 0, "right_mm_s": 0})],
)
@pytest.mark.parametrize(
    "header",
    [None, "Bearer wrong", f"Basic {TOKEN}", "Bearer", TOKEN, f"Bearer {TOKEN}x", "Bearer ünïcode"],
)
async def test_control_needs_the_right_token(
    client: TestClient[Any, Any],
    controls: FakeControls,
    path: str,
    body: dict[str, Any],
    header: str | None,
) -> None:
    headers = {} if header is None else {"Authorization": header}
    resp = await client.post(path, json=body, headers=headers)
    assert resp.status == 401
    assert resp.headers["WWW-Authenticate"].startswith("Bearer")
    assert controls.modes == [] and controls.drives == []


async def test_mode_change(client: TestClient[Any, Any], controls: FakeControls) -> None:
    for mode in ("hold", "manual", "follow"):
        resp = await client.post("/api/mode", json={"mode": mode}, headers=AUTH)
        assert resp.status == 200
        assert await resp.json() == {"ok": True, "mode": mode}
    assert controls.modes == [Mode.HOLD, Mode.MANUAL, Mode.FOLLOW]


BAD_MODE_BODIES: list[tuple[str, str | None]] = [
    ("{", None),
    ("", None),
    ("[1, 2]", None),
    ('"hold"', None),
    ("{}", "mode"),
    ('{"mode": "fast"}', "mode"),
    ('{"mode": 1}', "mode"),
    ('{"mode": null}', "mode"),
    ('{"mode": "hold", "speed": 3}', "speed"),
]


@pytest.mark.parametrize(("body", "field"), BAD_MODE_BODIES)
async def test_mode_bad_input_is_400_naming_the_field(
    client: TestClient[Any, Any], controls: FakeControls, body: str, field: str | None
) -> None:
    resp = await client.post(
        "/api/mode", data=body, headers={**AUTH, "Content-Type": "application/json"}
    )
    assert resp.status == 400
    doc = await resp.json()
    assert doc["field"] == field and doc["error"]
    assert controls.modes == []


BAD_DRIVE_BODIES: list[tuple[str, str | None]] = [
    ("not json", None),
    ("null", None),
    ('{"left_mm_s": 100}', "right_mm_s"),
    ('{"right_mm_s": 100}', "left_mm_s"),
    ('{"left_mm_s": "100", "right_mm_s": 100}', "left_mm_s"),
    ('{"left_mm_s": 100, "right_mm_s": true}', "right_mm_s"),
    ('{"left_mm_s": null, "right_mm_s": 0}', "left_mm_s"),
    ('{"left_mm_s": [1], "right_mm_s": 0}', "left_mm_s"),
    ('{"left_mm_s": NaN, "right_mm_s": 0}', None),
    ('{"left_mm_s": 0, "right_mm_s": Infinity}', None),
    ('{"left_mm_s": 1e400, "right_mm_s": 0}', "left_mm_s"),
    ('{"left_mm_s": 0, "right_mm_s": -1200.5}', "right_mm_s"),
    ('{"left_mm_s": 5000, "right_mm_s": 0}', "left_mm_s"),
    ('{"left_mm_s": 0, "right_mm_s": 0, "turbo": true}', "turbo"),
    ("[" * 10000, None),  # deeper than the JSON parser recurses
]


@pytest.mark.parametrize(("body", "field"), BAD_DRIVE_BODIES)
async def test_drive_bad_input_is_400_naming_the_field(
    client: TestClient[Any, Any],
    controls: FakeControls,
    state: RelayState,
    body: str,
    field: str | None,
) -> None:
    state.mode = Mode.MANUAL
    resp = await client.post(
        "/api/drive", data=body, headers={**AUTH, "Content-Type": "application/json"}
    )
    assert resp.status == 400
    doc = await resp.json()
    assert doc["field"] == field and doc["error"]
    assert controls.drives == []


async def test_drive_outside_manual_is_409(
    client: TestClient[Any, Any], controls: FakeControls, state: RelayState
) -> None:
    for mode in (Mode.FOLLOW, Mode.HOLD):
        state.mode = mode
        resp = await client.post(
            "/api/drive", json={"left_mm_s": 100, "right_mm_s": 100}, headers=AUTH
        )
        assert resp.status == 409
        doc = await resp.json()
        assert doc["mode"] == str(mode) and "manual" in doc["error"]
    assert controls.drives == []


async def test_drive_in_manual(
    client: TestClient[Any, Any], controls: FakeControls, state: RelayState
) -> None:
    state.mode = Mode.MANUAL
    resp = await client.post(
        "/api/drive", json={"left_mm_s": 150, "right_mm_s": -75.5}, headers=AUTH
    )
    assert resp.status == 200
    assert await resp.json() == {"ok": True, "left_mm_s": 150.0, "right_mm_s": -75.5}
    resp = await client.post(
        "/api/drive", json={"left_mm_s": 1200, "right_mm_s": -1200}, headers=AUTH
    )
    assert resp.status == 200
    assert controls.drives == [(150.0, -75.5), (1200.0, -1200.0)]


async def test_oversized_body_is_refused(
    client: TestClient[Any, Any], controls: FakeControls
) -> None:
    body = json.dumps({"mode": "hold", "pad": "x" * 100_000})
    resp = await client.post("/api/mode", data=body, headers=AUTH)
    assert resp.status == 413
    assert controls.modes == []


# --- /events -----------------------------------------------------------------------------


async def _next_event(content: Any, kind: str, timeout_s: float = 3.0) -> dict[str, Any]:
    """Read SSE frames until one of type `kind`; returns its JSON data."""
    async with asyncio.timeout(timeout_s):
        event, data = None, None
        while True:
            line = (await content.readline()).decode().rstrip("\n")
            if line.startswith("event: "):
                event = line[7:]
            elif line.startswith("data: "):
                data = line[6:]
            elif line == "" and event is not None:
                if event == kind:
                    assert data is not None
                    parsed: dict[str, Any] = json.loads(data)
                    return parsed
                event, data = None, None


async def test_events_push_a_new_snapshot_after_touch(
    client: TestClient[Any, Any], state: RelayState
) -> None:
    resp = await client.get("/events")
    assert resp.status == 200
    assert resp.headers["Content-Type"].startswith("text/event-stream")
    first = await _next_event(resp.content, "status")
    assert first["state"] == "driving"
    state.state = DriveState.LEADER_LOST
    state.reason = "leader below -85 dBm for 3 scans"
    state.touch()
    second = await _next_event(resp.content, "status")
    assert second["state"] == "leader_lost" and second["reason"].startswith("leader below")
    resp.close()


async def test_events_heartbeat_while_idle(client: TestClient[Any, Any]) -> None:
    resp = await client.get("/events")
    await _next_event(resp.content, "status")
    beat = await _next_event(resp.content, "heartbeat", timeout_s=2.0)
    assert "uptime_s" in beat
    resp.close()


async def test_shutdown_ends_open_event_streams(
    state: RelayState, controls: FakeControls, clock: ManualClock
) -> None:
    app = make_app(state, controls, clock=clock, token=TOKEN, sse_heartbeat_s=60.0)
    runner, port = await start_api(app, "127.0.0.1", 0)
    assert port > 0
    async with ClientSession() as session:
        resp = await session.get(f"http://127.0.0.1:{port}/events")
        await _next_event(resp.content, "status")
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        await asyncio.wait_for(runner.cleanup(), 5.0)
        assert loop.time() - t0 < 1.5
        resp.close()


async def test_start_api_reports_the_bound_port(
    state: RelayState, controls: FakeControls, clock: ManualClock
) -> None:
    runner, port = await start_api(
        make_app(state, controls, clock=clock, token=None), "127.0.0.1", 0
    )
    try:
        async with (
            ClientSession() as session,
            session.get(f"http://127.0.0.1:{port}/status") as resp,
        ):
            assert resp.status == 200
    finally:
        await runner.cleanup()


async def test_live_page_and_assets_are_served(client: TestClient[Any, Any]) -> None:
    resp = await client.get("/")
    assert resp.status == 200 and resp.content_type == "text/html"
    html = await resp.text()
    assert "/static/app.js" in html and "/static/style.css" in html
    assert "http://" not in html and "https://" not in html  # no CDN: works offline
    assert "default-src 'self'" in resp.headers["Content-Security-Policy"]
    for asset, ctype in (("/static/app.js", "javascript"), ("/static/style.css", "text/css")):
        r = await client.get(asset)
        assert r.status == 200 and ctype in r.content_type
        text = await r.text()
        assert "https://" not in text


@pytest.mark.parametrize("header", [None, "Bearer wrong"])
async def test_a_stop_needs_no_token(
    client: TestClient[Any, Any],
    open_client: TestClient[Any, Any],
    controls: FakeControls,
    header: str | None,
) -> None:
    """Stopping is always safe: hold is one click, with a token or without, configured or not."""
    headers = {} if header is None else {"Authorization": header}
    for c in (client, open_client):
        resp = await c.post("/api/mode", json={"mode": "hold"}, headers=headers)
        assert resp.status == 200, await resp.text()
    assert controls.modes and all(str(m) == "hold" for m in controls.modes)
    # ... and nothing that makes it move does.
    for body in ({"mode": "follow"}, {"mode": "manual"}):
        resp = await client.post("/api/mode", json=body, headers=headers)
        assert resp.status == 401


async def test_tokenless_stops_are_logged_at_a_bounded_rate(
    client: TestClient[Any, Any], controls: FakeControls, clock: ManualClock
) -> None:
    """A stop is open to anyone on the bridge; a script sending a thousand of them must not
    fill the journal: one line, then one a minute with the count it stands for."""
    import structlog

    with structlog.testing.capture_logs() as logs:
        for _ in range(50):
            assert (await client.post("/api/mode", json={"mode": "hold"})).status == 200
        clock.advance(61.0)
        assert (await client.post("/api/mode", json={"mode": "hold"})).status == 200
    lines = [e for e in logs if e["event"] == "api_stop_without_token"]
    assert [e["count"] for e in lines] == [1, 50], lines
    assert len(controls.modes) == 51


async def test_failed_authentication_backs_the_client_off(
    client: TestClient[Any, Any], controls: FakeControls
) -> None:
    from relayd.api.app import AUTH_FREE_FAILURES

    wrong = {"Authorization": "Bearer wrong"}
    codes = [
        (await client.post("/api/mode", json={"mode": "follow"}, headers=wrong)).status
        for _ in range(AUTH_FREE_FAILURES + 3)
    ]
    assert codes[:AUTH_FREE_FAILURES] == [401] * AUTH_FREE_FAILURES
    assert 429 in codes[AUTH_FREE_FAILURES:]
    # While backed off even the right token is refused, without a comparison: guessing is
    # slowed to the backoff's pace, whatever the guesser does.
    resp = await client.post("/api/mode", json={"mode": "follow"}, headers=AUTH)
    assert resp.status == 429 and int(resp.headers["Retry-After"]) >= 1
    assert [str(m) for m in controls.modes] == []


async def test_event_streams_are_capped_and_status_keeps_its_room(
    client: TestClient[Any, Any],
) -> None:
    from relayd.api.app import CONTEXT

    ctx = client.server.app[CONTEXT]
    ctx.max_streams_per_client, ctx.max_streams = 2, 3
    held = [await client.get("/events") for _ in range(2)]
    assert [r.status for r in held] == [200, 200]
    refused = await client.get("/events")
    assert refused.status == 503 and refused.headers["Retry-After"]
    assert "too many event streams" in (await refused.json())["error"]
    assert (await client.get("/status")).status == 200
    assert (await client.post("/api/mode", json={"mode": "hold"})).status == 200
    for r in held:
        r.close()
