"""Shared test helpers: waiting for a condition, and a daemon running on the fakes.

Tests poll for conditions instead of sleeping: the machines that run CI are shared
and slow, so every wait has a generous timeout and fails with what it waited for.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator, Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from relayd.daemon import Daemon


async def until(pred: Callable[[], object], what: str = "the condition", timeout_s: float = 30.0,
                poll_s: float = 0.005) -> float:
    """Poll `pred` until it is truthy; return the monotonic time it became so.

    Raises AssertionError naming `what` after `timeout_s` of wall time.
    """
    try:
        async with asyncio.timeout(timeout_s):
            while not pred():
                await asyncio.sleep(poll_s)
    except TimeoutError:
        raise AssertionError(f"timed out after {timeout_s} s waiting for {what}") from None
    return time.monotonic()


@contextlib.asynccontextmanager
async def running(daemon: Daemon) -> AsyncIterator[asyncio.Task[None]]:
    """Run `daemon` in a task for the block; cancel it (its safe shutdown) afterwards."""
    task = asyncio.create_task(daemon.run(), name="daemon")
    try:
        yield task
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
