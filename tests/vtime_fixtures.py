"""Virtual time for tests: run a coroutine on a `VirtualTimeLoop`, not on the wall clock.

Use it instead of wall sleeps: with every device on an in-memory link, waiting 5 s
for a fail-safe costs no wall time and never races a loaded machine. A test module
imports the fixture (`from vtime_fixtures import vtime`), writes the test body as a
coroutine taking the loop's clock, and hands it over:

    def test_stops(vtime: VirtualTime) -> None:
        async def body(clock: LoopClock) -> None:
            ...
            await clock.sleep(5.0)      # five virtual seconds, no wall time
        vtime.run(body)

The test itself is a plain function, so no pytest-asyncio loop is involved.
"""

from __future__ import annotations

import functools
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

import pytest

from relayd.vtime import LoopClock, run

T = TypeVar("T")


class VirtualTime:
    """Runs test bodies on a fresh virtual-time loop each."""

    def run(self, body: Callable[[LoopClock], Awaitable[T]], *, speed: float | None = None) -> T:
        async def main() -> T:
            return await body(LoopClock())

        return run(main(), speed=speed)


@pytest.fixture
def vtime() -> VirtualTime:
    return VirtualTime()


def virtual(fn: Callable[..., Awaitable[T]]) -> Callable[..., T]:
    """Run an async test function on a fresh virtual-time loop (a plain test to pytest).

    Its fixtures still arrive as arguments; inside, `LoopClock()` is its clock.
    """

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> T:
        async def main() -> T:
            return await fn(*args, **kwargs)

        return run(main())

    return wrapper
