"""The shared reconnect loop and policy: backoff, streaks, log discipline, replug
wake-up, and `Reconnect.run` itself (stop and cancel mid-wait and mid-serve) on
virtual time."""

from __future__ import annotations

import asyncio
import itertools
import random
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import pytest
import structlog
from hypothesis import given, settings
from hypothesis import strategies as st
from structlog.testing import capture_logs

from drivers.transport.backoff import Backoff
from drivers.transport.clock import Clock
from drivers.transport.link import REPLUG_POLL_S
from drivers.transport.reconnect import UNEXPECTED, Describe, Failure, Phase, Reconnect, expecting
from relayd.runtime import vtime
from tests.support import LoopClock, ManualClock, until


@pytest.fixture(autouse=True)
def _default_logging() -> Iterator[None]:
    """structlog's default configuration for these tests: another test (a CLI run) may
    have left a WARNING filter in place, and these tests count DEBUG lines too."""
    previous = structlog.get_config()
    structlog.reset_defaults()
    yield
    structlog.configure(**previous)


def make(clock: Clock | None = None, **kw: object) -> Reconnect:
    return Reconnect(
        structlog.get_logger("test"),
        "dev_failed",
        backoff=Backoff(initial_s=1.0, maximum_s=5.0, jitter=0),
        clock=clock or ManualClock(0.0),
        **kw,
    )  # type: ignore[arg-type]


def levels(logs: Sequence[Mapping[str, Any]], event: str) -> list[object]:
    return [e["log_level"] for e in logs if e["event"] == event]


def test_first_failure_warns_repeats_are_debug_success_resets() -> None:
    r = make()
    with capture_logs() as logs:
        for _ in range(3):
            r.failed(ConnectionError("port gone"))
        assert [r.next_delay() for _ in range(4)] == [1.0, 2.0, 4.0, 5.0]
        assert r.phase is Phase.BACKING_OFF and r.failures == 3 and r.last_error == "port gone"
        assert r.succeeded() is False  # the first connection is not a reconnect
        assert r.next_delay() == 1.0  # the backoff starts over
        r.failed("again")
        assert r.succeeded() is True and r.reconnects == 1
    assert levels(logs, "dev_failed") == ["warning", "debug", "debug", "warning"]
    assert levels(logs, "dev_recovered") == ["info", "info"]


def test_unexpected_errors_are_errors_with_traceback() -> None:
    r = make()
    with capture_logs() as logs:
        try:
            raise KeyError("bug")
        except KeyError as exc:
            text = r.failed(exc, unexpected=True)
    assert text.startswith("unexpected: KeyError")
    assert levels(logs, "dev_failed") == ["error"]
    assert logs[0].get("exc_info") is True


def test_a_new_kind_of_failure_is_news_and_a_long_streak_is_recalled() -> None:
    clock = ManualClock(0.0)
    r = make(clock, remind_s=60.0)
    with capture_logs() as logs:
        r.failed("down", kind="unreachable")
        r.failed("down", kind="unreachable")
        r.failed("refused", kind="auth")
        for _ in range(30):  # 30 more refusals, 5 s apart: 150 s
            clock.advance(5.0)
            r.failed("refused", kind="auth")
    got = levels(logs, "dev_failed")
    assert got[:3] == ["warning", "debug", "warning"]
    assert got[3:].count("warning") == 2  # at 60 s and 120 s


async def test_wait_ends_on_stop_and_on_a_replugged_port(tmp_path: Path) -> None:
    port = tmp_path / "ttyUSB0"
    r = make(Clock(), url=str(port))
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    loop.call_later(0.05, stop.set)
    t0 = loop.time()
    await r.wait(stop, 10.0)
    assert loop.time() - t0 < 1.0
    stop.clear()
    loop.call_later(0.05, port.touch)  # the adapter is plugged back in
    t0 = loop.time()
    await r.wait(stop, 10.0)
    assert loop.time() - t0 < 1.0
    r.close()
    assert r.phase is Phase.CLOSED
    r.attempt()
    assert r.phase is Phase.CLOSED


# ---- the loop itself: Reconnect.run, on virtual time ---------------------------------

Outcome = BaseException | float | None  # raise it, serve that long then lose the link, or succeed
DEVICE_TROUBLE = expecting(ConnectionError)


class Device:
    """A scripted device for `Reconnect.run`: what each connect and serve does, and a log.

    A serve without a scripted outcome lasts until `stop` is set and then raises as
    a port closed under it would. Times are loop (virtual) seconds.
    """

    def __init__(
        self, stop: asyncio.Event, connects: Sequence[Outcome] = (), serves: Sequence[Outcome] = ()
    ) -> None:
        self.stop = stop
        self.connects = list(connects)
        self.serves = list(serves)
        self.attempts_t: list[float] = []
        self.failures: list[tuple[str, Failure, str]] = []
        self.losses = 0
        self.serving = False
        self.serve_cancelled = False
        #: Set once a connection is served.
        self.up = asyncio.Event()
        #: What serve raises when the stop closes its port.
        self.closed_error: Exception = ConnectionError("port closed under the session")

    async def connect(self) -> None:
        self.attempts_t.append(asyncio.get_running_loop().time())
        outcome = self.connects.pop(0) if self.connects else None
        if isinstance(outcome, BaseException):
            raise outcome

    async def serve(self) -> None:
        outcome = self.serves.pop(0) if self.serves else None
        self.serving = True
        self.up.set()
        try:
            if isinstance(outcome, BaseException):
                raise outcome
            if isinstance(outcome, float):
                await asyncio.sleep(outcome)
                return
            await self.stop.wait()
            raise self.closed_error
        except asyncio.CancelledError:
            self.serve_cancelled = True
            raise
        finally:
            self.serving = False

    def on_failure(self, exc: Exception, failure: Failure, text: str) -> None:
        self.failures.append((type(exc).__name__, failure, text))

    async def after_loss(self) -> None:
        self.losses += 1

    async def run(self, r: Reconnect, describe: Describe = DEVICE_TROUBLE) -> None:
        await r.run(
            self.connect,
            self.serve,
            stop=self.stop,
            describe=describe,
            on_failure=self.on_failure,
            after_loss=self.after_loss,
        )

    def gaps(self) -> list[float]:
        return [round(b - a, 9) for a, b in itertools.pairwise(self.attempts_t)]


def loop_reconnect(**kw: Any) -> Reconnect:
    return make(LoopClock(), **kw)


VT = pytest.mark.virtual_time


@VT
async def test_run_backs_off_on_the_capped_schedule_and_starts_over_after_a_connection() -> None:
    stop = asyncio.Event()
    down = ConnectionError("no such port")
    dev = Device(stop, connects=[down] * 5, serves=[ConnectionError("hung up")])
    r = loop_reconnect()
    with capture_logs() as logs:
        task = asyncio.create_task(dev.run(r))
        await until(lambda: len(dev.attempts_t) == 7 and dev.serving, "the 7th connection")
        assert r.phase is Phase.UP and r.failures == 0 and r.reconnects == 1
        stop.set()
        await task
    # 1, 2, 4 then the 5 s cap; connected at the 6th try and lost at once: the backoff
    # had been reset, so the 7th try comes 1 s later.
    assert dev.gaps() == [1.0, 2.0, 4.0, 5.0, 5.0, 1.0]
    assert [(n, t) for n, _, t in dev.failures] == [("ConnectionError", "no such port")] * 5 + [
        ("ConnectionError", "hung up")
    ]
    assert dev.losses == 6  # after each counted failure; not after the stop
    assert r.last_error == "hung up"
    assert levels(logs, "dev_failed") == ["warning", "debug", "debug", "debug", "debug", "warning"]
    assert levels(logs, "dev_recovered") == ["info", "info"]


@VT
async def test_a_serve_that_returns_is_a_loss_not_a_failure() -> None:
    stop = asyncio.Event()
    dev = Device(stop, serves=[30.0])
    r = loop_reconnect()
    task = asyncio.create_task(dev.run(r))
    await until(
        lambda: len(dev.attempts_t) == 2 and dev.serving, "the second connection", timeout_s=100.0
    )
    stop.set()
    await task
    assert dev.gaps() == [31.0]  # served 30 s, then the first backoff step
    assert dev.failures == [] and r.failures == 0 and dev.losses == 1


@VT
async def test_describe_says_how_a_failure_is_logged_and_kept() -> None:
    stop = asyncio.Event()
    refused = Failure(
        kind="auth", event="dev_refused", text="login refused", fields={"hint": "password"}
    )

    def describe(exc: Exception) -> Failure:
        return refused if isinstance(exc, PermissionError) else expecting(ConnectionError)(exc)

    dev = Device(stop, connects=[PermissionError("403"), KeyError("bug"), ConnectionError("gone")])
    r = loop_reconnect()
    with capture_logs() as logs:
        task = asyncio.create_task(dev.run(r, describe))
        await until(lambda: dev.serving, "a connection")
        stop.set()
        await task
    assert [(n, f, t) for n, f, t in dev.failures] == [
        ("PermissionError", refused, "login refused"),
        ("KeyError", UNEXPECTED, "unexpected: KeyError('bug')"),
        ("ConnectionError", Failure(), "gone"),
    ]
    refusal = next(e for e in logs if e["event"] == "dev_refused")
    assert refusal["hint"] == "password" and refusal["log_level"] == "warning"
    # The bug does not end the loop, but is an ERROR with its traceback; the streak's
    # third failure is no news (DEBUG).
    assert [(e["log_level"], e.get("exc_info")) for e in logs if e["event"] == "dev_failed"] == [
        ("error", True),
        ("debug", None),
    ]
    assert dev.gaps() == [1.0, 2.0, 4.0]


@VT
async def test_stop_mid_wait_returns_at_once() -> None:
    stop = asyncio.Event()
    dev = Device(stop, connects=[ConnectionError("down")])
    r = make(LoopClock())
    r.backoff.initial_s = 60.0
    loop = asyncio.get_running_loop()
    task = asyncio.create_task(dev.run(r))
    await until(lambda: r.phase is Phase.BACKING_OFF, "the first failure")
    t0 = loop.time()
    loop.call_later(2.0, stop.set)
    await task
    assert loop.time() - t0 == pytest.approx(2.0)  # not the 60 s backoff
    assert len(dev.attempts_t) == 1 and dev.losses == 1


@VT
async def test_a_failure_the_stop_caused_is_not_counted_but_a_bug_still_is() -> None:
    stop = asyncio.Event()
    dev = Device(stop)
    r = loop_reconnect()
    with capture_logs() as logs:
        task = asyncio.create_task(dev.run(r))
        await until(lambda: dev.serving, "a connection")
        stop.set()  # serve's port is closed under it: ConnectionError
        await task
    assert dev.failures == [] and r.failures == 0 and dev.losses == 0
    assert levels(logs, "dev_failed") == []

    # A bug on the way out is still a bug: counted and logged, and the loop still ends.
    stop.clear()
    dev = Device(stop)
    dev.closed_error = RuntimeError("bug on the way out")
    with capture_logs() as logs:
        task = asyncio.create_task(dev.run(r))
        await until(lambda: dev.serving, "a connection")
        stop.set()
        await task
    assert [n for n, _, _ in dev.failures] == ["RuntimeError"] and dev.losses == 0
    assert levels(logs, "dev_failed") == ["error"]


@VT
async def test_cancel_mid_wait_leaves_nothing_behind() -> None:
    stop = asyncio.Event()
    dev = Device(stop, connects=[ConnectionError("down")])
    r = loop_reconnect()
    task = asyncio.create_task(dev.run(r))
    await until(lambda: r.phase is Phase.BACKING_OFF, "the first failure")
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert others() == []
    await asyncio.sleep(100.0)  # virtual: nothing retries behind our back
    assert len(dev.attempts_t) == 1 and r.failures == 1


@VT
async def test_cancel_mid_serve_goes_through_uncounted() -> None:
    stop = asyncio.Event()
    dev = Device(stop, serves=[1e6])
    r = loop_reconnect()
    task = asyncio.create_task(dev.run(r))
    await until(lambda: dev.serving, "a connection")
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert dev.serve_cancelled and not dev.serving
    assert others() == []
    # A cancel is no failure and no loss: the driver's safe stop may still need the port.
    assert dev.failures == [] and r.failures == 0 and dev.losses == 0 and r.phase is Phase.UP


def others() -> list[asyncio.Task[Any]]:
    current = asyncio.current_task()
    return [t for t in asyncio.all_tasks() if t is not current and not t.done()]


@VT
async def test_run_retries_a_replugged_port_at_once(tmp_path: Path) -> None:
    port = tmp_path / "ttyUSB0"
    stop = asyncio.Event()
    dev = Device(stop, connects=[ConnectionError("unplugged")])
    r = loop_reconnect(url=str(port))
    r.backoff.initial_s = 30.0
    asyncio.get_running_loop().call_later(2.0, port.touch)
    task = asyncio.create_task(dev.run(r))
    await until(lambda: dev.serving, "the connection after the replug")
    stop.set()
    await task
    assert 2.0 <= dev.gaps()[0] <= 2.0 + REPLUG_POLL_S + 1e-9


# ---- backoff bounds, for any schedule ------------------------------------------------

schedules = st.tuples(
    st.floats(0.001, 10.0), st.floats(0.001, 600.0), st.floats(1.0, 4.0), st.floats(0.0, 0.5)
)


@settings(max_examples=300, deadline=None)
@given(schedules, st.integers(1, 40), st.randoms(use_true_random=False))
def test_backoff_delays_grow_to_the_cap_within_the_jitter(
    schedule: tuple[float, float, float, float], n: int, rng: random.Random
) -> None:
    initial_s, maximum_s, factor, jitter = schedule
    b = Backoff(initial_s=initial_s, maximum_s=maximum_s, factor=factor, jitter=jitter, _rng=rng)
    nominal_prev = 0.0
    for k in range(n):
        delay = b.next_delay()
        nominal = min(maximum_s, initial_s * factor**k)
        assert nominal >= nominal_prev - 1e-12  # never shrinks within a streak
        assert nominal * (1 - jitter) - 1e-9 <= delay <= nominal * (1 + jitter) + 1e-9
        assert 0.0 < delay <= maximum_s * (1 + jitter) + 1e-9
        nominal_prev = nominal
    b.reset()
    assert (
        min(maximum_s, initial_s) * (1 - jitter) - 1e-9
        <= b.next_delay()
        <= min(maximum_s, initial_s) * (1 + jitter) + 1e-9
    )


@settings(max_examples=60, deadline=None)
@given(st.floats(0.01, 5.0), st.floats(0.01, 20.0), st.integers(0, 12))
def test_run_waits_exactly_the_backoff_schedule(initial_s: float, maximum_s: float, n: int) -> None:
    """Whatever the schedule, the loop's tries are the backoff's delays apart, and no closer."""

    async def scenario() -> list[float]:
        stop = asyncio.Event()
        dev = Device(stop, connects=[ConnectionError("down")] * n)
        r = Reconnect(
            structlog.get_logger("test"),
            "dev_failed",
            clock=LoopClock(),
            backoff=Backoff(initial_s=initial_s, maximum_s=maximum_s, jitter=0),
        )
        with capture_logs():
            task = asyncio.create_task(dev.run(r))
            async with asyncio.timeout(n * maximum_s + 1.0):
                await dev.up.wait()
            stop.set()
            await task
        return dev.gaps()

    gaps = vtime.run(scenario())
    assert gaps == pytest.approx([min(maximum_s, initial_s * 2.0**k) for k in range(n)], abs=1e-6)
