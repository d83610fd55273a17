"""Owns relayd's long-lived tasks: one per device plus the scanner, controller and API.

A bare `asyncio.TaskGroup` cancels every sibling when one child fails; on a robot a
flaky servo adapter must never take the base driver down. So each task runs inside a
keeper loop that logs the failure, counts it in the device's health and restarts the
task after a capped backoff, leaving the others alone; a device's task failing is also
reported to `on_fault` (the daemon publishes it as the device's FAULT). Shutdown cancels tasks in the
reverse of the order they were added, waiting for each, so the robot driver (added
first) is the last to go and its safe stop still has a controller-free port.

A keeper ends only by cancellation; one that ends otherwise (a BaseException the keeper
does not catch: SystemExit, a library's own BaseException subclass) has left its task
dead for good, with nothing to restart it. `wait_fatal()` raises then, so the daemon
shuts down with the safe stop instead of driving on with a dead control loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

import structlog

from drivers.transport.backoff import Backoff
from drivers.transport.clock import REAL_CLOCK, Clock
from relayd.runtime.state import RelayState

log = structlog.get_logger(__name__)

#: A task that ran this long before failing counts as healthy: its backoff restarts small.
HEALTHY_AFTER_S = 10.0


class TaskDied(RuntimeError):
    """A supervised task ended in a way its keeper cannot restart from."""


@dataclass(slots=True)
class _Entry:
    name: str
    factory: Callable[[], Awaitable[None]]
    device: str | None
    task: asyncio.Task[None] | None = None
    restarts: int = 0
    backoff: Backoff = field(default_factory=lambda: Backoff(initial_s=0.2, maximum_s=5.0))


class Supervisor:
    """Start, keep alive and stop a fixed set of named tasks."""

    def __init__(
        self,
        state: RelayState,
        clock: Clock = REAL_CLOCK,
        on_fault: Callable[[str, str], None] | None = None,
    ) -> None:
        self._state = state
        self._clock = clock
        #: Told (device, message) when a device's task fails; the daemon publishes a FAULT.
        self._on_fault = on_fault
        self._entries: list[_Entry] = []
        self._stopping = False
        self._fatal: asyncio.Future[None] | None = None

    def stopping(self) -> bool:
        """Whether stop() has begun (read after an await: another task may have called it)."""
        return self._stopping

    def add(
        self, name: str, factory: Callable[[], Awaitable[None]], *, device: str | None = None
    ) -> None:
        """Register a task; `device` names the health entry its failures are counted in."""
        self._entries.append(_Entry(name, factory, device))

    @property
    def names(self) -> list[str]:
        return [e.name for e in self._entries]

    def restarts(self, name: str) -> int:
        return next(e.restarts for e in self._entries if e.name == name)

    def start(self) -> None:
        for entry in self._entries:
            if entry.task is None:
                entry.task = asyncio.create_task(self._keep(entry), name=f"relayd:{entry.name}")
                entry.task.add_done_callback(functools.partial(self._ended, entry))

    async def wait_fatal(self) -> None:
        """Wait until a keeper dies (raises TaskDied from its exception); else forever."""
        if self._fatal is None:
            self._fatal = asyncio.get_running_loop().create_future()
        await asyncio.shield(self._fatal)

    def _ended(self, entry: _Entry, task: asyncio.Task[None]) -> None:
        if task.cancelled() or self._stopping:
            return
        exc = task.exception()
        died = TaskDied(f"task {entry.name} died: {exc!r}")
        died.__cause__ = exc
        log.critical("task_died", task=entry.name, error=repr(exc))
        if self._fatal is None:
            self._fatal = task.get_loop().create_future()
        if not self._fatal.done():
            self._fatal.set_exception(died)

    async def _keep(self, entry: _Entry) -> None:
        while not self._stopping:
            started = self._clock.now()
            try:
                await entry.factory()
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                if self.stopping():
                    return
                self._record_failure(entry, f"{type(exc).__name__}: {exc}")
                log.exception("task_failed", task=entry.name, restarts=entry.restarts)
            else:
                if self.stopping():
                    return  # e.g. the robot driver ending run() after its safe stop
                # Long-lived tasks do not return; one that does is restarted like a failure.
                self._record_failure(entry, "task returned")
                log.warning("task_exited", task=entry.name, restarts=entry.restarts)
            if self._clock.now() - started > HEALTHY_AFTER_S:
                entry.backoff.reset()
            entry.restarts += 1
            await self._clock.sleep(entry.backoff.next_delay())

    def _record_failure(self, entry: _Entry, message: str) -> None:
        if entry.device is not None:
            self._state.record_failure(entry.device, message)
            if self._on_fault is not None:
                try:
                    self._on_fault(entry.device, message)
                except Exception:
                    log.exception("fault_report_failed", task=entry.name)

    def begin_stop(self) -> None:
        """Shutdown has begun: a task ending from now on is neither restarted nor reported."""
        self._stopping = True

    async def stop(self, timeout_s: float = 1.0) -> None:
        """Cancel every task, newest first, waiting at most `timeout_s` (wall) for each."""
        self._stopping = True
        for entry in reversed(self._entries):
            task = entry.task
            if task is None or task.done():
                continue
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, TimeoutError, Exception):
                await asyncio.wait_for(asyncio.shield(task), timeout_s)
            if not task.done():
                log.error("task_stop_timeout", task=entry.name)
