"""Stopping the simulator's own tasks: cancel a set of them and wait until all have ended.

The runners stop their relays' daemons, the MobileSim engine its leader's driver and
each ARCOS bridge its forwarding tasks the same way at the end of a run. A task being
stopped may fail on its way out (a closed socket, a device gone first): that is not the
run's result, so its error is retrieved here and dropped. A cancellation of the caller
while it waits is not swallowed: it reaches the caller (a second Ctrl-C during the
teardown), whose own `finally` then decides what must still be stopped.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterable
from typing import Any


async def cancel_and_wait(tasks: Iterable[asyncio.Task[Any] | None]) -> None:
    """Cancel every task of `tasks` (None entries skipped) and wait until each has ended."""
    todo = [t for t in tasks if t is not None]
    for t in todo:
        t.cancel()
    if todo:
        await asyncio.wait(todo)
    for t in todo:
        if not t.cancelled():
            t.exception()  # retrieved, so asyncio does not log it as never retrieved
