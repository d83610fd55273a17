"""The one reconnect loop of every driver: capped backoff and log discipline.

A driver's long-running task connects, serves until the link fails, and tries again.
`Reconnect.run()` is that loop, written once: a driver hands it how to connect and
how to serve one connection, and how to read a failure (`Failure`); the loop counts,
logs, backs off and stops. `Reconnect` is the small state machine behind "tries
again": it counts failures in a row, picks the next delay from a capped `Backoff`,
waits it out (ending early on stop, or at once when an unplugged serial adapter is
plugged back in), and resets when a connection succeeds. It also owns how failures
are logged, the same way for every device:

* the first failure of a streak is a WARNING, repeats are DEBUG, so an unplugged
  device writes one line, not one per retry;
* with `remind_s`, a streak that lasts says so again at WARNING at most that often
  (a refused login, say, is worth a line a minute, not one per try);
* an unexpected exception (a bug, not a device problem) is an ERROR with its
  traceback, every time;
* the first success after failures is an INFO line with the streak's length.

Stopping: `run()` returns once `stop` is set (a failure that the stop itself caused,
the port closed under a session, is not counted), and a cancel goes straight
through it: it starts no task of its own, so nothing outlives it, and what a cancel
must still do on the wire (the robot's safe stop) is the driver's, around `run()`.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from enum import StrEnum

import structlog

from drivers.transport.backoff import Backoff
from drivers.transport.clock import Clock
from drivers.transport.link import wait_before_retry


@dataclass(frozen=True, slots=True)
class Failure:
    """How a driver reads one failed attempt; see `Reconnect.failed` for the fields.

    `unexpected` marks a bug rather than a device problem (ERROR with traceback, and
    counted even while stopping); `text` replaces the exception's own text as the
    error kept in `last_error`.
    """

    kind: str | None = None
    event: str | None = None
    unexpected: bool = False
    text: str | None = None
    fields: Mapping[str, object] = field(default_factory=dict)


#: The reading of an exception no driver expects: a bug.
UNEXPECTED = Failure(unexpected=True)

#: One step of a connection (connect, serve, clean up after a loss).
Step = Callable[[], Awaitable[object]]
#: Reads an exception out of connect or serve; pure (bookkeeping goes in `OnFailure`).
Describe = Callable[[Exception], Failure]
#: The driver's own record of a counted failure: the exception, its reading, the text kept.
OnFailure = Callable[[Exception, Failure, str], None]


def expecting(*types: type[Exception]) -> Describe:
    """The usual reading: an exception of `types` is device trouble, any other a bug."""

    def describe(exc: Exception) -> Failure:
        return Failure() if isinstance(exc, types) else UNEXPECTED

    return describe


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

    def __init__(
        self,
        log: structlog.typing.FilteringBoundLogger,
        event: str,
        *,
        backoff: Backoff,
        clock: Clock,
        url: str = "",
        remind_s: float | None = None,
        recovered_event: str | None = None,
    ) -> None:
        self._log = log
        self.event = event
        self.recovered_event = (
            event.removesuffix("_failed") + "_recovered"
            if recovered_event is None
            else recovered_event
        )
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

    def failed(
        self,
        error: BaseException | str,
        *,
        unexpected: bool = False,
        kind: str | None = None,
        event: str | None = None,
        **fields: object,
    ) -> str:
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
        remind = (
            self.remind_s is not None
            and self._warned_t is not None
            and now - self._warned_t >= self.remind_s
        )
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
        await wait_before_retry(
            self.url, self.next_delay() if delay_s is None else delay_s, self.clock, stop
        )

    def close(self) -> None:
        self.phase = Phase.CLOSED

    async def run(
        self,
        connect: Step,
        serve: Step,
        *,
        stop: asyncio.Event,
        describe: Describe,
        on_failure: OnFailure | None = None,
        after_loss: Step | None = None,
    ) -> None:
        """Connect, serve until the link is lost, back off, again; until `stop` is set.

        `connect()` opens and proves one connection (its success resets the backoff);
        `serve()` runs until that connection ends, by returning (a loss the driver has
        already reported: no failure is counted, the wait is the reset backoff's first
        step) or by raising. An exception out of either is read by `describe` and
        counted and logged by `failed`, then given to `on_failure`; an expected one
        while `stop` is set is the stop's doing and ends the loop uncounted.
        `after_loss()` tidies up a lost connection before the wait (never on stop or
        cancel: a driver's safe stop may still need the port). Returns when `stop`
        is set; raises only what is not an `Exception` (CancelledError).
        """
        while not stop.is_set():
            self.attempt()
            try:
                await connect()
                self.succeeded()
                await serve()
            except Exception as exc:  # noqa: BLE001 - nothing from a device may end the loop; bugs are logged with their traceback
                failure = describe(exc)
                if stop.is_set() and not failure.unexpected:
                    break
                error: BaseException | str = exc if failure.text is None else failure.text
                text = self.failed(
                    error,
                    unexpected=failure.unexpected,
                    kind=failure.kind,
                    event=failure.event,
                    **failure.fields,
                )
                if on_failure is not None:
                    on_failure(exc, failure, text)
            if stop.is_set():
                break
            if after_loss is not None:
                await after_loss()
            await self.wait(stop)
