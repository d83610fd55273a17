"""Simulator speed: simulated seconds per CPU second of `relayd sim`, and the identity check.

Each case is one `relayd sim --speed max --no-plots` run (virtual time, real daemons,
in-process devices) in a child process of its own: its wall and CPU time (the child's
user + system, from getrusage; it includes the ~1 s of imports and bring-up), the
simulated seconds (summary.json's `sim_seconds`) and a digest of its `summary.json`
and `trace.jsonl`.

With `--against TREE` every case also runs on another checkout of the project (e.g.
`git archive main | tar -x -C /tmp/base`), the two trees alternating case by case so
the machine's load hits both alike, and the table shows both side by side plus whether
the two runs gave byte-identical summary.json and trace.jsonl. A speed-up of the
simulator must not change a run: the exit status is 1 when any case differs. Where a
case differs, the table says which of summary.json's outcomes differ (none: only the
trace's figures moved), how many trace records differ, and the trace fields that do,
each with its largest difference (a change in the last bits shows as ~1e-12).

    python bench/simspeed.py                          # this tree, the default cases
    python bench/simspeed.py --against /tmp/base      # side by side + identity check
    python bench/simspeed.py --cases convoy:2:2 drift:1:1:on --repeat 3

A case is `scenario[:relays[:seed[:recovery]]]` (recovery on | off; default the
scenario's); a generated world is a scenario too, `generated:office:7:2:1` being the
office world of seed 7 with two relays and simulation seed 1. The default cases are the scenarios the test suite runs (seed 1) and
convoy with seed 2.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import statistics
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if __package__ in (None, ""):
    sys.path.insert(0, str(ROOT))

from bench.common import run_relayd_of  # noqa: E402 (after ROOT, which the path needs)

DEFAULT_CASES = (
    "convoy:2:1",
    "convoy:2:2",
    "corridor:0:1",
    "corridor:1:1",
    "corridor:2:1",
    "obstacle:1:1",
    "box-dead-ahead:1:1",
    "doorway:1:1",
    "person-in-corridor:1:1",
    "drift:1:1:off",
    "drift:1:1:on",
    "door:1:1:off",
    "door:1:1:on",
    "parking:1:1",
    "mixed",
)


@dataclass(frozen=True, slots=True)
class Case:
    scenario: str
    relays: int | None = None
    seed: int = 1
    recovery: str | None = None

    @classmethod
    def parse(cls, text: str) -> Case:
        parts = text.split(":")
        if parts[0] == "generated" and len(parts) >= 3:
            # A generated world is named generated:KIND:WORLD_SEED (relayd/sim/generate.py).
            parts = [":".join(parts[:3]), *parts[3:]]
        if not 1 <= len(parts) <= 4 or not parts[0]:
            raise argparse.ArgumentTypeError(f"not scenario[:relays[:seed[:on|off]]]: {text!r}")
        relays = int(parts[1]) if len(parts) > 1 and parts[1] else None
        seed = int(parts[2]) if len(parts) > 2 and parts[2] else 1
        rec = parts[3] if len(parts) > 3 and parts[3] else None
        if rec not in (None, "on", "off"):
            raise argparse.ArgumentTypeError(f"recovery must be on or off: {text!r}")
        return cls(parts[0], relays, seed, rec)

    def label(self) -> str:
        out = f"{self.scenario} r{'-' if self.relays is None else self.relays} s{self.seed}"
        return out if self.recovery is None else f"{out} rec {self.recovery}"

    def argv(self, out: Path) -> list[str]:
        args = [
            "sim",
            "--scenario",
            self.scenario,
            "--seed",
            str(self.seed),
            "--speed",
            "max",
            "--no-plots",
            "--out",
            str(out),
        ]
        if self.relays is not None:
            args += ["--relays", str(self.relays)]
        if self.recovery is not None:
            args += ["--recovery", self.recovery]
        return args


@dataclass(slots=True)
class Run:
    wall_s: float
    cpu_s: float
    sim_s: float
    digest: str
    summary: dict[str, object] = field(default_factory=dict)
    trace: bytes = b""


def run_case(case: Case, tree: Path) -> Run:
    """One `relayd sim` of `case` with the code of `tree`, in a child process."""
    env = dict(os.environ, PYTHONPATH=str(tree), PYTHONDONTWRITEBYTECODE="1")
    with tempfile.TemporaryDirectory(prefix="simspeed-") as tmp:
        out = Path(tmp) / "out"
        # The tree's own code, not whatever the venv has installed (checked, not assumed).
        wall, cpu = run_relayd_of(tree, case.argv(out), Path(tmp), env, case.label())
        digest = hashlib.sha256()
        for name in ("summary.json", "trace.jsonl"):
            digest.update((out / name).read_bytes())
        summary = json.loads((out / "summary.json").read_text())
        trace = (out / "trace.jsonl").read_bytes()
    return Run(wall, cpu, float(summary["sim_seconds"]), digest.hexdigest()[:12], summary, trace)


def summary_differences(a: object, b: object, where: str = "") -> list[str]:
    """The paths at which two summary.json documents differ (followers by index)."""
    if isinstance(a, dict) and isinstance(b, dict):
        keys = sorted(set(a) | set(b))
        return [d for k in keys for d in summary_differences(a.get(k), b.get(k), f"{where}.{k}")]
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [
            d
            for k, (x, y) in enumerate(zip(a, b, strict=True))
            for d in summary_differences(x, y, f"{where}[{k}]")
        ]
    return [] if a == b else [where.lstrip(".")]


def _field_deltas(a: object, b: object, where: str, out: dict[str, float]) -> None:
    """Per field path (list items merged), the largest |a - b|; inf for a non-number."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in a.keys() | b.keys():
            _field_deltas(a.get(k), b.get(k), f"{where}.{k}", out)
    elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for x, y in zip(a, b, strict=True):
            _field_deltas(x, y, f"{where}[]", out)
    elif a != b:
        delta = math.inf
        if isinstance(a, int | float) and isinstance(b, int | float):
            delta = math.inf if isinstance(a, bool) or isinstance(b, bool) else abs(a - b)
        key = where.lstrip(".")
        out[key] = max(out.get(key, 0.0), delta)


def trace_differences(a: bytes, b: bytes) -> tuple[int, dict[str, float]]:
    """(records that differ, field path -> largest difference) between two trace.jsonl."""
    la, lb = a.splitlines(), b.splitlines()
    deltas: dict[str, float] = {}
    records = abs(len(la) - len(lb))
    for x, y in zip(la, lb, strict=False):
        if x != y:
            records += 1
            _field_deltas(json.loads(x), json.loads(y), "", deltas)
    if len(la) != len(lb):
        deltas["(records)"] = math.inf
    return records, deltas


def describe_difference(a: Run, b: Run) -> str:
    """What differs between two runs of one case, in a table cell."""
    outcomes = summary_differences(a.summary, b.summary)
    text = "summary.json differs in: " + (", ".join(outcomes) if outcomes else "nothing")
    if a.trace or b.trace:
        records, deltas = trace_differences(a.trace, b.trace)
        fields = ", ".join(f"{k} {v:.2g}" for k, v in sorted(deltas.items()))
        text += f"; trace: {records} records differ, at most by {fields or 'nothing'}"
    return text


def _best(runs: Sequence[Run]) -> Run:
    """The median run by CPU time (the digests of repeats must agree)."""
    if len({r.digest for r in runs}) != 1:
        raise RuntimeError(f"repeats of one case differ: {[r.digest for r in runs]}")
    cpu = statistics.median(r.cpu_s for r in runs)
    wall = statistics.median(r.wall_s for r in runs)
    return Run(wall, cpu, runs[0].sim_s, runs[0].digest, runs[0].summary, runs[0].trace)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument(
        "--cases",
        nargs="+",
        type=Case.parse,
        default=[Case.parse(c) for c in DEFAULT_CASES],
        metavar="CASE",
        help="scenario[:relays[:seed[:on|off]]] (default: the test suite's)",
    )
    p.add_argument("--against", type=Path, help="another checkout to compare with (e.g. main's)")
    p.add_argument(
        "--repeat", type=int, default=1, help="runs per case and tree; the median is shown"
    )
    args = p.parse_args(argv)
    trees = [ROOT] + ([args.against.resolve()] if args.against else [])
    print(
        f"load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} CPUs; trees: "
        + ", ".join(str(t) for t in trees),
        flush=True,
    )
    cols = ["case", "sim s"]
    for t in trees:
        tag = "this" if t == ROOT else "other"
        cols += [f"{tag} wall s", f"{tag} CPU s", f"{tag} sim s/CPU s"]
    if args.against:
        cols += ["CPU ratio", "identical"]
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    differ = 0
    totals = [0.0] * len(trees)
    for case in args.cases:
        per_tree: list[list[Run]] = [[] for _ in trees]
        for _ in range(args.repeat):
            for k, tree in enumerate(trees):
                per_tree[k].append(run_case(case, tree))
        runs = [_best(r) for r in per_tree]
        row = [case.label(), f"{runs[0].sim_s:.1f}"]
        for k, r in enumerate(runs):
            totals[k] += r.cpu_s
            row += [f"{r.wall_s:.1f}", f"{r.cpu_s:.1f}", f"{r.sim_s / r.cpu_s:.1f}"]
        if args.against:
            same = runs[0].digest == runs[1].digest
            differ += not same
            row += [
                f"{runs[0].cpu_s / runs[1].cpu_s:.2f}",
                "yes"
                if same
                else f"**NO** {runs[0].digest} vs {runs[1].digest}; "
                + describe_difference(runs[0], runs[1]),
            ]
        print("| " + " | ".join(row) + " |", flush=True)
    print(
        "total CPU s: "
        + ", ".join(f"{t:.1f}" for t in totals)
        + (f"; ratio {totals[0] / totals[1]:.2f}" if args.against else "")
    )
    if args.against:
        print("all cases byte-identical" if not differ else f"{differ} case(s) DIFFER")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
