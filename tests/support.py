"""Shared test helpers: waiting for a condition, virtual time, one manual clock.

Tests poll for conditions instead of sleeping: the machines that run CI are shared
and slow, so every wait has a generous timeout and fails with what it waited for.

Tests marked `virtual_time` run on relayd.runtime.vtime's `VirtualTimeLoop` (tests/conftest.py
picks the loop): when nothing is ready to run the loop's time jumps to its next timer
instead of waiting for it, so a 4 s watchdog or a 60 s backoff take no wall time and a
loaded machine cannot make a timer late. Such a test talks to its fakes over
`memory://` links (no file descriptor); its drivers read time from a `LoopClock`.
`ManualClock` is the one clock a test sets by hand (pure logic that reads `now()`).
"""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import math
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn, Protocol

import pytest

from drivers.transport.clock import Clock
from relayd.runtime.vtime import LoopClock, VirtualTimeLoop

if TYPE_CHECKING:
    from relayd.sim.runner import SimResult, SimRunner

__all__ = [
    "LoopClock",
    "ManualClock",
    "VirtualTimeLoop",
    "clock_for",
    "piped_into_head",
    "run_scenario",
    "running",
    "until",
    "until_sync",
]

ROOT = Path(__file__).resolve().parents[1]


class ManualClock(Clock):
    """A clock that moves only when the test sets or advances `t`; sleeps stay real."""

    def __init__(self, t: float = 100.0) -> None:
        super().__init__()
        self.t = t

    def now(self) -> float:
        return self.t

    def advance(self, seconds: float) -> float:
        self.t += seconds
        return self.t


def is_virtual(request: pytest.FixtureRequest) -> bool:
    return request.node.get_closest_marker("virtual_time") is not None


def clock_for(request: pytest.FixtureRequest, speed: float) -> Clock:
    """The driver clock for a test: loop time if it runs virtual, else `speed` x wall time."""
    return LoopClock() if is_virtual(request) else Clock(speed)


class Runs(Protocol):
    """A daemon or driver whose `run()` goes on until cancelled."""

    def run(self) -> Awaitable[None]: ...


async def until(
    pred: Callable[[], object],
    what: str = "the condition",
    timeout_s: float = 30.0,
    poll_s: float = 0.005,
) -> Any:
    """Poll `pred` until it returns something truthy, and return that.

    `pred` may be a coroutine function (an HTTP probe, a request to a driver): each poll
    awaits it. Raises AssertionError naming `what` after `timeout_s` of loop time (wall
    time, or virtual time in a `virtual_time` test): the timeout only bounds a failure,
    so make it generous. Probes that cost something (an HTTP request) pass a longer `poll_s`.
    """
    try:
        async with asyncio.timeout(timeout_s):
            while True:
                value = pred()
                if inspect.isawaitable(value):
                    value = await value
                if value:
                    return value
                await asyncio.sleep(poll_s)  # the poll interval: this is the waiting helper
    except TimeoutError:
        raise AssertionError(f"timed out after {timeout_s} s waiting for {what}") from None


def until_sync(
    pred: Callable[[], object],
    what: str = "the condition",
    timeout_s: float = 30.0,
    poll_s: float = 0.05,
) -> Any:
    """`until` for synchronous tests (a child process, a file it writes): blocks the thread."""
    deadline = time.monotonic() + timeout_s
    while not (value := pred()):
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(poll_s)  # the poll interval: this is the waiting helper
    return value


@contextlib.asynccontextmanager
async def running(runner: Runs) -> AsyncIterator[asyncio.Task[None]]:
    """Run `runner.run()` in a task for the block; cancel it (its safe shutdown) afterwards."""

    async def run() -> None:
        await runner.run()

    task = asyncio.create_task(run(), name=f"{type(runner).__name__}.run")
    try:
        yield task
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


def parse_unit(text: str) -> dict[str, dict[str, list[str]]]:
    """A systemd unit file as {section: {key: [values in order]}}; asserts its shape."""
    sections: dict[str, dict[str, list[str]]] = {}
    current: dict[str, list[str]] | None = None
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], {})
            continue
        assert current is not None, f"directive outside a section: {line}"
        key, sep, value = line.partition("=")
        assert sep, f"not a key=value line: {line}"
        current.setdefault(key.strip(), []).append(value.strip())
    return sections


def skip_or_fail(message: str) -> NoReturn:
    """Skip where a test's tool is missing, but fail in CI: CI installs it, so a skip
    there would silently check nothing."""
    if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
        pytest.fail(message)
    pytest.skip(message)


def piped_into_head(
    argv: list[str], lines: int = 1, timeout_s: float = 30.0
) -> tuple[int, list[str], str, float]:
    """`relayd ARGV | head -LINES`: read LINES lines of stdout, close it, wait for the exit.

    With `lines=0` the reader closes before the command printed anything. Returns the
    exit code, the lines read, stderr, and the seconds from closing to the exit.
    stderr goes to a file: a flood of log lines must not block the command on a full pipe.
    """
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "relayd", *argv],
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
            env=env,
            cwd=ROOT,
        )
        try:
            assert proc.stdout is not None
            got = [proc.stdout.readline() for _ in range(lines)]
            proc.stdout.close()
            t0 = time.monotonic()
            code = proc.wait(timeout_s)
            waited_s = time.monotonic() - t0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        err.seek(0)
        return code, got, err.read(), waited_s


_scenario_runs: dict[tuple[str, int, float | None], tuple[SimResult, SimRunner]] = {}


def run_scenario(name: str, relays: int, pace: float | None = None) -> tuple[SimResult, SimRunner]:
    """A shipped scenario run once per process on virtual time, with `relays` relays:
    (SimResult, SimRunner). `pace`: paced to that many times wall time (None: flat out)."""
    from relayd.runtime import vtime
    from relayd.sim.runner import SimRunner
    from relayd.sim.scenario import load_scenario

    key = (name, relays, pace)
    if key not in _scenario_runs:
        runner = SimRunner(load_scenario(name).with_relays(relays), speed=pace, seed=1)
        _scenario_runs[key] = (vtime.run(runner.run(), speed=pace), runner)
    return _scenario_runs[key]


def diff_drive(
    pose: tuple[float, float, float],
    left_mm_s: float,
    right_mm_s: float,
    dt_s: float,
    track_mm: float = 400.0,
) -> tuple[float, float, float]:
    """Exact differential-drive kinematics: the pose (mm, mm, deg) after `dt_s` at these wheel speeds."""
    x, y, th = pose
    v = (left_mm_s + right_mm_s) / 2.0
    w = math.degrees((right_mm_s - left_mm_s) / track_mm)
    mid = math.radians(th + w * dt_s / 2.0)
    return x + v * dt_s * math.cos(mid), y + v * dt_s * math.sin(mid), th + w * dt_s


def kill_group(p: subprocess.Popen[bytes]) -> None:
    """SIGKILL a child started with start_new_session=True, its whole process group (a
    Dask nanny and its worker), and reap it."""
    if p.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(p.pid, signal.SIGKILL)
    with contextlib.suppress(subprocess.TimeoutExpired):
        p.wait(timeout=10)


def dask_scheduler(dask_cli: str, log_path: Path) -> tuple[subprocess.Popen[bytes], int]:
    """A real `dask scheduler` on loopback, on a port it picks itself (port 0: a port
    picked here and handed over could be taken by another test's server in between, and
    the client would then read that server's bytes), in its own process group; its
    output goes to log_path. Returns the process and its port, once it listens."""
    log = log_path.open("wb")
    proc = subprocess.Popen(
        [dask_cli, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard"],
        stdout=log,
        stderr=log,
        start_new_session=True,
    )
    log.close()

    def port() -> int | None:
        found = re.search(
            r"Scheduler at:\s*tcp://127\.0\.0\.1:(\d+)", log_path.read_text("utf-8", "replace")
        )
        return int(found.group(1)) if found else None

    return proc, int(until_sync(port, "the dask scheduler's address in its log", 60.0))
