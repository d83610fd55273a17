"""Time for drivers, fakes and the daemon, with an optional speed-up for the simulator.

Every timer in relayd (SIP period, resend interval, staleness limits, servo slew,
poll periods) is expressed in *clock seconds*. On a robot the clock is the monotonic
clock. The real-time simulator (bench/soak.py) shares one `Clock(speed)` between every
party, so a 100 ms SIP period passes in 100/speed ms of wall time and the behaviour is
the same at any speed; `relayd sim` runs on virtual time instead (relayd/runtime/vtime.py's
`LoopClock`, a subclass reading the virtual loop's time).
"""

from __future__ import annotations

import asyncio
import time
from contextlib import AbstractAsyncContextManager


class Clock:
    """Monotonic time, optionally running `speed` times faster than wall time."""

    __slots__ = ("_m0", "_t0", "speed")

    def __init__(self, speed: float = 1.0) -> None:
        if not speed > 0:
            raise ValueError(f"clock speed must be > 0, got {speed!r}")
        self.speed = float(speed)
        self._m0 = time.monotonic()
        self._t0 = self._m0

    def now(self) -> float:
        """Clock seconds (monotonic; comparable only with other readings of this clock)."""
        return self._t0 + (time.monotonic() - self._m0) * self.speed

    def to_real(self, seconds: float) -> float:
        """Wall-clock seconds that `seconds` of clock time take."""
        return seconds / self.speed

    async def sleep(self, seconds: float) -> None:
        await asyncio.sleep(max(0.0, seconds) / self.speed)

    def timeout(self, seconds: float | None) -> AbstractAsyncContextManager[object]:
        """`asyncio.timeout` measured in clock seconds."""
        return asyncio.timeout(None if seconds is None else seconds / self.speed)

    async def wait_for(self, aw: object, seconds: float | None) -> object:
        return await asyncio.wait_for(aw, None if seconds is None else seconds / self.speed)  # type: ignore[arg-type]


#: The clock of a real robot: wall time, speed 1.
REAL_CLOCK = Clock()
