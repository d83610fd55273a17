"""The daemon's history ring buffer and GET /history: bounded, incremental, restart-safe."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest
from aiohttp.test_utils import TestClient, TestServer

from relayd.api import make_app
from relayd.api.demo import DemoControls, populate
from relayd.api.history import FIELDS, History, parse_after
from relayd.core.vocab import DriveState
from relayd.runtime.state import RelayState
from tests.support import ManualClock, until


def _state(clock: ManualClock) -> RelayState:
    st = RelayState()
    populate(st, clock)
    return st


def test_samples_come_from_the_snapshot_and_the_ring_is_bounded() -> None:
    clock = ManualClock(500.0)
    st = _state(clock)
    hist = History(st.snapshot, clock, period_s=1.0, window_s=5.0)
    for i in range(8):
        st.rssi_behind_dbm = -50.0 - i
        st.x_mm = 100.0 * i
        st.state = DriveState.STOPPED if i % 2 else DriveState.DRIVING
        hist.sample()
        clock.t += 1.0
    doc = hist.window(-1)
    cols = doc["samples"]
    assert cols["seq"] == [3, 4, 5, 6, 7]  # five seconds at 1 Hz: the oldest three are gone
    assert cols["rssi_behind_dbm"] == [-53.0, -54.0, -55.0, -56.0, -57.0]
    assert cols["x_mm"] == [300.0, 400.0, 500.0, 600.0, 700.0]
    assert cols["state"] == ["stopped", "driving", "stopped", "driving", "stopped"]
    assert cols["age_s"] == [5.0, 4.0, 3.0, 2.0, 1.0]
    assert set(cols) == {"seq", "age_s", *FIELDS}
    assert doc["next_seq"] == 8
    assert doc["thresholds"]["threshold_b_dbm"] == -60.0


def test_after_returns_only_newer_samples_and_a_future_after_returns_all() -> None:
    clock = ManualClock(500.0)
    st = _state(clock)
    hist = History(st.snapshot, clock, period_s=0.5, window_s=300.0)
    for _ in range(4):
        hist.sample()
    assert hist.window(1)["samples"]["seq"] == [2, 3]
    assert hist.window(3)["samples"]["seq"] == []
    # A page that knew a previous run of the daemon (seq 900) gets everything again.
    assert hist.window(900)["samples"]["seq"] == [0, 1, 2, 3]


def test_non_finite_values_become_null() -> None:
    clock = ManualClock(500.0)
    st = _state(clock)
    st.bearing_deg = float("nan")
    st.rssi_leader_dbm = float("-inf")
    hist = History(st.snapshot, clock)
    hist.sample()
    cols = hist.window(-1)["samples"]
    assert cols["bearing_deg"] == [None] and cols["rssi_leader_dbm"] == [None]


def test_parse_after() -> None:
    assert parse_after(None) == -1 and parse_after("") == -1 and parse_after("17") == 17
    for bad in ("x", "1.5", "-2"):
        with pytest.raises(ValueError):
            parse_after(bad)


def test_bad_window_settings_are_refused() -> None:
    clock = ManualClock(500.0)
    with pytest.raises(ValueError):
        History(_state(clock).snapshot, clock, period_s=0.0)
    with pytest.raises(ValueError):
        History(_state(clock).snapshot, clock, period_s=2.0, window_s=1.0)


async def test_a_broken_snapshot_costs_a_sample_not_the_sampler() -> None:
    clock = ManualClock(500.0)
    st = _state(clock)
    calls = {"n": 0}

    def flaky(now: float) -> dict[str, Any]:
        calls["n"] += 1
        if calls["n"] == 2:
            raise RuntimeError("boom")
        return st.snapshot(now)

    hist = History(flaky, clock, period_s=0.01)
    task = asyncio.create_task(hist.run())
    try:
        await until(lambda: hist.next_seq >= 3, "three samples, one after the failure")
    finally:
        task.cancel()
    assert hist.next_seq >= 3 and calls["n"] >= 4


async def test_history_endpoint_samples_while_the_app_runs() -> None:
    clock = ManualClock(500.0)
    st = _state(clock)
    app = make_app(st, DemoControls(st), clock=clock, token="t" * 20)
    async with TestClient(TestServer(app)) as client:
        resp = await client.get("/history")
        assert resp.status == 200
        doc = await resp.json()
        assert doc["period_s"] == 0.5 and doc["window_s"] == 300.0
        first = doc["samples"]["seq"]
        assert first == [0]  # the sampler's first sample is taken at start-up
        clock.t += 1.0

        async def after_first() -> dict[str, Any] | None:
            doc = await (await client.get("/history", params={"after": "0"})).json()
            return doc if doc["samples"]["seq"] else None

        doc = await until(after_first, "the sampler's next real 0.5 s tick", poll_s=0.05)
        assert doc["samples"]["seq"][0] == 1
        bad = await client.get("/history", params={"after": "soon"})
        assert bad.status == 400
        assert (await bad.json())["field"] == "after"
