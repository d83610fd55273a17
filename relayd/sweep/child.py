"""One sweep run in its own process: `python -m relayd.sweep.child RUN.json OUT_DIR`.

RUN.json is a `RunSpec.payload()`. The run is the same as `relayd sim` on virtual
time (deterministic for a scenario and seed), without plots or a progress line. It
writes into OUT_DIR: summary.json (the simulator's), series.json (end-to-end
throughput once per simulated second, for the report's bands), sim.log, and
trace.jsonl when the run asks for it. Exit status 0 on success; anything else is a
failed run, its reason on stderr.

Why a process per run: the worker stays alive whatever a run does (an exception, a
hang, a crash of the interpreter), a hung run can be killed at its time limit, and no
state (logging, in-memory device registries) leaks from one run into the next.
"""

from __future__ import annotations

import json
import math
import os
import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

#: start_e2e_mbps: the mean end-to-end throughput over this first stretch of a run.
START_WINDOW_S = 20.0


def start_mean_mbps(records: Sequence[dict[str, Any]], window_s: float = START_WINDOW_S) -> float:
    """Mean end-to-end throughput over the records with t < window_s (0 if there are none)."""
    vals = [r["e2e_mbps"] for r in records if r["t"] < window_s]
    return round(sum(vals) / len(vals), 3) if vals else 0.0


def series_1hz(records: Sequence[dict[str, Any]]) -> dict[str, list[float]]:
    """The first record at or after each whole second: a compact time series for the report."""
    ts: list[float] = []
    e2e: list[float] = []
    nxt = 0
    for r in records:
        if r["t"] + 1e-9 >= nxt:
            ts.append(float(nxt))
            e2e.append(float(r["e2e_mbps"]))
            nxt = math.floor(r["t"] + 1e-9) + 1
    return {"t": ts, "e2e_mbps": e2e}


def run(spec: dict[str, Any], out: Path) -> dict[str, Any]:
    from relayd.cli.sim import SimLogFields
    from relayd.runtime import vtime
    from relayd.runtime.logsetup import setup_logging
    from relayd.sim.runner import SimRunner
    from relayd.sim.scenario import parse_scenario

    out.mkdir(parents=True, exist_ok=True)
    fields = SimLogFields()
    with (out / "sim.log").open("w", encoding="utf-8") as log_file:
        # sim.log as `relayd sim` writes it (plain JSON lines with relay and t), at warning:
        # a sweep keeps hundreds of them.
        setup_logging("warning", "json", stream=log_file, journal=False, extra=[fields])
        sc = parse_scenario(spec["scenario_doc"]).with_relays(int(spec["relays"]))
        runner = SimRunner(
            sc, speed=spec.get("speed"), seed=int(spec["seed"]), seconds=spec.get("seconds")
        )
        fields.runner = runner
        result = vtime.run(runner.run(), speed=spec.get("speed"))
    summary = dict(result.summary)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    series = series_1hz(result.records)
    series["start_e2e_mbps"] = [start_mean_mbps(result.records)]
    (out / "series.json").write_text(
        json.dumps(series, separators=(",", ":")) + "\n", encoding="utf-8"
    )
    if spec.get("trace"):
        with (out / "trace.jsonl").open("w", encoding="utf-8") as f:
            for rec in result.records:
                f.write(json.dumps(rec, separators=(",", ":")) + "\n")
    return summary


def die_with_parent() -> None:
    """Linux: SIGKILL this process when the worker that started it dies, so a dead
    worker leaves no orphan simulating; if the worker is already gone, stop now."""
    parent = os.environ.get("RELAYD_SWEEP_PARENT_PID")
    if sys.platform != "linux" or not parent:
        return
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != int(parent):
        os._exit(3)


def main(argv: Sequence[str] | None = None) -> int:
    die_with_parent()
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 2:
        print("usage: python -m relayd.sweep.child RUN.json OUT_DIR", file=sys.stderr)
        return 2
    spec = json.loads(Path(args[0]).read_text(encoding="utf-8"))
    run(spec, Path(args[1]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
