"""The one reconnect policy of every driver: capped backoff and log discipline.

A driver's long-running task connects, serves until the link fails, and tries again.
`Reconnect` is the small state machine behind "tries again": it counts failures in a
row, picks the next delay from a capped `Backoff`, waits it out (ending early on
close, or at once when an unplugged serial adapter is plugged back in), and resets
when a connection succeeds. It also owns how failures are logged, the same way for
every device:

* the first failure of a streak is a WARNING, repeats are DEBUG, so an unplugged
  device writes one line, not one per retry;
* with `remind_s`, a streak that lasts says so again at WARNING at most that often
  (a refused login, say, is worth a line a minute, not one per try);
* an unexpected exception (a bug, not a device problem) is an ERROR with its
  traceback, every time;
* the first success after failures is an INFO line with the streak's length.
"""

from __future__ import annotations

import asyncio
from enum import StrEnum

import structlog

from drivers.backoff import Backoff
from drivers.clock import Clock
from drivers.link import wait_before_retry


class Phase(StrEnum):
    IDLE = "idle"
    CONNECTING = "connecting"
    UP = "up"
    BACKING_OFF = "backing_off"
    CLOSED = "closed"


class Reconnect:
    """Failure streak, backoff and logging for one device's reconnect loop.

    `log` is the driver's bound structlog logger; `event` names its failure line
    (e.g. "robot_session_failed"; its recovery is then "robot_session_recovered"). `url` is the port: a serial path missing when a
    wait begins is polled and retried as soon as it reappears.
    """

    def __init__(self, log: structlog.typing.FilteringBoundLogger, event: str, *, backoff: Backoff,
                 clock: Clock, url: str = "", remind_s: float | None = None,
                 recovered_event: str | None = None) -> None:
        self._log = log
        self.event = event
        self.recovered_event = (event.removesuffix("_failed") + "_recovered"
                                if recovered_event is None else recovered_event)
        self.backoff = backoff
        self.clock = clock
        self.url = url
        self.remind_s = remind_s
        self.phase = Phase.IDLE
        #: Failures since the last success.
        self.failures = 0
        #: Successful connections after the first one.
        self.reconnects = 0
        self.last_error: str | None = None
        self._ever_up = False
        self._warned_t: float | None = None
        self._kind: str | None = None

    def attempt(self) -> None:
        """A connection attempt begins."""
        if self.phase is not Phase.CLOSED:
            self.phase = Phase.CONNECTING

    def succeeded(self) -> bool:
        """The device answered: reset the backoff. True if this was a reconnect."""
        if self.failures and self.recovered_event:
            self._log.info(self.recovered_event, failures=self.failures)
        self.failures = 0
        self._warned_t = None
        self._kind = None
        self.backoff.reset()
        again = self._ever_up
        if again:
            self.reconnects += 1
        self._ever_up = True
        if self.phase is not Phase.CLOSED:
            self.phase = Phase.UP
        return again

    def failed(self, error: BaseException | str, *, unexpected: bool = False, kind: str | None = None,
               event: str | None = None, **fields: object) -> str:
        """Count a failure, log it as the policy says; returns the error text kept.

        `kind` tells failures apart within a streak: a failure of another kind than
        the last one is news and logged at WARNING like a first one. `event`
        overrides the log event name for this failure.
        """
        if isinstance(error, BaseException):
            text = str(error) or type(error).__name__
            if unexpected:
                text = f"unexpected: {error!r}"
        else:
            text = error
        self.last_error = text
        self.failures += 1
        if self.phase is not Phase.CLOSED:
            self.phase = Phase.BACKING_OFF
        now = self.clock.now()
        name = event or self.event
        new_kind, self._kind = kind != self._kind, kind
        if unexpected:
            # A bug: loud, with its traceback (we are inside the except block).
            self._log.exception(name, error=text, attempt=self.failures, **fields)
            return text
        remind = (self.remind_s is not None and self._warned_t is not None
                  and now - self._warned_t >= self.remind_s)
        if self.failures == 1 or new_kind or remind:
            self._warned_t = now
            self._log.warning(name, error=text, attempt=self.failures, **fields)
        else:
            self._log.debug(name, error=text, attempt=self.failures, **fields)
        return text

    def next_delay(self) -> float:
        """Clock seconds until the next try (capped exponential backoff)."""
        return self.backoff.next_delay()

    async def wait(self, stop: asyncio.Event, delay_s: float | None = None) -> None:
        """Sleep the next backoff delay, or less: `stop` set, or the port plugged back in."""
        await wait_before_retry(self.url, self.next_delay() if delay_s is None else delay_s,
                                self.clock, stop)

    def close(self) -> None:
        self.phase = Phase.CLOSED
