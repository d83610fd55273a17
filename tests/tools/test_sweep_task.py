"""What a sweep worker runs (relayd/sweep/task.py): a run forked by the worker's fork
server (relayd/sweep/forkserver.py) gives what a fresh `python -m relayd.sweep.child`
gives, and a failing, hung or lost run comes back as RunFailed with its reason."""

from __future__ import annotations

import os
import signal
import sys
from typing import Any

import pytest

from relayd.sweep import task
from relayd.sweep.grid import build_grid
from relayd.sweep.task import RunFailed, run_task

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="the fork server is Linux's")


def _payload(seconds: float) -> dict[str, Any]:
    spec = build_grid(["convoy"], [1], [2], [], seconds=seconds)[0]
    return spec.payload()


def test_a_forked_run_is_the_fresh_process_run(monkeypatch: pytest.MonkeyPatch) -> None:
    payload = _payload(3.0)
    forked = run_task(payload, 120.0)
    monkeypatch.setenv("RELAYD_SWEEP_FORK", "0")
    fresh = run_task(payload, 120.0)
    for key in ("summary", "series"):
        assert forked[key] == fresh[key]
    assert forked["summary"]["sim_seconds"] >= 3.0


def test_a_failing_run_says_why() -> None:
    payload = _payload(3.0)
    payload["scenario_doc"] = {"name": "broken", "leader": "not a table"}
    with pytest.raises(RunFailed, match=r"exit status 1: (?s:.*)leader"):
        run_task(payload, 120.0)


def test_a_run_past_its_time_is_killed_and_the_server_goes_on() -> None:
    with pytest.raises(RunFailed, match="timed out after 1 s"):
        run_task(_payload(100_000.0), 1.0)
    assert run_task(_payload(3.0), 120.0)["summary"]["sim_seconds"] >= 3.0


def test_a_dead_server_is_started_again() -> None:
    run_task(_payload(3.0), 120.0)
    server = task._servers.server
    os.kill(server.proc.pid, signal.SIGKILL)
    server.proc.wait()
    assert run_task(_payload(3.0), 120.0)["summary"]["sim_seconds"] >= 3.0
    assert task._servers.server is not server
