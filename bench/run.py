"""Run the benchmarks and print one markdown table: `python bench/run.py` or `python -m bench`.

    python bench/run.py                  all benchmarks, full length (~8 min), writes bench/RESULTS.md
    python bench/run.py --quick          shorter runs (~2 min); prints only
    python bench/run.py --only latency --only scan
    python bench/run.py --list
    python bench/run.py --quick --results /tmp/r.md

These are measurements, not tests: they print figures against the project's
performance targets and never fail the build. tests/bench/test_smoke.py runs each one in a tiny
configuration so they keep working. A full run of every benchmark writes
bench/RESULTS.md (machine description, the table, each benchmark's details); the
hand-written discussion at the end of that file is kept.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make `bench` and `relayd` importable
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.common import BenchOutput, Result, machine_info

#: name -> module; each module has run(quick: bool) -> BenchOutput
BENCHES: dict[str, str] = {
    "latency": "bench.latency",
    "scan": "bench.scan",
    "status": "bench.status",
    "steady": "bench.steady",
    "sim": "bench.sim",
    "estimator": "bench.estimator",
    "bus": "bench.bus",
    "probe": "bench.probe",
    "tracking": "bench.tracking",
    "adaptive": "bench.adaptive",
    "record": "bench.record",
    "foxglove": "bench.foxglove_live",
    "recovery": "bench.recovery",
}
DESCRIPTIONS = {
    "latency": "SIP -> wheel command p50/p99/max, alone and under /status load",
    "scan": "scan period over its physical minimum; theorem 1's speed bound",
    "status": "/status throughput and p99 vs a bare aiohttp JSON handler",
    "steady": "CPU and resident memory of one relayd on the fakes",
    "sim": "wall time of a 300 s three-robot convoy",
    "estimator": "bearing error after 5 scans, noise-free and noisy",
    "bus": "event publish cost with 0, 1 and 3 subscribers (one never reading)",
    "probe": "`relayd probe robot` CPU at 10 Hz SIPs, this tree beside a baseline revision",
    "tracking": "WCA vs lobe fit + Kalman filter: static, noisy, fastest leader, convoy/corridor share",
    "adaptive": "calibration accuracy; adaptive vs fixed rear limits in `mixed`; other scenarios with adaptive",
    "record": "control latency with the recorder on vs off; recording size per hour",
    "foxglove": "control latency with one live Foxglove client vs none; the live server's cost per event",
    "recovery": "self-healing on vs off: breaks healed within 60 s, downtime, collisions (5 seeds; full: bench/recovery.py)",
}
RESULTS_MD = Path(__file__).resolve().parent / "RESULTS.md"
KEEP_MARKER = "<!-- Everything below this line is hand-written and kept when bench/run.py rewrites the file. -->"


def table(results: Sequence[Result]) -> str:
    lines = [
        "| benchmark | figure | value | target | result | notes |",
        "|---|---|---|---|---|---|",
    ]
    for r in results:
        cells = (r.bench, r.figure, r.value_text(), r.target, r.verdict(), r.note)
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines)


def run_benches(
    names: Sequence[str],
    quick: bool,
    progress: Callable[[str], None] = lambda s: print(s, file=sys.stderr, flush=True),
) -> list[BenchOutput]:
    outputs = []
    for name in names:
        progress(f"== {name}: {DESCRIPTIONS[name]} ...")
        load0 = _load1()
        t0 = time.perf_counter()
        try:
            out: BenchOutput = importlib.import_module(BENCHES[name]).run(quick=quick)
        except Exception as exc:  # one broken benchmark must not hide the others' figures
            traceback.print_exc()
            out = BenchOutput(
                name,
                [
                    Result(
                        name,
                        "benchmark failed",
                        None,
                        "",
                        "",
                        False,
                        f"{type(exc).__name__}: {exc}"[:300],
                    )
                ],
            )
        out.wall_s = time.perf_counter() - t0
        # Other processes on the machine move these figures; say how busy it was.
        out.details.append(
            f"Machine load average (1 min) {load0} at the start, {_load1()} at the end "
            f"of this benchmark, on {os.cpu_count()} logical CPUs."
        )
        progress(f"   {name} done in {out.wall_s:.0f} s")
        outputs.append(out)
    return outputs


def _load1() -> str:
    try:
        return f"{os.getloadavg()[0]:.2f}"
    except OSError:
        return "n/a"


def render(
    outputs: Sequence[BenchOutput],
    machine: dict[str, str],
    *,
    quick: bool,
    argv: Sequence[str],
    keep: str = "",
) -> str:
    results = [r for o in outputs for r in o.results]
    parts = [
        "# relayd benchmark results",
        "",
        "Generated by `bench/run.py` "
        + ("(`--quick`) " if quick else "")
        + f"(`{' '.join(['python bench/run.py', *argv]).strip()}`). Targets: the target column. "
        "These are figures from one run on the machine below, not guarantees.",
        "",
        "## Machine",
        "",
        *[f"- {k}: {v}" for k, v in machine.items()],
        "",
        "## Results",
        "",
        table(results),
        "",
        "## Details",
        "",
    ]
    for o in outputs:
        parts.append(f"### {o.name} ({o.wall_s:.0f} s)")
        parts.append("")
        mod = importlib.import_module(BENCHES[o.name])
        doc = (mod.__doc__ or "").strip()
        if doc:
            parts += [doc, ""]
        for d in o.details:
            parts += [d, ""]
    parts += [KEEP_MARKER, keep.rstrip("\n"), ""]
    return "\n".join(parts)


def _kept(path: Path) -> str:
    if not path.exists():
        return ""
    text = path.read_text(encoding="utf-8")
    _, sep, after = text.partition(KEEP_MARKER)
    return after.lstrip("\n") if sep else ""


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    p = argparse.ArgumentParser(
        prog="python bench/run.py",
        description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="benchmarks: " + ", ".join(BENCHES),
    )
    p.add_argument(
        "--quick", action="store_true", help="shorter runs (fewer cycles, scans, seconds)"
    )
    p.add_argument(
        "--only",
        action="append",
        choices=list(BENCHES),
        metavar="NAME",
        help="run only this benchmark (repeatable)",
    )
    p.add_argument(
        "--results",
        type=Path,
        default=None,
        help="write the markdown report here (default: bench/RESULTS.md on a full run of all)",
    )
    p.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    args = p.parse_args(argv)
    if args.list:
        for name in BENCHES:
            print(f"{name:10s} {DESCRIPTIONS[name]}")
        return 0
    names = args.only or list(BENCHES)
    machine = machine_info()
    outputs = run_benches(names, args.quick)
    results = [r for o in outputs for r in o.results]
    print()
    print(table(results))
    target = args.results
    if target is None and not args.quick and not args.only:
        target = RESULTS_MD
    if target is not None:
        text = render(outputs, machine, quick=args.quick, argv=argv, keep=_kept(target))
        tmp = target.with_name(target.name + ".tmp")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, target)
        print(f"\nwrote {target}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
