"""/status's `trail` (issue 26) against its typed model and the OpenAPI schema."""

from __future__ import annotations

import json

from relayd.api.openapi import STATUS_SCHEMA
from relayd.api.status import Status
from relayd.core.trail.keeper import TrailKeeper, TrailParams
from relayd.runtime.state import RelayState


def test_a_live_trail_matches_the_model_and_the_schema() -> None:
    keeper = TrailKeeper(TrailParams(pursuit="trail"))
    for k in range(12):  # a leader walking away along x, seen from the origin
        keeper.scan(float(k), (0.0, 0.0, 0.0), 0.0, 3.0, -30.0 - k, None)
    keeper.steer(12.0, (0.0, 0.0, 0.0), ())
    st = RelayState()
    st.trail_source = lambda: keeper.view().to_json()
    doc = st.snapshot(13.0)
    status = Status.model_validate_json(json.dumps(doc), strict=True)
    assert status.model_dump(mode="json") == doc
    trail = status.trail
    assert trail is not None and trail.source == "estimate"
    assert trail.leader_xy_m is not None and trail.leader_sigma_m is not None
    assert trail.points_m and trail.steer_deg is not None
    props = STATUS_SCHEMA["properties"]["trail"]
    assert props["nullable"] is True
    assert set(props["properties"]) == set(doc["trail"])


def test_bearing_pursuit_says_so() -> None:
    keeper = TrailKeeper(TrailParams(pursuit="bearing"))
    keeper.scan(0.0, (0.0, 0.0, 0.0), 10.0, 3.0, -40.0, None)
    view = keeper.view().to_json()
    assert view["source"] == "bearing" and view["leader_xy_m"] is not None
