"""Supervisor: a failing task restarts alone; shutdown cancels everything, newest first."""

from __future__ import annotations

import asyncio

import pytest

from relayd.runtime.state import RelayState
from relayd.runtime.supervisor import Supervisor
from tests.support import LoopClock, until


# Virtual time: the restart backoff (0.2, 0.4 s, ...) and the tasks' own pauses take no
# wall time, and a loaded machine cannot reorder them.
@pytest.mark.virtual_time
async def test_failing_task_restarts_without_touching_others() -> None:
    state = RelayState()
    sup = Supervisor(state, LoopClock())
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
    await until(lambda: ticks["flaky"] >= 3, "the flaky task's third run")
    steady_before = ticks["steady"]
    await until(
        lambda: ticks["steady"] > steady_before, "the steady task ticking on", timeout_s=1.0
    )
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


@pytest.mark.virtual_time
async def test_returning_task_is_restarted() -> None:
    sup = Supervisor(RelayState(), LoopClock())
    runs = 0

    async def short() -> None:
        nonlocal runs
        runs += 1

    sup.add("short", short)
    sup.start()
    await until(lambda: runs >= 3, "the third run of the returning task")
    await sup.stop()


class _Injected(BaseException):
    """Not an Exception: the keeper lets it through, so the task is dead for good."""


async def test_a_task_dead_beyond_its_keeper_is_fatal() -> None:
    from relayd.runtime.supervisor import TaskDied

    sup = Supervisor(RelayState(), LoopClock())

    async def dies() -> None:
        await asyncio.sleep(0)
        raise _Injected("boom")

    sup.add("dies", dies)
    sup.start()
    with pytest.raises(TaskDied, match="dies") as info:
        async with asyncio.timeout(5):
            await sup.wait_fatal()
    assert isinstance(info.value.__cause__, _Injected)
    await sup.stop()


async def test_no_task_dying_keeps_wait_fatal_waiting_and_a_stop_is_not_fatal() -> None:
    sup = Supervisor(RelayState(), LoopClock())

    async def forever() -> None:
        await asyncio.Event().wait()

    sup.add("forever", forever)
    sup.start()
    waiter = asyncio.ensure_future(sup.wait_fatal())
    await asyncio.sleep(0.05)
    await sup.stop()
    await asyncio.sleep(0)
    assert not waiter.done()
    waiter.cancel()
