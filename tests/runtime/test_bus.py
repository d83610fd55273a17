"""The event bus: the control path runs synchronously in publish order; readers never block it."""

from __future__ import annotations

import asyncio
from collections.abc import Sequence

import pytest

from relayd.runtime.bus import Bus
from tests.support import until


def test_control_path_sees_every_event_in_order_and_its_actions_follow() -> None:
    seen: list[int] = []
    done: list[tuple[int, tuple[str, ...]]] = []

    def brain(e: int) -> list[str]:
        seen.append(e)
        return [f"a{e}"]

    bus: Bus[int, str] = Bus(brain, lambda e, acts: done.append((e, tuple(acts))))
    for i in range(5):
        bus.publish(i)
    assert seen == [0, 1, 2, 3, 4]
    assert done == [(i, (f"a{i}",)) for i in range(5)]


def test_reentrant_publish_is_handled_after_the_current_event() -> None:
    order: list[str] = []
    bus: Bus[str, str] = Bus()

    def brain(e: str) -> list[str]:
        order.append(f"brain {e}")
        return [e]

    def act(e: str, actions: Sequence[str]) -> None:
        order.append(f"act {e}")
        if e == "sip":
            bus.publish("echo")  # e.g. a device answering at once
            order.append("after publish")

    bus.connect(brain, act)
    bus.publish("sip")
    assert order == ["brain sip", "act sip", "after publish", "brain echo", "act echo"]


def test_a_full_queue_drops_the_oldest_and_counts_it() -> None:
    bus: Bus[int, None] = Bus()
    sub = bus.subscribe("slow", maxlen=3)
    for i in range(10):
        bus.publish(i)
    assert sub.dropped == 7
    assert [sub.get_nowait() for _ in range(3)] == [7, 8, 9]
    assert sub.get_nowait() is None


async def test_a_slow_subscriber_never_delays_the_control_path() -> None:
    controlled: list[int] = []
    bus: Bus[int, None] = Bus(lambda e: controlled.append(e) or [], None)
    fast = bus.subscribe("fast", maxlen=1000)
    slow = bus.subscribe("slow", maxlen=4)
    got_fast: list[int] = []
    got_slow: list[int] = []

    stuck = asyncio.Event()  # never set: the slow reader hangs after its first event

    async def reader(sub: object, out: list[int], hang: bool) -> None:
        while True:
            out.append(await sub.get())  # type: ignore[attr-defined]
            if hang:
                await stuck.wait()

    tasks = [
        asyncio.create_task(reader(fast, got_fast, False)),
        asyncio.create_task(reader(slow, got_slow, True)),
    ]
    try:
        for i in range(100):
            bus.publish(i)  # synchronous: returns without waiting for any reader
            assert controlled[-1] == i
            await asyncio.sleep(0)
        await until(lambda: len(got_fast) >= 100, "the fast reader to catch up")
        assert got_fast == list(range(100))
        assert slow.dropped > 0
        assert len(slow) <= 4
    finally:
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


async def test_closed_subscription_ends_its_reader() -> None:
    bus: Bus[int, None] = Bus()
    sub = bus.subscribe("r")
    bus.unsubscribe(sub)
    with pytest.raises(EOFError):
        await sub.get()
    bus.publish(1)  # nobody is left to receive it
    assert sub.get_nowait() is None
