"""`relayd sweep`: Monte Carlo runs of the simulator over a grid, on a Dask cluster.

    relayd sweep --scenario corridor [--scenario outdoor ...] [--relays 0,1,2]
                 [--seeds N | --seed-list 1,5,9] [--set KEY=V1,V2,... ...]
                 [--seconds S] [--speed X|max] [--out DIR]
                 [--workers N | --scheduler tcp://HOST:8786] [--run-timeout S]
                 [--no-worker-timeout S] [--connect-timeout S] [--trace] [--no-plots]

Runs every combination (scenario x --set values x relay count x seed) once, each in its
own process on a Dask worker: an embedded LocalCluster with --workers processes (default:
the machine's cores), or the cluster behind --scheduler. Writes DIR/runs.csv, one folder
per run under DIR/runs/, and DIR/report.md. Re-running the same command skips the runs
already finished. Exit status: 0 when every run finished, 1 when some failed, 2 for a bad
argument or scenario.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from relayd.cli.argtypes import positive_float, scheduler_address, speed


def _int_list(text: str) -> list[int]:
    try:
        vals = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers, got {text!r}"
        ) from None
    if not vals or any(v < 0 for v in vals):
        raise argparse.ArgumentTypeError(f"expected comma-separated integers >= 0, got {text!r}")
    return vals


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {v}")
    return v


def _generated_arg(text: str) -> list[str]:
    kind, sep, n = text.partition(":")
    if not sep or not n.isdigit() or int(n) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected KIND:N, e.g. office:20")
    return [f"generated:{kind}:{i}" for i in range(int(n))]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scenario",
        action="append",
        default=[],
        help="a shipped scenario name, a TOML file or generated:KIND:SEED (repeatable)",
    )
    parser.add_argument(
        "--generated",
        action="append",
        default=[],
        type=_generated_arg,
        metavar="KIND:N",
        help="N generated worlds of KIND, seeds 0..N-1 (repeatable; relayd/sim/generate.py)",
    )
    parser.add_argument(
        "--relays",
        type=_int_list,
        default=None,
        help="relay counts, e.g. 0,1,2 (default: each scenario's own)",
    )
    seeds = parser.add_mutually_exclusive_group()
    seeds.add_argument("--seeds", type=_positive_int, default=None, help="seeds 1..N (default 10)")
    seeds.add_argument(
        "--seed-list", type=_int_list, default=None, help="explicit seeds, e.g. 3,7,11"
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=V1,V2,...",
        dest="sets",
        help="a parameter grid axis (repeatable): a dotted scenario key (radio.exponent, "
        "leader.speed_m_s) or a daemon [control]/[scan] key (threshold_b_dbm)",
    )
    parser.add_argument(
        "--seconds",
        type=positive_float,
        default=None,
        help="simulated seconds per run at most (default: each scenario's duration)",
    )
    parser.add_argument(
        "--speed",
        type=speed,
        default=None,
        help="pace of each run's virtual clock over wall time, or 'max' (default: max);"
        " results do not depend on it",
    )
    parser.add_argument("--out", default="sweep-out", help="output directory (default ./sweep-out)")
    cluster = parser.add_mutually_exclusive_group()
    cluster.add_argument(
        "--workers",
        type=_positive_int,
        default=None,
        help="worker processes of the embedded LocalCluster (default: the core count)",
    )
    cluster.add_argument(
        "--scheduler",
        type=scheduler_address,
        default=None,
        help="an existing Dask scheduler, tcp://HOST:PORT, e.g. tcp://host:8786",
    )
    parser.add_argument(
        "--run-timeout",
        type=positive_float,
        default=3600.0,
        help="wall seconds one run may take before it counts as failed (default 3600)",
    )
    parser.add_argument(
        "--no-worker-timeout",
        type=positive_float,
        default=120.0,
        help="give up on the runs still waiting after this many seconds without any worker"
        " (default 120)",
    )
    parser.add_argument(
        "--connect-timeout",
        type=positive_float,
        default=30.0,
        help="seconds to reach the --scheduler before giving up with exit 2 (default 30)",
    )
    parser.add_argument("--trace", action="store_true", help="keep each run's trace.jsonl (large)")
    parser.add_argument("--no-plots", action="store_true", help="report.md without PNG plots")


def run(args: argparse.Namespace) -> int:
    import logging

    try:
        import distributed  # noqa: F401  (Dask: an extra, not in the base install)
    except ImportError:
        print(
            "relayd sweep: Dask is not installed; install the sweep extra: "
            "pip install 'relayd[sweep]'",
            file=sys.stderr,
        )
        return 2

    from relayd.sim import plots as sim_plots
    from relayd.sweep.driver import SweepOptions, run_sweep
    from relayd.sweep.grid import GridError, build_grid, parse_set
    from relayd.sweep.report import write_report

    seeds = args.seed_list if args.seed_list is not None else list(range(1, (args.seeds or 10) + 1))
    try:
        axes = [parse_set(s) for s in args.sets]
        scenarios = list(args.scenario) + [s for g in args.generated for s in g]
        if not scenarios:
            raise GridError("--scenario or --generated: at least one")
        specs = build_grid(
            scenarios, args.relays, seeds, axes, seconds=args.seconds, speed=args.speed
        )
    except GridError as exc:
        print(f"relayd sweep: {exc}", file=sys.stderr)
        return 2
    set_keys = [a.key for a in axes]
    # Dask's own info lines (scheduler and worker start/stop) would bury the progress bar;
    # distributed sets levels on its sub-loggers when imported, so quiet them after that.

    for name in ["distributed", *logging.root.manager.loggerDict]:
        if name.startswith("distributed"):
            logging.getLogger(name).setLevel(logging.WARNING)
    out = Path(args.out)
    where = args.scheduler or f"a LocalCluster of {args.workers or 'all cores'} worker(s)"
    print(f"sweep: {len(specs)} runs on {where}; results in {out}/", flush=True)
    opts = SweepOptions(
        out=out,
        workers=args.workers,
        scheduler=args.scheduler,
        run_timeout_s=args.run_timeout,
        trace=args.trace,
        no_worker_timeout_s=args.no_worker_timeout,
        connect_timeout_s=args.connect_timeout,
    )
    try:
        outcome = run_sweep(specs, set_keys, opts)
    except (OSError, TimeoutError) as exc:
        # an unreachable --scheduler, or a LocalCluster that cannot start
        print(f"relayd sweep: no Dask cluster: {exc}", file=sys.stderr)
        return 2
    plots = not args.no_plots and sim_plots.available()
    report = write_report(out, outcome.rows, set_keys, plots=plots)
    print(
        f"sweep: {outcome.ok} run, {outcome.skipped} already done, {outcome.failed} failed;"
        f" {out / 'runs.csv'}, {report}",
        flush=True,
    )
    return 1 if any(r["status"] != "ok" for r in outcome.rows) else 0
