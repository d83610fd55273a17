"""Each driver's `health()`: a frozen snapshot that follows the device up, down and back."""

from __future__ import annotations

import asyncio
import dataclasses
from pathlib import Path

import pytest

from drivers.airos import AirOsPoller
from drivers.airos.fake import FakeAirOs
from drivers.arcos import ArcosRobot
from drivers.arcos.fake import FakeRobot
from drivers.pantilt import ServoCalibration, make_pantilt
from drivers.pantilt.fake import FakeMaestro
from drivers.transport.backoff import Backoff
from drivers.transport.clock import Clock
from drivers.transport.health import DeviceHealth, LinkState
from drivers.wifi.fake import ProcfsWriter
from drivers.wifi.sources import ProcfsSource
from tests.support import running, until


def test_health_is_frozen_and_its_counters_read_only() -> None:
    counters = {"sips": 1}
    h = DeviceHealth("robot", LinkState.UP, counters=counters)
    counters["sips"] = 2  # the driver keeps counting; the snapshot does not move
    assert h.counters["sips"] == 1 and h.connected
    with pytest.raises(dataclasses.FrozenInstanceError):
        h.errors = 3  # type: ignore[misc]
    with pytest.raises(TypeError):
        h.counters["sips"] = 5  # type: ignore[index]
    assert h.age_s(10.0) is None
    assert DeviceHealth("x", LinkState.STALE, last_rx_t=4.0).age_s(10.0) == 6.0
    assert not DeviceHealth("x", LinkState.STALE).connected


async def test_robot_health_follows_the_session() -> None:
    clock = Clock(10.0)
    fake = FakeRobot(clock=clock)
    robot = ArcosRobot(
        fake.serve_memory("health-robot"),
        clock=clock,
        backoff=Backoff(initial_s=0.1, maximum_s=0.2, jitter=0),
    )
    assert robot.health().state is LinkState.CONNECTING
    try:
        async with running(robot):
            await until(lambda: robot.health().state is LinkState.UP, "robot up")
            h = robot.health()
            assert h.connected and h.device == "robot" and h.last_rx_t is not None
            assert h.counters["sips"] >= 1 and h.reconnects == 0
            fake.hang_up()
            await until(lambda: robot.health().state is LinkState.DOWN, "robot down")
            down = robot.health()
            assert not down.connected and down.last_error is not None
            assert down.last_rx_t is not None and down.last_rx_t >= h.last_rx_t  # kept after loss
            fake.reappear()
            await until(lambda: robot.health().connected, "robot back")
            assert robot.health().reconnects == 1
        await robot.shutdown()
        assert robot.health().state is LinkState.CLOSED
    finally:
        await fake.stop()


async def test_pantilt_health_counts_timeouts_as_errors() -> None:
    clock = Clock(10.0)
    fake = FakeMaestro(clock=clock)
    pt = make_pantilt(
        "maestro",
        fake.serve_memory("health-servo"),
        None,
        {0: ServoCalibration()},
        clock=clock,
        reply_timeout_s=0.5,
        poll_s=1000.0,
        max_timeouts=5,
    )
    assert pt.health().state is LinkState.CONNECTING
    task = asyncio.create_task(pt.run())
    try:
        await until(lambda: pt.health().connected, "servo up")
        assert pt.health().last_rx_t is not None
        fake.silent = True
        with pytest.raises(Exception, match="no reply"):
            await pt.is_moving()
        h = pt.health()
        assert h.state is LinkState.STALE and h.errors >= 1 and h.counters["timeouts"] == 1
        fake.silent = False
        await pt.is_moving()
        assert pt.health().state is LinkState.UP
    finally:
        await pt.close()
        await task
        fake.close()
    assert pt.health().state is LinkState.CLOSED


async def test_poller_health() -> None:
    clock = Clock(20.0)
    async with FakeAirOs("ubnt", "secret-pass", clock=clock) as fake:
        poller = AirOsPoller(fake.base_url or "", "ubnt", "secret-pass", poll_s=1.0, clock=clock)
        assert poller.health().state is LinkState.CONNECTING
        task = asyncio.create_task(poller.run())
        try:
            await until(lambda: poller.health().connected, "radio up")
            h = poller.health()
            assert h.device == "ap" and h.last_rx_t == poller.last_update_t and h.errors == 0
        finally:
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task


async def test_wifi_source_health(tmp_path: Path) -> None:
    path = tmp_path / "wireless"
    writer, src = ProcfsWriter(path, "wlan1"), ProcfsSource("wlan1", path=path)
    assert src.health().state is LinkState.CONNECTING
    writer.write(-60)
    sample = await src.read()
    h = src.health()
    assert h.connected and h.last_rx_t == sample.t and h.device == "wifi"
    writer.remove_interface()
    await src.read()
    h = src.health()
    assert h.state is LinkState.DOWN and h.errors == 1 and h.last_error is not None
