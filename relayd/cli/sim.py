"""`relayd sim`: run real relayd daemons in the simulated world and summarise the run.

    relayd sim [--scenario NAME|FILE] [--map FILE.map] [--engine builtin|mobilesim]
               [--mobilesim PATH] [--relays N|all] [--speed X|max] [--seconds S]
               [--out DIR] [--seed N] [--no-plots] [--record] [--recovery on|off]
               [--log-level LEVEL]

With no arguments: the corridor with two relays at speed 10. Prints each relay's API
port at start (its live page is at http://127.0.0.1:PORT/), a one-line progress on a
terminal, then a short summary; writes summary.json, trace.jsonl, sim.log and PNG
plots (if matplotlib imports) into --out, and with --record each relay's recording,
<out>/<relay name>.mcap, made by that relay's daemon exactly as on a robot. `--relays all` runs the scenario once per
relay count (0, 1, ... N) into DIR/relays-K/ and draws their throughput in one plot.
Exit status: 0 when the run(s) completed, 2 for a bad scenario or argument. SIGTERM
or Ctrl-C stops a run in order (the relays' daemons, then MobileSim and its Xvfb with
`--engine mobilesim`) and exits 0 or 130, as every relayd command does; the outputs of
the run cut short are incomplete.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from relayd.cli.argtypes import positive_float, speed

if TYPE_CHECKING:  # the simulator is imported when a run starts, not with the command line
    from relayd.sim.runner import SimRunner

DEFAULT_SCENARIO = "corridor"
DEFAULT_SPEED = 10.0


def _relays_arg(text: str) -> int | str:
    if text == "all":
        return text
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--relays must be a number or 'all', got {text!r}"
        ) from None
    if n < 0:
        raise argparse.ArgumentTypeError("--relays must be >= 0")
    return n


def configure(parser: argparse.ArgumentParser) -> None:
    from relayd.sim.scenario import builtin_names

    parser.add_argument(
        "--scenario",
        default=DEFAULT_SCENARIO,
        metavar="NAME|FILE",
        help=f"a shipped scenario ({', '.join(builtin_names())}; default {DEFAULT_SCENARIO})"
        " or a scenario TOML file (docs/SIMULATOR.md), or generated:KIND:SEED (relayd/sim/generate.py)",
    )
    parser.add_argument(
        "--map",
        default=None,
        metavar="FILE.map",
        help="an ARIA map (docs/SIMULATOR.md, 'ARIA maps'): its walls, points, RobotHome"
        " start poses and Goal route; with --scenario FILE the scenario's other keys apply",
    )
    parser.add_argument(
        "--map-material",
        default=None,
        metavar="NAME",
        help="material of the map's LINES (default: the scenario's map_material, else brick)",
    )
    parser.add_argument(
        "--engine",
        choices=["builtin", "mobilesim"],
        default="builtin",
        help="builtin: relayd's own world on virtual time (default); mobilesim: the robots in"
        " MobileSim, in real time (needs --map or a scenario with map =)",
    )
    parser.add_argument(
        "--mobilesim",
        default=None,
        metavar="PATH",
        help="the MobileSim program for --engine mobilesim (default: $RELAYD_MOBILESIM)",
    )
    parser.add_argument(
        "--save-scenario",
        metavar="FILE",
        default=None,
        help="write the generated:KIND:SEED world's scenario TOML to FILE and exit",
    )
    parser.add_argument(
        "--relays",
        type=_relays_arg,
        default=None,
        metavar="N|all",
        help="number of relays, or 'all' for one run per count (default: the scenario's)",
    )
    parser.add_argument(
        "--speed",
        type=speed,
        default=DEFAULT_SPEED,
        metavar="X|max",
        help=f"pace of the virtual clock over wall time, or 'max' (default {DEFAULT_SPEED:g});"
        " the results do not depend on it",
    )
    parser.add_argument(
        "--seconds",
        type=positive_float,
        default=None,
        metavar="S",
        help="simulated seconds to run at most (default: the scenario's duration)",
    )
    parser.add_argument(
        "--out", default="sim-out", metavar="DIR", help="output directory (default ./sim-out)"
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=1,
        metavar="N",
        help="world seed (shadowing, fading, sonar noise; default 1)",
    )
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    parser.add_argument(
        "--record",
        action="store_true",
        help="each relay's daemon records its run to <out>/<relay name>.mcap (docs/RECORDING.md)",
    )

    parser.add_argument(
        "--recovery",
        choices=["on", "off"],
        default=None,
        help="force every relay's recovery.enabled (default: the scenario's [recovery])",
    )
    parser.add_argument(
        "--log-level",
        default="info",
        choices=["debug", "info", "warning", "error"],
        help="daemon log level in sim.log (default info)",
    )


class SimLogFields:
    """structlog processor: every sim.log line names its relay and carries the simulated time.

    `relay` comes from the context each relay's tasks run in (None for the world's own
    lines); `t` is the simulated second, on the same scale as trace.jsonl's `t`.
    """

    def __init__(self) -> None:
        self.runner: SimRunner | None = None

    def __call__(self, _logger: Any, _method: str, event: dict[str, Any]) -> dict[str, Any]:
        event.setdefault("relay", None)
        event["t"] = round(self.runner.sim_time(), 3) if self.runner is not None else 0.0
        return event


SIM_LOG_FIELDS = SimLogFields()


#: A relay that drove less than this (m) in a run never moved.
STILL_M = 0.05


def outcome_words(s: dict[str, Any]) -> str:
    """What happened to the leader and the link, in words that cannot mislead: a leader
    already on its goal reached nothing, and a link that broke after the leader arrived
    broke (summary.json's goal_reached counts that run as reached: the paper's measure)."""
    arrived, broken = s["goal_reached_at_s"], s["link_broken_at_s"]
    breaks = s.get("link_breaks") or []
    still_down = bool(breaks) and breaks[-1].get("end_s") is None
    down = ", and was still down at the end" if still_down else ""
    if arrived is not None and arrived <= 0.0:
        leader = "the leader stood on its goal from the start (nothing to reach)"
    elif arrived is not None:
        leader = f"the leader reached its goal at {arrived:.1f} s"
    else:
        leader = "the leader did NOT reach its goal"
    if broken is None:
        return f"{leader}, the link held"
    if arrived is not None and 0.0 < arrived < broken:
        return f"{leader} with the link up; the link broke later, at {broken:.1f} s{down}"
    if arrived is not None and arrived > 0.0:
        # summary.json's goal_reached is false: the paper's goal is to arrive connected.
        return f"{leader}, but the link had broken before, at {broken:.1f} s{down}"
    return f"{leader}; the link broke at {broken:.1f} s{down}"


def format_summary(s: dict[str, Any]) -> str:
    """A few human lines about one run."""
    lines = [
        f"{s['scenario']} with {s['relays']} relay(s), {s['sim_seconds']:.0f} s simulated: "
        + outcome_words(s),
        f"  end-to-end throughput: min {s['min_e2e_mbps']:.1f} Mbps, final {s['final_e2e_mbps']:.1f} Mbps;"
        f" collisions: {s['collisions']}",
    ]
    still = [f["name"] for f in s["followers"] if f["travelled_m"] < STILL_M]
    if still:
        lines.append(f"  never moved: {', '.join(still)}")
    stuck = [f for f in s["followers"] if f.get("on_link_rule") is False]
    if stuck:
        ends = ", ".join(f"{f['name']} ({f['final_state']}: {f['stopped_reason']})" for f in stuck)
        lines.append(f"  NOT ended on the link rule (stuck or gave up): {ends}")
    breaks = s.get("link_breaks") or []
    if breaks:
        lines.append(f"  link breaks: {len(breaks)}, down {s.get('downtime_s', 0.0):.1f} s in all")
    for f in s["followers"]:
        lines.append(
            f"  {f['name']}: max gap {f['max_gap_m']:.1f} m, final gap {f['final_gap_m']:.1f} m, "
            f"travelled {f['travelled_m']:.1f} m, ends {f['final_state']} ({f['stopped_reason']})"
        )
        for e in f.get("recovery_episodes") or []:
            lines.append(
                f"    recovery {e['kind']} {e['start_s']:.1f}-"
                + ("..." if e["end_s"] is None else f"{e['end_s']:.1f}")
                + f" s: {e['outcome']}, {e['distance_m']:.1f} m"
            )
    return "\n".join(lines)


def _mobilesim_kwargs(args: argparse.Namespace, out: Path) -> dict[str, Any]:
    """The MobileSim engine's program and log file (MobileSimError if there is no program)."""
    from relayd.sim.msproc import find_program

    out.mkdir(parents=True, exist_ok=True)
    return {"program": find_program(args.mobilesim), "mobilesim_log": out / "mobilesim.log"}


async def run_one(
    scenario: Any, relays: int, args: argparse.Namespace, out: Path, plots: bool
) -> tuple[dict[str, Any], list[dict[str, Any]], Any]:
    from relayd.sim import plots as sim_plots
    from relayd.sim.progress import ProgressLine
    from relayd.sim.runner import SimRunner

    sc = scenario.with_relays(relays)
    seconds = args.seconds if args.seconds is not None else sc.duration_s
    progress = ProgressLine(seconds)

    def ready(ports: dict[str, int | None]) -> None:
        for name, port in ports.items():
            print(f"{name}: API and live page at http://127.0.0.1:{port}/", flush=True)

    kwargs: dict[str, Any] = {}
    if getattr(args, "engine", "builtin") == "mobilesim":
        from relayd.sim.msengine import MobileSimRunner

        runner_cls: Any = MobileSimRunner
        kwargs = _mobilesim_kwargs(args, out)
    else:
        runner_cls = SimRunner
    runner = runner_cls(
        sc,
        **kwargs,
        speed=args.speed,
        seed=args.seed,
        seconds=seconds,
        out_dir=out,
        on_progress=progress,
        on_ready=ready,
        record_dir=out if args.record else None,
        recovery=None if args.recovery is None else args.recovery == "on",
    )
    SIM_LOG_FIELDS.runner = runner
    try:
        result = await runner.run()
    finally:
        progress.close()
        SIM_LOG_FIELDS.runner = None
    if plots:
        sim_plots.write_run_plots(runner.world, result.records, out)
    return result.summary, result.records, runner.world


def _open_log(out: Path) -> Any:
    out.mkdir(parents=True, exist_ok=True)
    return (out / "sim.log").open("w", encoding="utf-8")


def _save_generated(ref: str, dest: Path) -> int:
    from relayd.sim.generate import GenerateError, generate, parse_ref

    try:
        parsed = parse_ref(ref)
        if parsed is None:
            print(f"--save-scenario: {ref!r} is not generated:KIND:SEED", file=sys.stderr)
            return 2
        dest.write_text(generate(*parsed), encoding="utf-8")
    except (GenerateError, OSError) as exc:
        print(f"--save-scenario: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {dest}")
    return 0


def _load(args: argparse.Namespace) -> Any:
    """The scenario of --scenario, read from --map's ARIA map when given (ScenarioError)."""
    from relayd.sim.scenario import load_scenario, parse_scenario

    if args.map is None:
        if args.map_material is not None:
            from relayd.sim.scenario import ScenarioError

            raise ScenarioError(["--map-material: needs --map"])
        return load_scenario(args.scenario)
    import tomllib

    from relayd.sim.mapscenario import with_map

    doc: dict[str, Any] = {}
    if args.scenario != DEFAULT_SCENARIO:
        p = Path(args.scenario)
        try:
            doc = tomllib.loads(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
            from relayd.sim.scenario import ScenarioError

            raise ScenarioError([f"{p}: {exc}"]) from None
    doc.pop("map", None)
    if args.map_material is not None:
        doc["map_material"] = args.map_material
    return parse_scenario(with_map(doc, args.map))


def run(args: argparse.Namespace) -> int:
    """On a virtual-time loop: deterministic, paced to --speed x wall time (or flat out)."""
    from relayd.cli.dispatch import until_signal
    from relayd.runtime import vtime

    if args.engine == "mobilesim":
        import asyncio

        # MobileSim runs in real time: a plain event loop, whatever --speed says.
        return asyncio.run(until_signal(_stoppable(args))) or 0
    return vtime.run(until_signal(_stoppable(args)), speed=args.speed) or 0


async def _stoppable(args: argparse.Namespace) -> int:
    """`_run`, saying so when a signal cuts it short (the runners' `finally` blocks have
    stopped the daemons, MobileSim and Xvfb by the time the cancellation gets here)."""
    import asyncio

    try:
        return await _run(args)
    except asyncio.CancelledError:
        print("relayd sim: stopped before the end of the run", file=sys.stderr, flush=True)
        raise


async def _run(args: argparse.Namespace) -> int:
    from relayd.runtime.logsetup import StdStream, setup_logging
    from relayd.sim import plots as sim_plots
    from relayd.sim.msproc import MobileSimError
    from relayd.sim.scenario import ScenarioError

    if args.save_scenario is not None:
        return _save_generated(args.scenario, Path(args.save_scenario))
    try:
        scenario = _load(args)
        if isinstance(args.relays, int):
            scenario.with_relays(args.relays)
    except ScenarioError as exc:
        what = args.scenario if args.map is None else args.map
        print(f"{what}: {len(exc.errors)} error(s)", file=sys.stderr)
        for line in exc.errors:
            print(f"  {line}", file=sys.stderr)
        return 2
    out = Path(args.out)
    log_file = _open_log(out)
    try:
        # Plain JSON lines (no journald priority prefix): sim.log is read by tools and people.
        setup_logging(
            args.log_level, "json", stream=log_file, journal=False, extra=[SIM_LOG_FIELDS]
        )
        plots = not args.no_plots and sim_plots.available()
        if args.no_plots is False and not plots:
            print(
                "matplotlib is not installed: no plots (pip install 'relayd[sim]')", file=sys.stderr
            )
        counts = (
            list(range(len(scenario.relay) + 1))
            if args.relays == "all"
            else [scenario.relays if args.relays is None else int(args.relays)]
        )
        runs: list[tuple[str, list[dict[str, Any]]]] = []
        summaries = []
        for n in counts:
            sub = out / f"relays-{n}" if args.relays == "all" else out
            pace = "max" if args.speed is None else f"{args.speed:g}"
            print(f"running {scenario.name} with {n} relay(s) at speed {pace} ...", flush=True)
            try:
                summary, records, _ = await run_one(scenario, n, args, sub, plots)
            except MobileSimError as exc:
                print(f"mobilesim: {exc}", file=sys.stderr)
                return 2
            summaries.append(summary)
            runs.append((f"{n} relay(s)", records))
            print(format_summary(summary), flush=True)
        if args.relays == "all":
            (out / "summary.json").write_text(
                json.dumps({"scenario": scenario.name, "runs": summaries}, indent=2) + "\n",
                encoding="utf-8",
            )
            if plots:
                from relayd.sim.plots_throughput import plot_throughput

                plot_throughput(
                    runs,
                    out / "throughput.png",
                    f"{scenario.name}: end-to-end throughput by number of relays",
                )
        print(f"outputs in {out}/", flush=True)
    finally:
        # Never leave structlog writing into a closed file.
        setup_logging("warning", "console", stream=StdStream("stderr"))
        log_file.close()
    return 0
