"""What a robustness sweep costs: a small `relayd sweep` of generated worlds, timed, and
extrapolated to the headline sweep's run count.

Each tree (this checkout, and with `--against` another one, e.g. `git archive main | tar
-x -C /tmp/base`) runs the same sweep in a child process of its own: N office and N
corridors worlds (seeds 0..N-1), 2 relays, simulation seed 1, on the embedded LocalCluster
with `--workers` workers, no plots. The table gives the sweep's wall time, the CPU time of
its whole process tree (the driver, Dask's scheduler and workers, every run), the
simulated seconds, and the cost per simulated second and per run; then the wall time
the same mix would take for `--runs` runs (800: 200 + 200 worlds, both pursuit laws),
at the sample's wall per run. With `--against` the two trees' runs.csv must agree in
every column but wall_s (exit status 1 otherwise).

    python bench/sweepspeed.py --worlds 10                      # this tree
    python bench/sweepspeed.py --worlds 10 --against /tmp/base  # before / after

The machine's load changes both figures (a loaded machine's cores are shared): the
table prints the load average before and after each sweep.
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if __package__ in (None, ""):
    sys.path.insert(0, str(ROOT))

from bench.common import run_relayd_of  # noqa: E402 (after ROOT, which the path needs)


@dataclass(frozen=True, slots=True)
class Sweep:
    runs: int
    wall_s: float
    cpu_s: float
    sim_s: float
    rows: list[dict[str, str]]
    load: tuple[float, float]


def run_sweep(tree: Path, worlds: int, workers: int, extra: Sequence[str]) -> Sweep:
    """One sweep with the code of `tree`, in a child process; its figures and rows."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    with tempfile.TemporaryDirectory(prefix="sweepspeed-") as tmp:
        out = Path(tmp) / "out"
        argv = [
            "sweep",
            "--generated",
            f"office:{worlds}",
            "--generated",
            f"corridors:{worlds}",
            "--relays",
            "2",
            "--seeds",
            "1",
            "--workers",
            str(workers),
            "--no-plots",
            "--out",
            str(out),
            *extra,
        ]
        load0 = os.getloadavg()[0]
        wall, cpu = run_relayd_of(tree, argv, Path(tmp), env, "sweep")
        with (out / "runs.csv").open(encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
    sim = sum(float(r["sim_seconds"]) for r in rows if r["sim_seconds"])
    return Sweep(len(rows), wall, cpu, sim, rows, (load0, os.getloadavg()[0]))


def outcomes(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--worlds", type=int, default=10, help="worlds of each kind (default 10)")
    p.add_argument("--workers", type=int, default=2, help="LocalCluster workers (default 2)")
    p.add_argument("--runs", type=int, default=800, help="run count to extrapolate to")
    p.add_argument("--against", type=Path, help="another checkout to compare with")
    p.add_argument("--set", action="append", default=[], help="passed to relayd sweep")
    args = p.parse_args(argv)
    extra = [a for s in args.set for a in ("--set", s)]
    trees = [ROOT] + ([args.against.resolve()] if args.against else [])
    cols = ["tree", "runs", "sim s", "wall s", "CPU s", "CPU ms / sim s", "wall s / run"]
    cols += ["load avg", f"{args.runs} runs, wall"]
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    results = []
    for tree in trees:
        s = run_sweep(tree, args.worlds, args.workers, extra)
        results.append(s)
        per_run = s.wall_s / s.runs
        est_min = per_run * args.runs / 60.0
        row = [
            "this" if tree == ROOT else str(tree),
            str(s.runs),
            f"{s.sim_s:.0f}",
            f"{s.wall_s:.0f}",
            f"{s.cpu_s:.0f}",
            f"{1000 * s.cpu_s / s.sim_s:.1f}",
            f"{per_run:.2f}",
            f"{s.load[0]:.1f}-{s.load[1]:.1f}",
            f"{est_min:.0f} min",
        ]
        print("| " + " | ".join(row) + " |", flush=True)
    if args.against:
        same = outcomes(results[0].rows) == outcomes(results[1].rows)
        print("runs.csv identical but for wall_s" if same else "runs.csv DIFFERS")
        return 0 if same else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
