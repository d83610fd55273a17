"""The /status document against its typed model (relayd.api.status.Status).

`RelayState.snapshot()` builds the dict by hand for speed; these tests hold it to the
model, which is also where the OpenAPI schema comes from.
"""

from __future__ import annotations

import json

from drivers.transport.clock import Clock
from drivers.transport.health import DeviceHealth, LinkState
from relayd.api.demo import populate
from relayd.api.openapi import STATUS_SCHEMA
from relayd.api.status import Status
from relayd.core.vocab import ScanRecord
from relayd.runtime.state import LinkInfo, RelayState


def _validate(doc: dict[str, object]) -> Status:
    # JSON mode: what a client decodes (enums as strings, ints where floats are allowed).
    return Status.model_validate_json(json.dumps(doc), strict=True)


def test_a_fresh_state_matches_the_model() -> None:
    doc = RelayState().snapshot(0.0)
    status = _validate(doc)
    assert set(doc) == set(Status.model_fields)
    assert status.last_scan is None and status.health == {}


def test_a_busy_state_matches_the_model_field_by_field() -> None:
    st = RelayState(
        started_t=1.0,
        bearing_deg=12.5,
        rssi_leader_dbm=-48.0,
        x_mm=10.0,
        y_mm=-3.0,
        theta_deg=5.0,
        battery_v=12.9,
        robot_name="relay1",
    )
    st.last_scan = ScanRecord(
        t=2.0,
        angles_deg=(-10.0, 0.0, 10.0),
        rssi_dbm=(-60.0, -50.0, -55.0),
        bearing_deg=1.0,
        rssi_leader_dbm=-50.0,
        situation=0,
        period_s=1.2,
    )
    st.links["rear"] = LinkInfo(signal_dbm=-55.0, ccq_pct=90.0, t=2.5)
    st.health_sources["robot"] = lambda: DeviceHealth(
        "robot", LinkState.UP, last_rx_t=2.9, errors=1
    )
    st.health["pantilt"] = DeviceHealth(
        "pantilt", LinkState.DOWN, errors=2
    )  # the supervisor's record
    st.thresholds = {"threshold_l_dbm": -30.0}
    doc = st.snapshot(3.0)
    status = _validate(doc)
    assert status.model_dump(mode="json") == doc
    assert status.health["robot"].errors == 1 and status.health["pantilt"].errors == 2


def test_the_demo_state_matches_the_model() -> None:
    clock = Clock()
    st = RelayState()
    populate(st, clock)
    _validate(st.snapshot(clock.now()))


def test_the_openapi_schema_is_the_models() -> None:
    assert list(STATUS_SCHEMA["properties"]) == list(Status.model_fields)
    assert STATUS_SCHEMA["required"] == list(Status.model_fields)
    assert STATUS_SCHEMA["properties"]["bearing_deg"]["nullable"] is True
    assert STATUS_SCHEMA["properties"]["mode"]["enum"] == ["follow", "hold", "manual"]
    assert STATUS_SCHEMA["properties"]["sonar_mm"]["minItems"] == 16
    assert "$ref" not in json.dumps(STATUS_SCHEMA) and "anyOf" not in json.dumps(STATUS_SCHEMA)
