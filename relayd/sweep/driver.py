"""Running a sweep grid on Dask: submit, retry once, resume, show progress, write results.

Layout of the output directory DIR:

    DIR/runs.csv                      one row per run of the grid, in grid order
    DIR/report.md, DIR/plots/*.png    means and bands per grid cell (relayd.sweep.report)
    DIR/runs/<run_id>/run.json        status, attempts, error, wall time, the runs.csv row
    DIR/runs/<run_id>/summary.json    the simulator's summary (as `relayd sim` writes it)
    DIR/runs/<run_id>/series.json     end-to-end throughput once per simulated second

Resuming: a run whose run.json says "ok" with the same parameter digest is not run
again. Failed runs are run again on the next invocation (a failure may be the
machine's, not the run's).

Failures: a run that raises, exits non-zero, outlives `--run-timeout`, or whose worker
dies, is submitted once more (a new Dask key); a second failure is recorded as
status "failed" with its error and the sweep goes on. If no worker is connected for
`no_worker_timeout_s`, the runs still waiting are recorded as failed and the sweep ends:
it never waits forever.

Results do not depend on the number of workers: each run is a pure function of its
spec (the simulator runs on virtual time), and runs.csv is written in grid order,
not completion order.
"""

from __future__ import annotations

import csv
import json
import logging
import os
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from relayd.sweep.grid import RunSpec

#: runs.csv columns before the --set keys, and after them.
HEAD_COLUMNS = ("scenario", "relays", "seed")
TAIL_COLUMNS = (
    "goal_reached",
    "link_broken_at_s",
    "min_e2e_mbps",
    "final_e2e_mbps",
    "start_e2e_mbps",
    "collisions",
    "sim_seconds",
    "wall_s",
    "status",
    "attempts",
    "error",
    "run_dir",
)


def default_workers() -> int:
    """The machine's usable cores (this process's CPU affinity where the OS tells it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@dataclass(slots=True)
class SweepOptions:
    out: Path
    workers: int | None = None
    scheduler: str | None = None
    run_timeout_s: float = 3600.0
    retries: int = 1
    trace: bool = False
    no_worker_timeout_s: float = 120.0
    #: How long to try reaching an external scheduler before the sweep gives up.
    connect_timeout_s: float = 30.0


@dataclass(slots=True)
class SweepOutcome:
    total: int
    skipped: int
    ok: int
    failed: int
    rows: list[dict[str, Any]]


def columns(set_keys: list[str]) -> list[str]:
    return [*HEAD_COLUMNS, *set_keys, *TAIL_COLUMNS]


def row_for(
    spec: RunSpec,
    *,
    status: str,
    attempts: int,
    error: str = "",
    wall_s: float | None = None,
    summary: dict[str, Any] | None = None,
    start_e2e_mbps: float | None = None,
) -> dict[str, Any]:
    row: dict[str, Any] = {"scenario": spec.scenario, "relays": spec.relays, "seed": spec.seed}
    row.update(dict(spec.params))
    s = summary or {}
    row.update(
        {
            "goal_reached": s.get("goal_reached", ""),
            "link_broken_at_s": "" if s.get("link_broken_at_s") is None else s["link_broken_at_s"],
            "min_e2e_mbps": s.get("min_e2e_mbps", ""),
            "final_e2e_mbps": s.get("final_e2e_mbps", ""),
            "start_e2e_mbps": "" if start_e2e_mbps is None else start_e2e_mbps,
            "collisions": s.get("collisions", ""),
            "sim_seconds": s.get("sim_seconds", ""),
            "wall_s": "" if wall_s is None else wall_s,
            "status": status,
            "attempts": attempts,
            "error": error,
            "run_dir": f"runs/{spec.run_id}",
        }
    )
    row.update(relay_columns(s))
    return row


#: Per-relay outcome columns, from summary.json's followers (named <relay>_<field>).
RELAY_FIELDS = (
    ("reason", "stopped_reason"),
    ("on_rule", "on_link_rule"),
    ("final_gap_m", "final_gap_m"),
    ("stuck_s", "stuck_s"),
    ("collisions", "collisions"),
    ("travelled_m", "travelled_m"),
)
#: The split outcome (leader_arrived, link_held, relays_ok) where the summary has it.
SPLIT_FIELDS = ("leader_arrived", "link_held", "relays_ok")


def relay_columns(summary: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {k: summary[k] for k in SPLIT_FIELDS if k in summary}
    for f in summary.get("followers", []):
        for col, key in RELAY_FIELDS:
            out[f"{f['name']}_{col}"] = f.get(key, "")
    return out


def load_finished(out: Path, spec: RunSpec) -> dict[str, Any] | None:
    """The recorded row of a finished run with the same parameters, or None."""
    path = out / "runs" / spec.run_id / "run.json"
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if meta.get("status") != "ok" or meta.get("digest") != spec.digest:
        return None
    if not (path.parent / "summary.json").exists():
        return None
    row: dict[str, Any] = meta["row"]
    return row


def write_run(out: Path, spec: RunSpec, row: dict[str, Any], result: dict[str, Any] | None) -> None:
    """A run's folder: files first, run.json last, so a half-written folder is not 'finished'."""
    folder = out / "runs" / spec.run_id
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    if result is not None:
        (folder / "summary.json").write_text(
            json.dumps(result["summary"], indent=2) + "\n", encoding="utf-8"
        )
        (folder / "series.json").write_text(
            json.dumps(result["series"], separators=(",", ":")) + "\n", encoding="utf-8"
        )
        (folder / "sim.log").write_text(result.get("sim_log", ""), encoding="utf-8")
        if "trace" in result:
            (folder / "trace.jsonl").write_text(result["trace"], encoding="utf-8")
    meta = {
        "run_id": spec.run_id,
        "digest": spec.digest,
        "status": row["status"],
        "attempts": row["attempts"],
        "error": row["error"],
        "wall_s": row["wall_s"],
        "row": row,
    }
    tmp = folder / "run.json.tmp"
    tmp.write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    tmp.replace(folder / "run.json")


def write_csv(path: Path, rows: list[dict[str, Any]], set_keys: list[str]) -> None:
    tmp = path.with_suffix(".csv.tmp")
    with tmp.open("w", encoding="utf-8", newline="") as f:
        fixed = columns(set_keys)
        # The per-relay columns after the fixed ones, in the order the rows first name them.
        extra = list(dict.fromkeys(k for r in rows for k in r if k not in fixed))
        w = csv.DictWriter(f, fieldnames=[*fixed, *extra], extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow(r)
    tmp.replace(path)


def _fmt_s(s: float) -> str:
    s = max(0, round(s))
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{h}h{m:02d}m{sec:02d}s" if h else f"{m}m{sec:02d}s" if m else f"{sec}s"


class SweepProgress:
    """A progress bar: runs done of the total, failures, elapsed and estimated time left.

    On a terminal one line is rewritten in place; otherwise (CI logs, pipes) one line
    per finished run, so a log still shows how far a sweep got.
    """

    def __init__(
        self,
        total: int,
        skipped: int,
        stream: TextIO | None = None,
        width: int = 24,
        enabled: bool | None = None,
        now: Callable[[], float] = time.monotonic,
    ) -> None:
        self.stream = sys.stderr if stream is None else stream
        self.total = total
        self.skipped = skipped
        self.width = width
        self._now = now
        self.t0 = now()
        self.ok = 0
        self.failed = 0
        self.tty = self.stream.isatty() if enabled is None else enabled

    def text(self) -> str:
        done = self.skipped + self.ok + self.failed
        frac = done / self.total if self.total else 1.0
        fill = round(frac * self.width)
        elapsed = self._now() - self.t0
        ran = self.ok + self.failed
        left = self.total - done
        eta = "?" if ran == 0 and left else _fmt_s(elapsed / ran * left) if left else "0s"
        parts = [f"[{'#' * fill}{'.' * (self.width - fill)}] {done}/{self.total} runs"]
        if self.skipped:
            parts.append(f"{self.skipped} resumed")
        if self.failed:
            parts.append(f"{self.failed} failed")
        parts.append(f"elapsed {_fmt_s(elapsed)}")
        parts.append(f"ETA {eta}")
        return "  ".join(parts)

    def update(self, *, ok: int = 0, failed: int = 0) -> None:
        self.ok += ok
        self.failed += failed
        if self.tty:
            self.stream.write("\r" + self.text() + "  ")
        else:
            self.stream.write(self.text() + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _start_client(opts: SweepOptions) -> tuple[Any, Any]:
    """A Dask client on the given scheduler, or on an embedded LocalCluster."""
    import dask
    import distributed

    # distributed ships no annotations for these constructors: call them through Any.
    dist: Any = distributed
    Client, LocalCluster = dist.Client, dist.LocalCluster

    if opts.scheduler:
        try:
            return Client(opts.scheduler, timeout=f"{opts.connect_timeout_s:g}s"), None
        except OSError:
            raise
        except Exception as exc:  # noqa: BLE001 - whatever answered, it is not a scheduler
            # Something else listens there (a web server's answer read as a frame length
            # once asked numpy for 3 EiB): say so as the unreachable case is said.
            raise OSError(
                f"{opts.scheduler} did not answer as a Dask scheduler "
                f"({type(exc).__name__}: {str(exc)[:120]})"
            ) from None
    n = opts.workers or default_workers()
    # The scheduler serves HTTP (health, metrics, the dashboard if bokeh is installed) on
    # a free loopback port: the default 8787 clashes with any other cluster on the machine.
    # allowed-failures 0: a run whose worker dies comes back as KilledWorker at once and
    # our own retry (once) decides, instead of Dask re-running it on up to 3 more workers.
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        cluster = LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
            memory_limit=0,
            silence_logs=logging.ERROR,
        )
        return Client(cluster), cluster


# Complexity: the sweep's one sequence: cluster, submit, collect, fail cleanly at each step.
def run_sweep(  # noqa: C901
    specs: list[RunSpec],
    set_keys: list[str],
    opts: SweepOptions,
    progress: SweepProgress | None = None,
) -> SweepOutcome:
    """Run every spec not yet finished in opts.out; returns the rows in grid order."""
    import distributed
    from distributed.client import FutureCancelledError

    dist: Any = distributed  # distributed.wait has no annotations
    wait = dist.wait

    from relayd.sweep.task import run_task

    out = opts.out
    out.mkdir(parents=True, exist_ok=True)
    rows: dict[int, dict[str, Any]] = {}
    todo: list[int] = []
    for i, spec in enumerate(specs):
        done = load_finished(out, spec)
        if done is not None:
            rows[i] = done
        else:
            todo.append(i)
    skipped = len(rows)
    prog = progress or SweepProgress(len(specs), skipped)
    ok = failed = 0

    def ordered() -> list[dict[str, Any]]:
        return [rows[i] for i in sorted(rows)]

    if todo:
        client, cluster = _start_client(opts)
        try:
            futures: dict[Any, tuple[int, int]] = {}

            def submit(i: int, attempt: int) -> Any:
                spec = specs[i]
                payload = spec.payload() | {"trace": opts.trace}
                fut = client.submit(
                    run_task,
                    payload,
                    opts.run_timeout_s,
                    pure=False,
                    key=f"relayd-run-{spec.digest}-{i}-a{attempt}",
                )
                futures[fut] = (i, attempt)
                return fut

            for i in todo:
                submit(i, 1)
            pending = set(futures)
            last_csv = time.monotonic()
            no_workers_since: float | None = None
            while pending:
                try:
                    finished, pending = wait(pending, timeout=2.0, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    finished = set()
                for fut in finished:
                    i, attempt = futures.pop(fut)
                    spec = specs[i]
                    try:
                        result = fut.result()
                    except (Exception, FutureCancelledError) as exc:  # noqa: BLE001 - any failure is the run's
                        if attempt <= opts.retries:
                            pending.add(submit(i, attempt + 1))
                            continue
                        err = f"{type(exc).__name__}: {exc}".replace("\n", " ")[:500]
                        rows[i] = row_for(spec, status="failed", attempts=attempt, error=err)
                        write_run(out, spec, rows[i], None)
                        failed += 1
                        prog.update(failed=1)
                        continue
                    start = result["series"].get("start_e2e_mbps", [None])[0]
                    rows[i] = row_for(
                        spec,
                        status="ok",
                        attempts=attempt,
                        wall_s=result["wall_s"],
                        summary=result["summary"],
                        start_e2e_mbps=start,
                    )
                    write_run(out, spec, rows[i], result)
                    ok += 1
                    prog.update(ok=1)
                if time.monotonic() - last_csv > 10.0:
                    write_csv(out / "runs.csv", ordered(), set_keys)
                    last_csv = time.monotonic()
                if pending:
                    n_workers = len(client.scheduler_info().get("workers", {}))
                    if n_workers:
                        no_workers_since = None
                    elif no_workers_since is None:
                        no_workers_since = time.monotonic()
                    elif time.monotonic() - no_workers_since > opts.no_worker_timeout_s:
                        for fut in pending:
                            i, attempt = futures.pop(fut)
                            rows[i] = row_for(
                                specs[i],
                                status="failed",
                                attempts=attempt,
                                error=f"no Dask worker for {opts.no_worker_timeout_s:g} s",
                            )
                            write_run(out, specs[i], rows[i], None)
                            failed += 1
                            prog.update(failed=1)
                        client.cancel(list(pending))
                        pending = set()
        finally:
            prog.close()
            client.close()
            if cluster is not None:
                cluster.close()
    else:
        prog.close()
    write_csv(out / "runs.csv", ordered(), set_keys)
    return SweepOutcome(len(specs), skipped, ok, failed, ordered())
