"""Device health in /status: the driver's own view plus the supervisor's failure count.

The defect this pins: the supervisor counted a failed device task in
`health[device].errors`, and the daemon's 0.5 s health loop then overwrote the field
with the driver's counters, so the failure vanished from /status and /metrics within
half a second. Now health is read from the driver at snapshot time and the
supervisor's count is added on top. Runs in virtual time with the robot on an
in-memory link: seconds of daemon time cost milliseconds. A failed device task is
also published on the bus as the device's FAULT, and the device's UP follows once the
shell sees it usable again.
"""

from __future__ import annotations

import asyncio

import pytest

from drivers.arcos.fake import FakeRobot
from relayd.config.model import Settings
from relayd.core.events import DeviceEvent, DeviceStatus
from relayd.daemon import Daemon
from relayd.runtime.vtime import LoopClock


def _settings(robot_url: str) -> Settings:
    return Settings.model_validate(
        {
            "robot": {"port": robot_url},
            "pantilt": {"enabled": False},
            "wifi": {"enabled": False},
            "api": {"enabled": False},
        }
    )


@pytest.mark.virtual_time
async def test_supervisor_failure_count_survives_in_status() -> None:
    clock = LoopClock()
    fake = FakeRobot(clock=clock)
    url = fake.serve_memory("health-robot")
    await fake.start()
    daemon = Daemon(_settings(url), clock=clock, env={})
    failures = 0

    async def flaky_helper() -> None:
        # A task the supervisor keeps for the robot device that fails once a second.
        nonlocal failures
        await clock.sleep(1.0)
        failures += 1
        raise OSError("helper lost the robot")

    daemon.supervisor.add("robot-helper", flaky_helper, device="robot")
    await daemon.start()
    try:
        await clock.sleep(5.0)  # ten periods of the old 0.5 s health copy
        assert failures >= 2
        robot = daemon.robot
        assert robot is not None and robot.connected
        shown = daemon.state.snapshot(clock.now())["health"]["robot"]
        driver_errors = robot.health().errors
        supervised = daemon.state.health["robot"].errors
        assert supervised >= 2
        assert shown["errors"] == driver_errors + supervised
        assert shown["connected"] is True
    finally:
        await daemon.shutdown()
        await fake.stop()


@pytest.mark.virtual_time
async def test_a_failed_device_task_is_published_as_fault_then_up_again() -> None:
    clock = LoopClock()
    fake = FakeRobot(clock=clock)
    url = fake.serve_memory("fault-robot")
    await fake.start()
    daemon = Daemon(_settings(url), clock=clock, env={})
    devices = daemon.bus.subscribe("test-devices", maxlen=10_000)
    failed = False

    async def helper_that_fails_once() -> None:
        nonlocal failed
        await clock.sleep(2.0)
        if not failed:
            failed = True
            raise OSError("helper lost the robot")
        await asyncio.Event().wait()

    daemon.supervisor.add("robot-helper", helper_that_fails_once, device="robot")
    started = clock.now()
    await daemon.start()
    try:
        await clock.sleep(4.0)
        seen = [
            e
            for e in iter(devices.get_nowait, None)
            if isinstance(e, DeviceEvent) and e.device == "robot"
        ]
        statuses = [e.status for e in seen]
        # Down until the handshake, up, the fault, and up again on the next tick.
        assert statuses == [
            DeviceStatus.DOWN,
            DeviceStatus.UP,
            DeviceStatus.FAULT,
            DeviceStatus.UP,
        ], seen
        fault, back = seen[2], seen[3]
        assert fault.detail == "OSError: helper lost the robot"
        assert fault.t - started == pytest.approx(2.0, abs=0.2)
        assert back.t - fault.t <= 0.11  # one control tick
    finally:
        await daemon.shutdown()
        await fake.stop()
