"""`relayd sweep`: the grid, the progress bar, and real sweeps on Dask (an embedded
LocalCluster, and a `dask scheduler` with two `dask worker` processes on loopback).

The sweeps are tiny (a few simulated seconds of the convoy) so they stay in CI's budget;
every process a test starts is bounded in time and killed in a finally.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from relayd.cli import main
from relayd.sweep.child import series_1hz, start_mean_mbps
from relayd.sweep.driver import SweepProgress, columns
from relayd.sweep.grid import GridError, apply_override, build_grid, parse_set, parse_value
from tests.support import dask_scheduler, kill_group, until_sync

pytest.importorskip("distributed")

TINY = ["--scenario", "convoy", "--seconds", "3", "--no-plots"]


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(encoding="utf-8") as f:
        return list(csv.DictReader(f))


def _without_wall(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


# --- the grid --------------------------------------------------------------------------


def test_parse_set_values_and_shorthand() -> None:
    assert parse_value("3") == 3 and parse_value("-2.5") == -2.5 and parse_value("true") is True
    assert parse_value("step") == "step"
    a = parse_set("radio.exponent=2.5,3")
    assert a.path == ("radio", "exponent") and a.values == (2.5, 3)
    # a bare daemon key is short for its section
    assert parse_set("threshold_b_dbm=-40,-50").path == ("control", "threshold_b_dbm")
    assert parse_set("samples=13").path == ("scan", "samples")
    with pytest.raises(GridError, match="not a scenario key"):
        parse_set("cheese=1")
    with pytest.raises(GridError, match="KEY=V1"):
        parse_set("radio.exponent")


def test_apply_override_walks_tables_and_lists() -> None:
    doc = {"relay": [{"name": "a", "control": {}}], "radio": {"exponent": 3.0}}
    apply_override(doc, ("relay", "0", "control", "threshold_b_dbm"), -40)
    apply_override(doc, ("radio", "exponent"), 2.0)
    apply_override(doc, ("control", "kp"), 0.5)
    assert doc == {
        "relay": [{"name": "a", "control": {"threshold_b_dbm": -40}}],
        "radio": {"exponent": 2.0},
        "control": {"kp": 0.5},
    }
    with pytest.raises(GridError, match="out of range"):
        apply_override(doc, ("relay", "3", "x"), 1)


def test_build_grid_expands_in_order_and_validates_up_front() -> None:
    specs = build_grid(
        ["convoy"], [0, 2], [1, 2], [parse_set("radio.shadow_sigma_db=2,4")], seconds=3
    )
    assert len(specs) == 8
    assert [(s.params[0][1], s.relays, s.seed) for s in specs[:4]] == [
        (2, 0, 1),
        (2, 0, 2),
        (2, 2, 1),
        (2, 2, 2),
    ]
    assert specs[0].run_id == "convoy/relays-0/radio.shadow_sigma_db=2/seed-1"
    assert specs[0].doc["radio"]["shadow_sigma_db"] == 2
    # the digest follows the parameters, not the object
    again = build_grid(
        ["convoy"], [0, 2], [1, 2], [parse_set("radio.shadow_sigma_db=2,4")], seconds=3
    )
    assert [s.digest for s in specs] == [s.digest for s in again]
    assert len({s.digest for s in specs}) == 8
    with pytest.raises(GridError, match=r"radio\.shadow_sigma_db"):
        build_grid(["convoy"], [0], [1], [parse_set("radio.shadow_sigma_db=-1")])
    with pytest.raises(GridError, match="relays"):
        build_grid(["convoy"], [7], [1], [])
    with pytest.raises(GridError, match="no scenario named"):
        build_grid(["nowhere"], [0], [1], [])


def test_series_and_start_mean() -> None:
    recs = [{"t": round(0.1 * k, 2), "e2e_mbps": 27.0 if k < 150 else 12.0} for k in range(300)]
    assert start_mean_mbps(recs) == pytest.approx((150 * 27 + 50 * 12) / 200, abs=1e-3)
    s = series_1hz(recs)
    assert s["t"] == [float(k) for k in range(30)]
    assert s["e2e_mbps"][14] == 27.0 and s["e2e_mbps"][15] == 12.0


def test_progress_bar_counts_and_eta() -> None:
    now = [100.0]
    buf = io.StringIO()
    p = SweepProgress(10, 2, stream=buf, enabled=False, now=lambda: now[0])
    assert "2/10 runs" in p.text() and "ETA ?" in p.text()
    now[0] += 40.0
    p.update(ok=3)
    p.update(failed=1)  # 4 runs in 40 s: 4 left take 40 s more
    line = buf.getvalue().splitlines()[-1]
    assert "6/10 runs" in line and "1 failed" in line and "ETA 40s" in line and "2 resumed" in line


# --- real sweeps -----------------------------------------------------------------------


@pytest.mark.timeout(240)
def test_two_workers_equal_one_worker_and_resume(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # 4 runs: two relay counts x two values of one axis; a second, one-valued axis still
    # checks the column order of several --set keys.
    grid = [
        *TINY,
        "--relays",
        "0,1",
        "--seed-list",
        "2",
        "--set",
        "radio.shadow_sigma_db=2,8",
        "--set",
        "leader.speed_m_s=0.2",
    ]
    two, one = tmp_path / "two", tmp_path / "one"
    assert main(["sweep", *grid, "--workers", "2", "--out", str(two)]) == 0
    rows = _rows(two / "runs.csv")
    fixed = columns(["radio.shadow_sigma_db", "leader.speed_m_s"])
    assert list(rows[0])[: len(fixed)] == fixed
    # The split outcome, then per-relay outcome columns, filled for the 1-relay runs only.
    split = ["leader_arrived", "link_held", "relays_ok"]
    per_relay = [
        "relay1_reason",
        "relay1_on_rule",
        "relay1_final_gap_m",
        "relay1_stuck_s",
        "relay1_collisions",
        "relay1_travelled_m",
    ]
    assert list(rows[0])[len(fixed) :] == split + per_relay
    for r in rows:
        assert (r["relay1_reason"] != "") == (r["relays"] == "1")
        assert {r[k] for k in split} <= {"True", "False"}, r
    assert len(rows) == 4 and all(r["status"] == "ok" and r["attempts"] == "1" for r in rows)
    for r in rows:
        summary = json.loads((two / r["run_dir"] / "summary.json").read_text())
        assert summary["relays"] == int(r["relays"]) and summary["sim_seconds"] >= 3.0
        assert float(r["start_e2e_mbps"]) > 0
    assert (two / "report.md").read_text().count("## convoy") == 2

    # same grid on one worker: identical apart from the wall time
    assert main(["sweep", *grid, "--workers", "1", "--out", str(one)]) == 0
    assert _without_wall(_rows(one / "runs.csv")) == _without_wall(rows)

    # resume: nothing re-runs; a deleted run folder runs again, alone
    capsys.readouterr()
    stamp = (two / rows[0]["run_dir"] / "run.json").stat().st_mtime_ns
    assert main(["sweep", *grid, "--workers", "2", "--out", str(two)]) == 0
    assert "0 run, 4 already done" in capsys.readouterr().out
    assert (two / rows[0]["run_dir"] / "run.json").stat().st_mtime_ns == stamp
    victim = two / rows[3]["run_dir"]
    for f in victim.iterdir():
        f.unlink()
    assert main(["sweep", *grid, "--workers", "1", "--out", str(two)]) == 0
    assert "1 run, 3 already done" in capsys.readouterr().out
    assert _without_wall(_rows(two / "runs.csv")) == _without_wall(rows)


@pytest.mark.timeout(120)
def test_a_failing_run_is_retried_once_then_recorded(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "fail"
    # No run can finish in 0.3 s of wall time (the child alone takes longer to start).
    t0 = time.monotonic()
    code = main(
        [
            "sweep",
            *TINY,
            "--relays",
            "1",
            "--seeds",
            "1",
            "--workers",
            "1",
            "--run-timeout",
            "0.3",
            "--out",
            str(out),
        ]
    )
    assert code == 1
    assert time.monotonic() - t0 < 100
    (row,) = _rows(out / "runs.csv")
    assert row["status"] == "failed" and row["attempts"] == "2"
    assert "timed out after 0.3 s" in row["error"]
    assert row["min_e2e_mbps"] == "" and row["wall_s"] == ""
    meta = json.loads((out / row["run_dir"] / "run.json").read_text())
    assert meta["status"] == "failed"
    assert (
        "failed: `runs/convoy/relays-1/seed-1` after 2 attempt(s)"
        in (out / "report.md").read_text()
    )
    # a failed run is not 'finished': the next invocation tries it again
    capsys.readouterr()
    assert (
        main(["sweep", *TINY, "--relays", "1", "--seeds", "1", "--workers", "1", "--out", str(out)])
        == 0
    )
    assert "1 run, 0 already done, 0 failed" in capsys.readouterr().out
    assert _rows(out / "runs.csv")[0]["status"] == "ok"


@pytest.mark.timeout(120)
def test_an_unreachable_scheduler_is_an_error_not_a_hang(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    port = _free_port()
    t0 = time.monotonic()
    # --connect-timeout bounds the wait (default 30 s); a short one keeps the test short.
    code = main(
        [
            "sweep",
            *TINY,
            "--relays",
            "0",
            "--seeds",
            "1",
            "--scheduler",
            f"tcp://127.0.0.1:{port}",
            "--connect-timeout",
            "2",
            "--out",
            str(tmp_path / "x"),
        ]
    )
    waited_s = time.monotonic() - t0
    assert code == 2 and 2.0 <= waited_s < 60, waited_s
    assert "no Dask cluster" in capsys.readouterr().err


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.timeout(120)
def test_a_cluster_without_workers_does_not_hang_the_sweep(tmp_path: Path) -> None:
    dask_cli = str(Path(sys.executable).parent / "dask")
    sched, port = dask_scheduler(dask_cli, tmp_path / "dask.log")
    try:
        from distributed import Client

        with Client(f"tcp://127.0.0.1:{port}", timeout="60s"):
            pass  # the scheduler is up
        t0 = time.monotonic()
        code = main(
            [
                "sweep",
                *TINY,
                "--relays",
                "0",
                "--seeds",
                "2",
                "--scheduler",
                f"tcp://127.0.0.1:{port}",
                "--no-worker-timeout",
                "3",
                "--out",
                str(tmp_path / "x"),
            ]
        )
        assert code == 1 and time.monotonic() - t0 < 60
        rows = _rows(tmp_path / "x" / "runs.csv")
        assert [r["status"] for r in rows] == ["failed", "failed"]
        assert all("no Dask worker for 3 s" in r["error"] for r in rows)
    finally:
        kill_group(sched)


@pytest.mark.timeout(300)
def test_external_scheduler_two_workers_one_killed(tmp_path: Path) -> None:
    """A real `dask scheduler` and two `dask worker`s on loopback; one worker is killed
    (its whole process group, nanny included) while the sweep runs: every run still
    finishes, on the survivor, and the sweep exits."""
    dask_cli = str(Path(sys.executable).parent / "dask")
    procs: list[subprocess.Popen[bytes]] = []
    log = (tmp_path / "dask.log").open("wb")
    try:
        sched, port = dask_scheduler(dask_cli, tmp_path / "scheduler.log")
        procs.append(sched)
        addr = f"tcp://127.0.0.1:{port}"
        for _ in range(2):
            procs.append(
                subprocess.Popen(
                    [
                        dask_cli,
                        "worker",
                        addr,
                        "--nthreads",
                        "1",
                        "--host",
                        "127.0.0.1",
                        "--no-dashboard",
                        "--memory-limit",
                        "0",
                    ],
                    stdout=log,
                    stderr=log,
                    start_new_session=True,
                )
            )
        from distributed import Client

        with Client(addr, timeout="60s") as c:
            c.wait_for_workers(2, timeout=90)
        out = tmp_path / "ext"
        sweep = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "relayd",
                "sweep",
                *TINY,
                "--relays",
                "0,1",
                "--seeds",
                "2",
                "--scheduler",
                addr,
                "--out",
                str(out),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        procs.append(sweep)

        def a_run_done() -> bool:
            assert sweep.poll() is None, sweep.stdout.read() if sweep.stdout else ""
            return bool(list(out.glob("runs/**/run.json")))

        until_sync(a_run_done, "the first finished run", 120.0, poll_s=0.2)
        kill_group(procs[2])
        text, _ = sweep.communicate(timeout=200)
        assert sweep.returncode == 0, text.decode()
        rows = _rows(out / "runs.csv")
        assert len(rows) == 4 and all(r["status"] == "ok" for r in rows), rows
    finally:
        for p in reversed(procs):
            kill_group(p)
        log.close()


def test_a_server_that_is_not_a_dask_scheduler_is_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A web server's answer, read as a Dask frame, once asked numpy for 3 EiB (a traceback)."""
    import threading

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen()
    port = server.getsockname()[1]

    def answer() -> None:
        with contextlib.suppress(OSError):
            while True:
                conn, _ = server.accept()
                with conn:
                    conn.recv(65536)
                    conn.sendall(
                        b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n" + b"x" * 200
                    )

    threading.Thread(target=answer, daemon=True).start()
    try:
        code = main(
            [
                "sweep",
                *TINY,
                "--relays",
                "0",
                "--seeds",
                "1",
                "--scheduler",
                f"tcp://127.0.0.1:{port}",
                "--connect-timeout",
                "5",
                "--out",
                str(tmp_path / "x"),
            ]
        )
    finally:
        server.close()
    err = capsys.readouterr().err
    assert code == 2, err
    assert "no Dask cluster" in err and "did not answer as a Dask scheduler" in err, err
