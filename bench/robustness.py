"""The headline robustness table: generated worlds, the shipped default beside a variant.

    python -m bench.robustness                     # 200 office + 200 corridors worlds, 2 relays,
                                                   # the shipped default beside the paper's law
                                                   # (PAPER: its keys that differ, all at 0)
    python -m bench.robustness --set control.detour=false,true
    python -m bench.robustness --worlds 20 --kind hall --kind mixed
    python -m bench.robustness --from DIR          # the table of the two laws' sweeps already
                                                   # run (DIR/default, DIR/paper), or of one
                                                   # sweep (DIR/runs.csv, its --set axis given)

Runs `relayd sweep --generated KIND:N ... --seeds 1 --relays 2 [--set AXIS] --no-plots` on
the embedded LocalCluster (two workers: the development machine's two cores; without
--set: once as shipped, into DIR/default, and once with the PAPER keys, into DIR/paper,
the two tabulated as one by their `law`) and prints, per kind and setting, the clean
share (relayd/sweep/robust.py: the leader arrived, the link held, no collision, every
relay on the link rule) with its Wilson 95 % interval and
the failures by category, the five worst runs with their worlds drawn (DIR/plots/worst-K.png),
then the sweep's wall time and what a simulated second cost.
With `--from` it reads that directory's runs.csv (and the timing it wrote, when this
script ran the sweep).
"""

from __future__ import annotations

import argparse
import csv
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

from bench.pursuit import AVOIDANCE, VARIANTS
from relayd.sweep.robust import section


def _axis(key: str, value: object) -> str:
    return f"{key}={str(value).lower() if isinstance(value, bool) else value}"


#: The paper's law as it was: bench/pursuit.py's "paper" variant (the keys of the shipped
#: default that differ from it, each at the value that turns it off) as sweep axes.
PAPER = tuple(_axis(f"control.{k}", v) for k, v in VARIANTS["paper"].items()) + tuple(
    _axis(f"avoidance.{k}", v) for k, v in AVOIDANCE["paper"].items()
)
#: The law column of the two sweeps without --set.
LAWS = {"default": (), "paper": PAPER}


def run_sweep(args: argparse.Namespace, out: Path, sets: tuple[str, ...]) -> dict[str, float]:
    cmd = [sys.executable, "-m", "relayd", "sweep", "--seeds", "1", "--relays", "2"]
    for k in args.kind:
        cmd += ["--generated", f"{k}:{args.worlds}"]
    for axis in sets:
        cmd += ["--set", axis]
    cmd += ["--workers", str(args.workers), "--out", str(out), "--no-plots"]
    print("$", " ".join(cmd[2:]), file=sys.stderr)
    t0 = time.monotonic()
    subprocess.run(cmd, check=True)
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    timing = {"wall_s": time.monotonic() - t0, "cpu_s": ru.ru_utime + ru.ru_stime}
    (out / "bench-timing.json").write_text(json.dumps(timing), encoding="utf-8")
    return timing


def by_law(out: Path, set_key: str) -> bool:
    """Is `out` the two laws' sweeps (no --set axis, DIR/default and DIR/paper)?"""
    return not set_key and (out / "default").is_dir()


def read_rows(out: Path, set_key: str) -> list[dict[str, str]]:
    """The sweep's runs.csv; the two laws' sweeps, each row with its `law`."""
    if not by_law(out, set_key):
        with (out / "runs.csv").open(encoding="utf-8") as fh:
            return list(csv.DictReader(fh))
    rows: list[dict[str, str]] = []
    for law in LAWS:
        with (out / law / "runs.csv").open(encoding="utf-8") as fh:
            for row in csv.DictReader(fh):
                row["law"] = law
                rows.append(row)
    return rows


def table(out: Path, set_key: str) -> list[str]:
    rows = read_rows(out, set_key)
    (out / "plots").mkdir(exist_ok=True)
    law = by_law(out, set_key)
    lines = section(rows, [set_key] if set_key else ["law"] if law else [], maps=out)
    sim_s = sum(float(r["sim_seconds"] or 0) for r in rows)
    run_wall_s = sum(float(r["wall_s"] or 0) for r in rows)
    lines += [
        f"Runs: {len(rows)} ({sum(r['status'] == 'ok' for r in rows)} ok), "
        f"{sim_s:,.0f} simulated s, {run_wall_s / max(sim_s, 1e-9) * 1000:.1f} ms of run "
        f"wall per simulated second (each run's own wall time; {len(rows)} runs, "
        f"mean {sim_s / max(len(rows), 1):.0f} simulated s a run).",
    ]
    paths = [out / f"{k}/bench-timing.json" for k in LAWS] if law else [out / "bench-timing.json"]
    if all(p.exists() for p in paths):
        ts = [json.loads(p.read_text(encoding="utf-8")) for p in paths]
        t = {k: sum(x[k] for x in ts) for k in ("wall_s", "cpu_s")}
        lines.append(
            f"Sweep: {t['wall_s'] / 60:.1f} min of wall, {t['cpu_s'] / 60:.1f} min of CPU "
            f"(every process of the sweep), {t['cpu_s'] / max(sim_s, 1e-9) * 1000:.1f} ms of "
            "CPU per simulated second."
        )
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--worlds", type=int, default=200, help="worlds per kind (seeds 0..N-1)")
    ap.add_argument("--kind", action="append", default=None, help="office, corridors, hall, ...")
    ap.add_argument(
        "--set", default=None, help="a variant axis (default: the shipped law and the paper's)"
    )
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("robustness-out"))
    ap.add_argument("--from", dest="src", type=Path, help="a sweep directory already run")
    args = ap.parse_args()
    args.kind = args.kind or ["office", "corridors"]
    out = args.src or args.out
    set_key = args.set.split("=", 1)[0] if args.set else ""
    if args.src is None and args.set:
        run_sweep(args, out, (args.set,))
    elif args.src is None:
        for law, sets in LAWS.items():
            run_sweep(args, out / law, sets)
    print("\n".join(table(out, set_key)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
