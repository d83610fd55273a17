"""Serial ports over real ptys: every hang-up, drop and cancel ends with the port closed.

The 60-minute soak lost a relay's pan-tilt for good: a port the driver had given up
(three unanswered requests) reported connection_lost from pyserial-asyncio's
background close *after* the driver had already reopened the tty, the driver took
that for the loss of the new port and forgot it unclosed, and the forgotten port kept
the tty's flock: every later open failed with EAGAIN. On a loaded machine the close
report comes late; here the loop's executor reports `Serial.close` late on purpose.

Each test counts the process's descriptors on the pty slave: the fake keeps one, the
driver may hold one while connected, and nothing else may ever be there.
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import os
import threading
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest
import serial_asyncio_fast

from drivers.pantilt import PanTilt, PanTiltError, ServoCalibration, make_pantilt
from drivers.pantilt.fake import FakeMaestro
from drivers.transport.clock import Clock
from drivers.transport.link import LinkError, open_link
from tests.support import until

SPEED = 10.0
#: How late the executor reports a finished Serial.close (wall seconds): later than
#: the driver's reconnect after a drop, as on the soak's loaded machine.
LATE_CLOSE_S = 0.4


def fds_on(path: str) -> int:
    """This process's open descriptors on the tty behind `path` (a symlink to a pty slave)."""
    target = os.path.realpath(path)
    n = 0
    for fd in os.listdir("/proc/self/fd"):
        try:
            if os.readlink(f"/proc/self/fd/{fd}") == target:
                n += 1
        except OSError:
            continue
    return n


def lockable(path: str) -> bool:
    """True if nobody holds the tty's exclusive lock (what the driver's open needs)."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    finally:
        os.close(fd)
    return True


#: Loop turns given to a late close report's callbacks (the transport's connection_lost,
#: the driver's handling of it) once the report itself is in.
SETTLE_TURNS = 20


@pytest.fixture
async def late_close(monkeypatch: pytest.MonkeyPatch) -> AsyncIterator[list[asyncio.Future[Any]]]:
    """The loop's executor closes a Serial at once but reports it `LATE_CLOSE_S` later.

    Yields the reports (futures) handed out so far, so a test can wait until every one
    has come in instead of sleeping for the longest it might take."""
    loop = asyncio.get_running_loop()
    orig = loop.run_in_executor
    reports: list[asyncio.Future[Any]] = []

    def run_in_executor(executor: Any, fn: Callable[..., Any], *args: Any) -> asyncio.Future[Any]:
        fut = orig(executor, fn, *args)
        if getattr(fn, "__name__", "") != "close":
            return fut
        late: asyncio.Future[Any] = loop.create_future()
        reports.append(late)

        def report() -> None:
            if late.done():
                return
            if fut.cancelled():
                late.cancel()
            elif fut.exception() is not None:
                late.set_exception(fut.exception())  # type: ignore[arg-type]
            else:
                late.set_result(fut.result())

        fut.add_done_callback(lambda _f: loop.call_later(LATE_CLOSE_S, report))
        return late

    monkeypatch.setattr(loop, "run_in_executor", run_in_executor)
    yield reports


async def _rig(tmp_path: Path, **options: float) -> tuple[FakeMaestro, PanTilt, asyncio.Task[None]]:
    clock = Clock(SPEED)
    fake = FakeMaestro(clock=clock)
    path = fake.serve_pty(tmp_path / "servo")
    opts: dict[str, float] = {"reply_timeout_s": 1.0, "poll_s": 1000.0}
    opts.update(options)
    pt = make_pantilt("maestro", path, None, {0: ServoCalibration()}, clock=clock, **opts)
    task = asyncio.create_task(pt.run())
    await until(lambda: pt.connected, "the first connection")
    return fake, pt, task


async def _close(fake: FakeMaestro, pt: PanTilt, task: asyncio.Task[None]) -> None:
    path = fake.path
    await pt.close()
    await asyncio.wait_for(task, 5)
    if fake._port is not None and fake._port.is_open:
        # Closed means closed: only the fake's own end is left on the tty.
        assert fds_on(path) == 1
    fake.close()


async def _connected_and_alone(
    fake: FakeMaestro, pt: PanTilt, what: str, reports: list[asyncio.Future[Any]]
) -> None:
    # Connected to the port that is there now: a request is answered (right after a
    # quick pull and replug the driver may still hold the port that just went away).
    async def answered() -> bool:
        if not pt.connected:
            return False
        with contextlib.suppress(PanTiltError):
            await pt.is_moving()
            return True
        return False

    await until(answered, f"{what}: a request answered on the new port", 20.0, poll_s=0.02)
    # Every late report has come in (and been ignored) before we look.
    await until(
        lambda: all(r.done() for r in reports), f"{what}: the late close reports", timeout_s=20.0
    )
    for _ in range(SETTLE_TURNS):
        await asyncio.sleep(0)
    assert pt.connected, f"{what}: a late close report took the new port down ({pt.last_error})"
    assert fds_on(fake.path) == 2, (
        f"{what}: descriptors on the tty besides the fake's and the driver's"
    )


async def test_a_late_close_report_of_a_dropped_port_leaves_the_new_port_alone(
    tmp_path: Path, late_close: list[asyncio.Future[Any]]
) -> None:
    """The soak's failure: silent controller, drop, fast reconnect, late report; five times."""
    fake, pt, task = await _rig(tmp_path, poll_s=0.5)
    try:
        for cycle in range(5):
            reconnects = pt.counters["reconnects"]
            fake.silent = True
            await until(lambda: not pt.connected, "the silent controller dropped")
            fake.silent = False
            await _connected_and_alone(fake, pt, f"cycle {cycle}", late_close)
            assert pt.counters["reconnects"] == reconnects + 1
    finally:
        await _close(fake, pt, task)


async def test_hang_ups_idle_under_a_write_and_during_a_connect(
    tmp_path: Path, late_close: list[asyncio.Future[Any]]
) -> None:
    """Pulled and replugged twelve times, in the three places it hurts; reconnects every time."""
    fake, pt, task = await _rig(tmp_path, reply_timeout_s=0.5)
    try:
        for cycle in range(12):
            kind = ("idle", "write", "connect")[cycle % 3]
            reconnects = pt.counters["reconnects"]
            if kind == "write":
                # The write hits EIO: pyserial-asyncio's fatal write error aborts the port.
                fake.hang_up()
                with pytest.raises(Exception):  # noqa: B017 - PanTiltError or no reply
                    await pt.set_angle(0, 5.0 * cycle)
                    await pt.is_moving()
            else:
                fake.hang_up()
            await until(lambda: not pt.connected, f"cycle {cycle}: the hang-up noticed")
            if kind == "connect":
                # Plugged in, and pulled again while the driver opens or handshakes.
                errors = pt.counters["errors"]
                fake.reappear()
                await until(
                    lambda e=errors: (
                        pt.counters["errors"] > e or pt.connected or fds_on(fake.path) > 1
                    ),
                    f"cycle {cycle}: a connect under way",
                )
                fake.hang_up()
                # The fault injected, not a wait for an outcome: the cable stays out this
                # long mid-connect; whatever the driver makes of it, it must then recover.
                await asyncio.sleep(0.05)
            fake.reappear()
            await _connected_and_alone(fake, pt, f"cycle {cycle} ({kind})", late_close)
            assert pt.counters["reconnects"] > reconnects
    finally:
        await _close(fake, pt, task)


async def test_close_ends_with_the_port_closed_when_the_background_close_is_cancelled(
    tmp_path: Path,
) -> None:
    fake, pt, task = await _rig(tmp_path)
    try:
        assert fds_on(fake.path) == 2
        closing = asyncio.create_task(pt.close())
        await asyncio.sleep(0)  # the transport has scheduled its background close...
        cancelled = [t for t in serial_asyncio_fast._BACKGROUND_TASKS if not t.done()]
        assert cancelled, "pyserial-asyncio closed without a background task"
        for t in cancelled:
            t.cancel()  # ...which never runs (a cancelled task, a loop shutting down)
        t0 = time.monotonic()
        await closing
        assert time.monotonic() - t0 < 3.0
        assert fds_on(fake.path) == 1
        assert lockable(fake.path)
        await asyncio.wait_for(task, 5)
    finally:
        await _close(fake, pt, task)


async def test_an_open_cancelled_in_the_executor_leaves_no_port_open(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fake = FakeMaestro(clock=Clock(SPEED))
    path = fake.serve_pty(tmp_path / "servo")
    loop = asyncio.get_running_loop()
    orig = loop.run_in_executor
    started = asyncio.Event()
    given_up = threading.Event()  # set once the caller has cancelled the open

    def slow_open(executor: Any, fn: Callable[..., Any], *args: Any) -> asyncio.Future[Any]:
        # Ours opens with _open_serial; pyserial-asyncio's own path with serial_for_url.
        if getattr(getattr(fn, "func", fn), "__name__", "") not in (
            "_open_serial",
            "serial_for_url",
        ):
            return orig(executor, fn, *args)

        def opened_late() -> Any:
            port = fn(*args)  # the port is open (and flocked) here...
            loop.call_soon_threadsafe(started.set)
            given_up.wait(30)  # ...and the executor is still busy when the caller gives up
            return port

        return orig(executor, opened_late)

    monkeypatch.setattr(loop, "run_in_executor", slow_open)
    try:
        opening = asyncio.create_task(open_link(path, 115200, asyncio.Protocol))
        await started.wait()
        assert fds_on(path) == 2
        opening.cancel()
        with pytest.raises(asyncio.CancelledError):
            await opening
        given_up.set()
        await until(lambda: fds_on(path) == 1, "the cancelled open's port closed", timeout_s=5.0)
        assert lockable(path)
        monkeypatch.undo()
        transport, _ = await open_link(path, 115200, asyncio.Protocol)
        closed = asyncio.Event()
        transport.set_protocol(_Lost(closed))
        transport.close()
        await asyncio.wait_for(closed.wait(), 5)
        assert fds_on(path) == 1
        with pytest.raises(LinkError):
            await open_link(str(tmp_path / "no-such-tty"), 115200, asyncio.Protocol)
    finally:
        given_up.set()
        fake.close()


class _Lost(asyncio.Protocol):
    def __init__(self, closed: asyncio.Event) -> None:
        self.closed = closed

    def connection_lost(self, exc: Exception | None) -> None:
        self.closed.set()
