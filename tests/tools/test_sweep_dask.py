"""A generated-world sweep on a real Dask deployment: a `dask scheduler` and two
`dask worker` processes on loopback give the same runs.csv as the embedded LocalCluster.

Fifty worlds (25 offices, 25 corridor networks), two relays, one seed. Each run simulates
only RUN_S seconds, enough for both relays to have scanned with their drawn antennas and
decided. What a run costs is its process start (a child alone: 1.31 s wall at 1 simulated
second, 1.37 s at 5, 1.53 s at 10), so a shorter run would not make the test shorter: it
took 167 s on a loaded 2-core machine (64 s the scheduler's sweep, 92 s the LocalCluster's;
bench/RESULTS.md). Every process the test starts is bounded in time and killed in a finally.
"""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest

from relayd.cli import main
from tests.support import dask_scheduler, kill_group

pytest.importorskip("distributed")

#: Simulated seconds per run: both relays have finished their first scan by 4 s and
#: decided (the leader near, none moved yet); at 3 s they have not.
RUN_S = "5"
GRID = [
    "--generated",
    "office:25",
    "--generated",
    "corridors:25",
    "--relays",
    "2",
    "--seeds",
    "1",
    "--seconds",
    RUN_S,
    "--no-plots",
]


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(encoding="utf-8") as f:
        rows = [{k: v for k, v in r.items() if k != "wall_s"} for r in csv.DictReader(f)]
    return sorted(rows, key=lambda r: (r["scenario"], r["relays"], r["seed"]))


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_fifty_generated_worlds_on_a_scheduler_equal_the_local_cluster(tmp_path: Path) -> None:
    dask_cli = str(Path(sys.executable).parent / "dask")
    procs: list[subprocess.Popen[bytes]] = []
    log = (tmp_path / "dask.log").open("wb")
    common = ["--host", "127.0.0.1", "--no-dashboard"]
    try:
        sched, port = dask_scheduler(dask_cli, tmp_path / "scheduler.log")
        procs.append(sched)
        addr = f"tcp://127.0.0.1:{port}"
        for _ in range(2):
            procs.append(
                subprocess.Popen(
                    [dask_cli, "worker", addr, "--nthreads", "1", "--memory-limit", "0", *common],
                    stdout=log,
                    stderr=log,
                    start_new_session=True,
                )
            )
        from distributed import Client

        with Client(addr, timeout="60s") as c:
            c.wait_for_workers(2, timeout=90)
        ext, local = tmp_path / "ext", tmp_path / "local"
        assert main(["sweep", *GRID, "--scheduler", addr, "--out", str(ext)]) == 0
        with Client(addr, timeout="60s") as c:
            # Both workers ran runs: the sweep was spread over the deployment.
            executed = c.run(lambda dask_worker: dask_worker.state.executed_count)
        assert len(executed) == 2 and all(n > 0 for n in executed.values()), executed
        assert sum(executed.values()) >= 50, executed
    finally:
        for p in reversed(procs):
            kill_group(p)
        log.close()
    assert main(["sweep", *GRID, "--workers", "2", "--out", str(local)]) == 0

    rows = _rows(ext / "runs.csv")
    assert rows == _rows(local / "runs.csv")
    assert len(rows) == 50 and all(r["status"] == "ok" for r in rows)
    names = {r["scenario"] for r in rows}
    assert len(names) == 50
    assert {n.rsplit("-", 1)[0] for n in names} == {"generated-office", "generated-corridors"}
    for r in rows:
        # The runs got as far as the relays' first decisions (the scan was heard).
        assert float(r["sim_seconds"]) >= float(RUN_S)
        assert r["relay1_reason"] not in ("", "no_scan_yet"), r
        assert r["relay2_reason"] not in ("", "no_scan_yet"), r
