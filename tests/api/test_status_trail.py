"""/status's `trail` against its typed model and the OpenAPI schema."""

from __future__ import annotations

import json

from relayd.api.openapi import STATUS_SCHEMA
from relayd.api.status import Status
from relayd.core.plan.navigator import Navigator
from relayd.core.trail.keeper import TrailKeeper, TrailParams
from relayd.runtime.state import RelayState


def test_a_live_trail_matches_the_model_and_the_schema() -> None:
    keeper = TrailKeeper(TrailParams(pursuit="trail"))
    for k in range(12):  # a leader walking away along x, seen from the origin
        keeper.scan(float(k), (0.0, 0.0, 0.0), 0.0, 3.0, -30.0 - k, None)
    keeper.steer(12.0, (0.0, 0.0, 0.0), ())
    nav = Navigator()
    for k in range(-20, 21):  # a wall across the way, 2 m ahead
        nav.grid.set_occupied(nav.grid.cell(2.0, 0.1 * k), 0.0)
    assert nav.steer(12.0, (0.0, 0.0, 0.0), keeper.goal_xy((0.0, 0.0, 0.0), 0.0)) is not None
    st = RelayState()
    st.trail_source = lambda: {**keeper.view().to_json(), "detour_m": nav.path_json()}
    doc = st.snapshot(13.0)
    status = Status.model_validate_json(json.dumps(doc), strict=True)
    assert status.model_dump(mode="json") == doc
    trail = status.trail
    assert trail is not None and trail.source == "estimate"
    assert trail.leader_xy_m is not None and trail.leader_sigma_m is not None
    assert trail.points_m and trail.steer_deg is not None
    assert trail.detour_m is not None and len(trail.detour_m) >= 3  # round the wall's end
    props = STATUS_SCHEMA["properties"]["trail"]
    assert props["nullable"] is True
    assert set(props["properties"]) == set(doc["trail"])


def test_bearing_pursuit_says_so() -> None:
    keeper = TrailKeeper(TrailParams(pursuit="bearing"))
    keeper.scan(0.0, (0.0, 0.0, 0.0), 10.0, 3.0, -40.0, None)
    view = keeper.view().to_json()
    assert view["source"] == "bearing" and view["leader_xy_m"] is not None


def test_the_own_path_resource_matches_its_schema() -> None:
    from relayd.api.openapi import PATH_SCHEMA
    from relayd.api.status import OwnPath

    keeper = TrailKeeper(TrailParams())
    assert keeper.path_json() == {"pose": None, "points": []}
    for k in range(50):  # 20 mm a SIP: a point each 0.1 m
        keeper.own_pose(0.1 * k, (20.0 * k, 0.0, 0.0))
    doc = keeper.path_json()
    path = OwnPath.model_validate_json(json.dumps(doc), strict=True)
    assert path.model_dump(mode="json") == doc
    assert path.pose is not None and path.pose.x_m == 0.98
    assert 9 <= len(path.points) <= 10  # 0.98 m driven, float steps at the 0.1 m edges
    assert set(PATH_SCHEMA["properties"]) == {"pose", "points"}


async def test_get_path_serves_the_relay_s_own_path() -> None:
    from typing import Any

    from aiohttp.test_utils import TestClient, TestServer

    from relayd.api import make_app
    from tests.support import ManualClock

    class _Controls:
        def set_mode(self, mode: object) -> None: ...
        def manual_drive(self, left_mm_s: float, right_mm_s: float) -> None: ...

    keeper = TrailKeeper(TrailParams())
    keeper.own_pose(1.0, (1500.0, -200.0, 30.0))
    st = RelayState()
    st.path_source = keeper.path_json
    app = make_app(st, _Controls(), clock=ManualClock(10.0), token=None)  # type: ignore[arg-type]
    client: TestClient[Any, Any] = TestClient(TestServer(app, host="127.0.0.1"))
    await client.start_server()
    try:
        resp = await client.get("/path")
        assert resp.status == 200
        doc = await resp.json()
        assert doc["pose"] == {"t": 1.0, "x_m": 1.5, "y_m": -0.2, "theta_deg": 30.0}
        assert doc["points"] == [[1.0, 1.5, -0.2]]
    finally:
        await client.close()


async def test_a_follower_reads_a_relay_s_path_over_http_and_shows_its_feed() -> None:
    """Relay A's API serves GET /path; relay B's feed client reads it, B's keeper follows it
    (source leader_feed) and B's /status shows the feed, valid against the model and schema."""
    from typing import Any

    from aiohttp.test_utils import TestClient, TestServer

    from relayd.api import make_app
    from relayd.core.trail.align import Frame
    from relayd.core.trail.feed import FeedParams
    from relayd.runtime.leaderfeed import HttpPathClient, parse_path
    from tests.support import ManualClock

    class _Controls:
        def set_mode(self, mode: object) -> None: ...
        def manual_drive(self, left_mm_s: float, right_mm_s: float) -> None: ...

    leader = TrailKeeper(TrailParams())
    for k in range(60):  # 6 m east at 0.5 m/s
        leader.own_pose(0.2 * k, (100.0 * k, 0.0, 0.0))
    st_a = RelayState()
    st_a.path_source = leader.path_json
    app = make_app(st_a, _Controls(), clock=ManualClock(10.0), token=None)  # type: ignore[arg-type]
    client: TestClient[Any, Any] = TestClient(TestServer(app, host="127.0.0.1"))
    await client.start_server()
    try:
        feed_client = HttpPathClient(str(client.make_url("/")))
        event = parse_path(await feed_client.fetch(), 12.0)
        await feed_client.close()
    finally:
        await client.close()
    follower = TrailKeeper(
        TrailParams(pursuit="trail", feed=FeedParams(prior=Frame(1.5, 0.0, 0.0)))
    )
    follower.leader_path(event)
    got = follower.steer(12.2, (0.0, 0.0, 0.0), ())
    assert got is not None and got.steer_deg is not None and abs(got.steer_deg) < 1.0
    st_b = RelayState()
    st_b.trail_source = lambda: {**follower.view().to_json(), "detour_m": None}
    doc = st_b.snapshot(12.3)
    status = Status.model_validate_json(json.dumps(doc), strict=True)
    assert status.model_dump(mode="json") == doc
    assert status.trail is not None and status.trail.source == "leader_feed"
    assert status.trail.feed is not None and status.trail.feed.state == "up"
    feed_schema = STATUS_SCHEMA["properties"]["trail"]["properties"]["feed"]
    assert set(feed_schema["properties"]) == set(doc["trail"]["feed"])
