"""Device health in /status: the driver's own view plus the supervisor's failure count.

The defect this pins: the supervisor counted a failed device task in
`health[device].errors`, and the daemon's 0.5 s health loop then overwrote the field
with the driver's counters, so the failure vanished from /status and /metrics within
half a second. Now health is read from the driver at snapshot time and the
supervisor's count is added on top. Runs in virtual time with the robot on an
in-memory link: seconds of daemon time cost milliseconds.
"""

from __future__ import annotations

import pytest

from drivers.arcos.fake import FakeRobot
from relayd.config import Settings
from relayd.daemon import Daemon
from relayd.vtime import LoopClock


def _settings(robot_url: str) -> Settings:
    return Settings.model_validate({
        "robot": {"port": robot_url},
        "pantilt": {"enabled": False},
        "wifi": {"enabled": False},
        "api": {"enabled": False},
    })


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
