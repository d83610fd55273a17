"""Obstacle avoidance bench: the shipped obstacle scenarios, many seeds, escape vs none.

Runs the pure closed-loop model (relayd/sim/model.py: the real controller, the truthful
sonar, integer VEL/RVEL, the P3-AT's accelerations, the world's collision check) in
virtual time, for every seed of every scenario, twice: with the escape (this relayd) and
with the paper's law alone (the controller before the escape), side by side. A seed
varies the radio (shadowing and fading, hence RSSI^l) and the noise on the scan bearing.

    python bench/avoid.py                 # 10 seeds per scenario
    python bench/avoid.py --seeds 20 --markdown

Figures per scenario: success rate (the robot's centre got half a robot length past
the obstacle's far side along the line to the leader, within the time limit, with no
collision), time to get past (median and worst of the successes), the minimum clearance
from the robot's footprint to any wall or box over all runs, and collisions (contact
episodes, the world's count).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make `relayd` importable
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from relayd.sim.model import run_model
from relayd.sim.scenario import load_scenario

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
    return Row(name, "escape" if escape else "paper only", seeds, len(times),
               statistics.median(times) if times else None, max(times) if times else None,
               clearance, collisions, blocked)


def table(rows: Sequence[Row]) -> str:
    head = ("| scenario | controller | passed | time to get past, median / worst | "
            "min clearance | collisions | ended `blocked` |\n|---|---|---|---|---|---|---|")
    lines = [head]
    for r in rows:
        t = "-" if r.t_median_s is None else f"{r.t_median_s:.1f} s / {r.t_max_s:.1f} s"
        lines.append(f"| {r.scenario} | {r.variant} | {r.passed}/{r.runs} ({100 * r.passed / r.runs:.0f} %) "
                     f"| {t} | {r.min_clearance_m:.3f} m | {r.collisions} | {r.blocked} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10, help="seeds per scenario (default 10)")
    ap.add_argument("--seconds", type=float, default=300.0, help="time limit per run, clock s")
    ap.add_argument("--only", action="append", choices=list(SCENARIOS), help="one scenario (repeatable)")
    args = ap.parse_args(argv)
    started = time.perf_counter()
    rows = []
    for name in args.only or SCENARIOS:
        for escape in (True, False):
            rows.append(bench(name, SCENARIOS[name], args.seeds, args.seconds, escape))
    print(table(rows))
    print(f"\n{len(rows) * args.seeds} runs of up to {args.seconds:.0f} clock s in "
          f"{time.perf_counter() - started:.0f} s wall")
    ok = all(r.passed == r.runs and r.collisions == 0 and r.min_clearance_m >= 0.1
             for r in rows if r.variant == "escape")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
