"""Supervisor: a failing task restarts alone; shutdown cancels everything, newest first."""

from __future__ import annotations

import asyncio

from drivers.clock import Clock
from relayd.state import RelayState
from relayd.supervisor import Supervisor


async def test_failing_task_restarts_without_touching_others() -> None:
    state = RelayState()
    sup = Supervisor(state, Clock(speed=50))
    ticks = {"steady": 0, "flaky": 0}

    async def steady() -> None:
        while True:
            ticks["steady"] += 1
            await asyncio.sleep(0.001)

    async def flaky() -> None:
        ticks["flaky"] += 1
        await asyncio.sleep(0.001)
        raise OSError("servo adapter unplugged")

    sup.add("steady", steady)
    sup.add("flaky", flaky, device="pantilt")
    sup.start()
    async with asyncio.timeout(5):
        while ticks["flaky"] < 3:
            await asyncio.sleep(0.005)
    steady_before = ticks["steady"]
    await asyncio.sleep(0.02)
    assert ticks["steady"] > steady_before  # still running
    assert sup.restarts("flaky") >= 2
    assert state.health["pantilt"].errors >= 2
    assert "servo adapter unplugged" in (state.health["pantilt"].last_error or "")
    await sup.stop()
    assert all(t.done() for t in asyncio.all_tasks() if t.get_name().startswith("relayd:"))


async def test_stop_order_is_reverse_of_start() -> None:
    sup = Supervisor(RelayState())
    order: list[str] = []

    def make(name: str):
        async def task() -> None:
            try:
                await asyncio.Event().wait()
            finally:
                order.append(name)
        return task

    for name in ("robot", "scanner", "control"):
        sup.add(name, make(name))
    sup.start()
    await asyncio.sleep(0)
    await sup.stop()
    assert order == ["control", "scanner", "robot"]


async def test_returning_task_is_restarted() -> None:
    sup = Supervisor(RelayState(), Clock(speed=100))
    runs = 0

    async def short() -> None:
        nonlocal runs
        runs += 1

    sup.add("short", short)
    sup.start()
    async with asyncio.timeout(5):
        while runs < 3:
            await asyncio.sleep(0.005)
    await sup.stop()
