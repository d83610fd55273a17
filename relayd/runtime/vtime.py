"""Virtual time: an asyncio event loop whose clock jumps instead of waiting.

`VirtualTimeLoop.time()` is virtual. Whenever the loop would block in `select()`
waiting for its next timer, it polls the real file descriptors with timeout 0 instead
and, when nothing is ready, moves its clock straight to that timer. So every
`asyncio.sleep`, `call_later`, `asyncio.timeout` and driver timer fires in order at
its exact virtual time, as fast as the CPU allows, and a run whose I/O is all
in-process (memory links, in-process fakes) is deterministic: the same inputs give
the same callbacks in the same order at the same times.

Real sockets still work (the status API answers during a simulation): they are
polled on every turn. With `speed` set, the loop paces itself to `speed` x wall
time (it really waits, up to the next timer, so a person can watch the live page);
without it, it runs flat out.

`LoopClock` is the `drivers.transport.clock.Clock` for code running on such a loop: its now()
is the loop's time and its sleeps are plain loop sleeps, so one clock serves the
world, the fakes and the daemons. On an ordinary loop it is the monotonic clock.

Decision: our own ~100 lines rather than the `looptime` library. looptime does the
same thing (it patches a running loop's `time()` and its selector's timeout) but is
built as a pytest plugin around pytest-asyncio's loops; the simulator needs the same
loop outside pytest (`relayd sim`), with `--speed` pacing, and a subclass of the
standard loop is simpler to reason about than patching one in place.
"""

from __future__ import annotations

import asyncio
import selectors
import time
from collections.abc import Coroutine
from contextlib import AbstractAsyncContextManager
from typing import Any, TypeVar

from drivers.transport.clock import Clock

T = TypeVar("T")

#: Where virtual time starts: far from 0, so no code can mistake it for "unset".
VIRTUAL_EPOCH_S = 1000.0


class _JumpingSelector(selectors.DefaultSelector):
    """Polls the real descriptors without blocking; tells the loop how far to jump."""

    def __init__(self, loop: VirtualTimeLoop) -> None:
        super().__init__()
        self._vloop = loop

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        loop = self._vloop
        events = super().select(0)
        if events or timeout == 0:
            return events
        if timeout is None:
            # No timer at all: nothing virtual can happen until real I/O arrives.
            return super().select(None)
        if loop.speed is None:
            loop._advance(timeout)
            return events
        # Paced: wait for real I/O up to the timer's wall-clock equivalent.
        started = time.monotonic()
        events = super().select(timeout / loop.speed)
        if events:
            loop._advance(min(timeout, (time.monotonic() - started) * loop.speed))
        else:
            loop._advance(timeout)
        return events


class VirtualTimeLoop(asyncio.SelectorEventLoop):
    """A selector event loop on virtual time; `speed=None`: as fast as possible."""

    def __init__(self, *, start_s: float = VIRTUAL_EPOCH_S, speed: float | None = None) -> None:
        self._vtime = float(start_s)
        self.speed = speed
        super().__init__(_JumpingSelector(self))
        if speed is not None and not speed > 0:
            self.close()
            raise ValueError(f"speed must be > 0 or None, got {speed!r}")

    def time(self) -> float:
        return self._vtime

    def _advance(self, seconds: float) -> None:
        if seconds > 0:
            self._vtime += seconds


def run(
    coro: Coroutine[Any, Any, T], *, speed: float | None = None, start_s: float = VIRTUAL_EPOCH_S
) -> T:
    """`asyncio.run` on a fresh virtual-time loop."""
    # The main task hands its result over here instead of holding it: when asyncio.Runner
    # restores the SIGINT handler it builds (and throws away) the repr of its handler,
    # which names the main task and so the task's result, in full. For a simulation's
    # result (thousands of trace records) that cost about 2 % of a run, twice.
    result: list[T] = []

    async def main() -> None:
        result.append(await coro)

    with asyncio.Runner(
        loop_factory=lambda: VirtualTimeLoop(start_s=start_s, speed=speed)
    ) as runner:
        runner.run(main())
    return result[0]


class LoopClock(Clock):
    """The clock of whatever loop runs the code: virtual on a `VirtualTimeLoop`."""

    __slots__ = ("_loop",)

    def __init__(self, loop: asyncio.AbstractEventLoop | None = None) -> None:
        super().__init__(1.0)
        self._loop = loop

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            self._loop = asyncio.get_running_loop()
        return self._loop

    def now(self) -> float:
        return self.loop.time()

    def to_real(self, seconds: float) -> float:
        # Every timer here is a loop timer (aiohttp's too), measured in loop seconds.
        return seconds

    async def sleep(self, seconds: float) -> None:
        await asyncio.sleep(max(0.0, seconds))

    def timeout(self, seconds: float | None) -> AbstractAsyncContextManager[object]:
        return asyncio.timeout(seconds)

    async def wait_for(self, aw: object, seconds: float | None) -> object:
        return await asyncio.wait_for(aw, seconds)  # type: ignore[arg-type]
