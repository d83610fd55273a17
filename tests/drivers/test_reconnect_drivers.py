"""Each driver on the shared reconnect loop (`Reconnect.run`): how it reads a failure.

The loop itself is tested in test_reconnect.py; the drivers' reconnects after a lost
device in their own tests. Here: a bug inside one connection (not a device problem) is
an ERROR with its traceback, kept in the driver's health, and the driver goes on
(reconnecting if the link went with it) instead of dying. In-memory fakes on virtual time.
"""

from __future__ import annotations

import asyncio
import itertools
from typing import Any

import pytest
from structlog.testing import capture_logs

from drivers.airos import AirOsPoller
from drivers.airos.fake import FakeAirOs
from drivers.airos.model import LinkQuality
from drivers.arcos import ArcosRobot
from drivers.arcos.fake import FakeRobot
from drivers.arcos.session import ArcosSession
from drivers.pantilt import ServoCalibration, make_pantilt
from drivers.pantilt.fake import FakeMaestro
from drivers.transport.backoff import Backoff
from drivers.transport.health import LinkState
from tests.support import LoopClock, running, until

pytestmark = pytest.mark.virtual_time


def errors_with_traceback(logs: list[dict[str, Any]], event: str) -> list[str]:
    return [
        e["error"]
        for e in logs
        if e["event"] == event and e["log_level"] == "error" and e.get("exc_info") is True
    ]


async def test_a_bug_in_a_robot_session_is_loud_and_the_robot_reconnects(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    clock = LoopClock()
    fake = FakeRobot(clock=clock)
    robot = ArcosRobot(
        fake.serve_memory("bug-robot"),
        clock=clock,
        backoff=Backoff(initial_s=0.1, maximum_s=0.2, jitter=0),
    )
    serve = ArcosSession.serve
    bugs = [KeyError("sonar")]

    async def buggy_serve(session: ArcosSession) -> None:
        if bugs:
            raise bugs.pop()
        await serve(session)

    monkeypatch.setattr(ArcosSession, "serve", buggy_serve)
    try:
        with capture_logs() as logs:
            async with running(robot):
                await until(
                    lambda: robot.health().reconnects == 1 and robot.connected,
                    "the robot back after the bug",
                )
                await until(lambda: robot.health().state is LinkState.UP, "SIPs again")
                h = robot.health()
                # (last_error then tells how the dropped session's port ended.)
                assert h.counters["link_errors"] == 0 and h.counters["sessions"] == 2
        assert errors_with_traceback(logs, "robot_session_failed") == [
            "unexpected: KeyError('sonar')"
        ]
    finally:
        await fake.stop()


async def test_shutting_a_robot_down_is_not_a_failure() -> None:
    clock = LoopClock()
    fake = FakeRobot(clock=clock)
    robot = ArcosRobot(fake.serve_memory("closing-robot"), clock=clock)
    try:
        with capture_logs() as logs:
            async with running(robot) as task:
                await until(lambda: robot.connected, "the robot up")
                await robot.shutdown()  # closes the port under the session
                await asyncio.wait_for(task, 5.0)  # run() returns instead of reconnecting
        assert robot.health().state is LinkState.CLOSED
        assert not [e for e in logs if e["event"] == "robot_session_failed"]
    finally:
        await fake.stop()


async def test_a_bug_in_a_servo_poll_is_loud_and_the_servo_task_lives_on() -> None:
    clock = LoopClock()
    fake = FakeMaestro(clock=clock)
    pt = make_pantilt(
        "maestro",
        fake.serve_memory("bug-servo"),
        None,
        {0: ServoCalibration()},
        clock=clock,
        poll_s=1.0,
        backoff=Backoff(initial_s=0.1, jitter=0),
    )
    poll = pt._poll
    bugs = [ZeroDivisionError("division by zero")]

    async def buggy_poll() -> None:
        if bugs:
            raise bugs.pop()
        await poll()

    pt._poll = buggy_poll  # type: ignore[method-assign]
    try:
        with capture_logs() as logs:
            async with running(pt):
                await until(lambda: not bugs and pt.health().errors == 1, "the bug")
                commands = pt.counters["commands"]
                # The port itself is fine, so it is kept: served again after the backoff.
                await until(lambda: pt.counters["commands"] >= commands + 2, "polls again")
                h = pt.health()
                assert h.state is LinkState.UP and h.errors == 1
                assert h.last_error == "unexpected: ZeroDivisionError('division by zero')"
        expected = ["unexpected: ZeroDivisionError('division by zero')"]
        assert errors_with_traceback(logs, "pantilt_connect_failed") == expected
    finally:
        await pt.close()
        fake.close()


async def test_a_bug_in_an_airos_poll_is_loud_and_polling_goes_on() -> None:
    clock = LoopClock()
    updates: list[LinkQuality] = []
    async with FakeAirOs("ubnt", "secret-pass", clock=clock) as fake:
        poller = AirOsPoller(
            fake.base_url or "",
            "ubnt",
            "secret-pass",
            poll_s=1.0,
            clock=clock,
            on_update=updates.append,
        )
        fetch = poller.client.fetch
        bugs = [KeyError("wireless")]

        async def buggy_fetch() -> LinkQuality:
            if bugs and updates:  # one good poll first, then the bug
                raise bugs.pop()
            return await fetch()

        poller.client.fetch = buggy_fetch  # type: ignore[method-assign]
        with capture_logs() as logs:
            async with running(poller):
                await until(lambda: poller.state == "unreachable", "the bug")
                assert poller.last_error == "KeyError: 'wireless'"
                assert poller.health().state is LinkState.DOWN and poller.counters["errors"] == 1
                await until(lambda: poller.state == "ok" and len(updates) >= 3, "polling again")
        assert errors_with_traceback(logs, "airos_poll_crashed") == ["KeyError: 'wireless'"]
        assert poller.counters["logins"] == 1  # the session was kept across the bug


async def test_airos_polls_at_a_fixed_rate_and_backs_off_on_the_shared_loop() -> None:
    clock = LoopClock()
    polled_t: list[float] = []
    async with FakeAirOs("ubnt", "secret-pass", clock=clock) as fake:
        poller = AirOsPoller(
            fake.base_url or "",
            "ubnt",
            "secret-pass",
            poll_s=1.0,
            clock=clock,
            on_update=lambda q: polled_t.append(clock.now()),
            backoff=Backoff(initial_s=1.0, maximum_s=5.0, jitter=0),
        )
        async with running(poller):
            await until(lambda: len(polled_t) >= 4, "four polls")
            gaps = [b - a for a, b in itertools.pairwise(polled_t)]
            # The request's own latency is not added: one poll per clock second.
            assert gaps == pytest.approx([1.0] * len(gaps), abs=0.05)
            assert poller.counters["errors"] == 0
