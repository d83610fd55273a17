"""The shared reconnect policy: backoff, streaks, log discipline, replug wake-up."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import pytest
import structlog
from structlog.testing import capture_logs
from support import ManualClock

from drivers.backoff import Backoff
from drivers.clock import Clock
from drivers.reconnect import Phase, Reconnect


@pytest.fixture(autouse=True)
def _default_logging() -> Iterator[None]:
    """structlog's default configuration for these tests: another test (a CLI run) may
    have left a WARNING filter in place, and these tests count DEBUG lines too."""
    previous = structlog.get_config()
    structlog.reset_defaults()
    yield
    structlog.configure(**previous)


def make(clock: Clock | None = None, **kw: object) -> Reconnect:
    return Reconnect(structlog.get_logger("test"), "dev_failed",
                     backoff=Backoff(initial_s=1.0, maximum_s=5.0, jitter=0),
                     clock=clock or ManualClock(0.0), **kw)  # type: ignore[arg-type]


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
