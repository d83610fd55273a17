"""Obstacle avoidance bench: the shipped obstacle scenarios, many seeds, escape vs none.

Runs the pure closed-loop model (relayd/sim/model.py: the real controller, the truthful
sonar, integer VEL/RVEL, the P3-AT's accelerations, the world's collision check) in
virtual time, for every seed of every scenario, twice: with the escape (this relayd) and
with the paper's law alone (the controller before the escape), side by side. A seed
varies the radio (shadowing and fading, hence RSSI^l) and the noise on the scan bearing.

    python bench/avoid.py                 # 10 seeds per scenario
    python bench/avoid.py --seeds 20
    python bench/avoid.py --real          # the same, with real daemons (`relayd sim`)

`--real` runs each seed through `relayd sim`'s runner instead (real relayd daemons with
the in-process fakes, the FakeRobot's motion, real sweeps of the scan servo and the
estimator's bearing, virtual time, flat out), for the scenario's own duration. Its
clearance is sampled on the 10 Hz trace (the robot moves at most 3 cm between
samples, 1.5 cm during an escape), so it may read up to that much high.

Figures per scenario: success rate (the robot's centre got half a robot length past
the obstacle's far side along the line to the leader, within the time limit, with no
collision), time to get past (median and worst of the successes), the minimum clearance
from the robot's footprint to any wall or box over all runs, and collisions (contact
episodes, the world's count).
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

if __package__ in (None, ""):  # run as a script: make `relayd` importable
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from relayd.core.geometry import ROBOT_LENGTH_M
from relayd.sim.model import clearance_m, run_model
from relayd.sim.scenario import load_scenario

if TYPE_CHECKING:
    from relayd.sim.runner import SimResult

#: Scenario -> the far side of its obstacle along the line to the leader (m).
SCENARIOS: dict[str, float] = {
    "box-dead-ahead": 2.75,
    "box-dead-ahead-offset": 2.75,
    "u-trap": 3.5,
    "doorway": 3.0,
    "person-in-corridor": 2.75,
}


@dataclass(slots=True)
class Row:
    scenario: str
    variant: str
    runs: int
    passed: int
    t_median_s: float | None
    t_max_s: float | None
    min_clearance_m: float
    collisions: int
    blocked: int


def bench(name: str, past_m: float, seeds: int, seconds: float, escape: bool) -> Row:
    scenario = load_scenario(name)
    times: list[float] = []
    clearance = float("inf")
    collisions = blocked = 0
    for seed in range(seeds):
        out = run_model(scenario, seed=seed, past_m=past_m, seconds=seconds, escape=escape)
        clearance = min(clearance, out.min_clearance_m)
        collisions += out.collisions
        blocked += out.final_reason == "blocked"
        if out.passed_at_s is not None and out.collisions == 0:
            times.append(out.passed_at_s)
    return Row(
        name,
        "escape" if escape else "paper only",
        seeds,
        len(times),
        statistics.median(times) if times else None,
        max(times) if times else None,
        clearance,
        collisions,
        blocked,
    )


def _real_run(name: str, seed: int) -> tuple[SimResult, float]:
    """One `relayd sim` run, flat out on virtual time, and its footprint's least clearance."""
    from relayd.runtime import vtime
    from relayd.sim.runner import SimRunner

    runner = SimRunner(load_scenario(name).with_relays(1), speed=None, seed=seed)
    world, low = runner.world, [float("inf")]

    def watch(_rec: dict[str, Any]) -> None:
        low[0] = min(low[0], clearance_m(world.relays[0].polygon(), world.obstacles))

    runner.on_progress = watch
    return vtime.run(runner.run(), speed=None), low[0]


def bench_real(name: str, past_m: float, seeds: int) -> Row:
    """The scenario with real daemons (`relayd sim`, virtual time), one run per seed."""
    times: list[float] = []
    clearance = float("inf")
    collisions = blocked = 0
    for seed in range(seeds):
        result, low = _real_run(name, seed)
        first = result.records[0]
        sx, sy = first["relays"][0]["x"], first["relays"][0]["y"]
        lx, ly = first["leader"]["x"], first["leader"]["y"]
        line = math.atan2(ly - sy, lx - sx)
        passed = None
        for rec in result.records:
            r = rec["relays"][0]
            if (r["x"] - sx) * math.cos(line) + (r["y"] - sy) * math.sin(
                line
            ) >= past_m + ROBOT_LENGTH_M / 2.0:
                passed = rec["t"]
                break
        follower = result.summary["followers"][0]
        clearance = min(clearance, low)
        collisions += result.summary["collisions"]
        blocked += follower["stopped_reason"] == "blocked"
        if passed is not None and result.summary["collisions"] == 0:
            times.append(passed)
    return Row(
        name,
        "real daemons",
        seeds,
        len(times),
        statistics.median(times) if times else None,
        max(times) if times else None,
        clearance,
        collisions,
        blocked,
    )


def table(rows: Sequence[Row]) -> str:
    head = (
        "| scenario | controller | passed | time to get past, median / worst | "
        "min clearance | collisions | ended `blocked` |\n|---|---|---|---|---|---|---|"
    )
    lines = [head]
    for r in rows:
        t = "-" if r.t_median_s is None else f"{r.t_median_s:.1f} s / {r.t_max_s:.1f} s"
        lines.append(
            f"| {r.scenario} | {r.variant} | {r.passed}/{r.runs} ({100 * r.passed / r.runs:.0f} %) "
            f"| {t} | {r.min_clearance_m:.3f} m | {r.collisions} | {r.blocked} |"
        )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10, help="seeds per scenario (default 10)")
    ap.add_argument("--seconds", type=float, default=300.0, help="time limit per run, clock s")
    ap.add_argument(
        "--only", action="append", choices=list(SCENARIOS), help="one scenario (repeatable)"
    )
    ap.add_argument(
        "--real",
        action="store_true",
        help="real daemons (relayd sim, the scenario's duration) instead of the model",
    )
    args = ap.parse_args(argv)
    started = time.perf_counter()
    rows = []
    if args.real:
        from relayd.runtime.logsetup import setup_logging

        # The daemons' logs would bury the table: warnings and worse only, and nowhere.
        setup_logging("warning", "json", stream=open(os.devnull, "w"), journal=False)  # noqa: SIM115
    for name in args.only or SCENARIOS:
        if args.real:
            rows.append(bench_real(name, SCENARIOS[name], args.seeds))
            print(table(rows[-1:]).splitlines()[-1], file=sys.stderr, flush=True)
            continue
        for escape in (True, False):
            rows.append(bench(name, SCENARIOS[name], args.seeds, args.seconds, escape))
    print(table(rows))
    limit = "the scenario's duration" if args.real else f"{args.seconds:.0f} clock s"
    print(
        f"\n{len(rows) * args.seeds} runs of up to {limit} in "
        f"{time.perf_counter() - started:.0f} s wall"
    )
    ok = all(
        r.passed == r.runs and r.collisions == 0 and r.min_clearance_m >= 0.1
        for r in rows
        if r.variant != "paper only"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
