"""Self-healing (relayd/core/recovery/machine.py): recovery on vs off, the same scenarios and seeds, one run.

For each scenario and seed the simulator runs twice on virtual time (flat out), once
with every relay's `recovery.enabled = false` (today's behaviour, the baseline) and
once with it on, and reads summary.json:

- **recovery rate**: the share of end-to-end link breaks (spells closer than 1 s merged,
  `relayd.sim.outcomes.link_breaks`) that ended within 60 s of simulated time; a break
  still open at the end of the run counts as not healed, except one that began less
  than 60 s before the end (it had no chance to be judged: counted as "censored");
- **downtime**: the end-to-end link's total down time per run, median and worst;
- **collisions** and recovery episodes (count, outcomes, distance driven).

The self-healing scenarios (blind-corner, door, drift) get `--seeds` seeds each; the
shipped paper scenarios (corridor, convoy, obstacle, parking) get `--check-seeds` each
and must behave as before with recovery on: goal reached as often, no more collisions,
downtime no worse.

    python bench/recovery.py                 # 20 seeds x 3 scenarios, 3 x 4 checks
    python bench/recovery.py --seeds 5 --check-seeds 1 --results /tmp/r.md
    python bench/recovery.py --scenarios blind-corner --seeds 10 --checks '' --estimator lobe --window adaptive
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.common import BenchOutput, Result

NAME = "recovery"
HEAL_WITHIN_S = 60.0
TARGET_RATE = 0.95
HEALING_SCENARIOS = ("blind-corner", "door", "drift")
CHECK_SCENARIOS = ("corridor", "convoy", "obstacle", "parking")


def run_sim(
    scenario: str, seed: int, recovery: bool, scan: dict[str, Any] | None = None
) -> dict[str, Any]:
    """One flat-out virtual-time run; its summary. `scan`: settings laid over the scenario's
    `[scan]` (e.g. the bearing estimator)."""
    from relayd.runtime import vtime
    from relayd.sim.runner import SimRunner
    from relayd.sim.scenario import load_scenario

    sc = load_scenario(scenario)
    if scan:
        sc = sc.model_copy(update={"scan": {**sc.scan, **scan}})

    async def go() -> dict[str, Any]:
        result = await SimRunner(sc, speed=None, seed=seed, recovery=recovery).run()
        return result.summary

    summary: dict[str, Any] = vtime.run(go(), speed=None)
    return summary


def healed(summary: dict[str, Any]) -> tuple[int, int, int]:
    """(breaks judged, healed within HEAL_WITHIN_S, censored) of one run."""
    end = float(summary["sim_seconds"])
    judged = ok = censored = 0
    for b in summary.get("link_breaks") or []:
        if b["end_s"] is None and end - b["start_s"] < HEAL_WITHIN_S:
            censored += 1
            continue
        judged += 1
        if b["duration_s"] is not None and b["duration_s"] <= HEAL_WITHIN_S:
            ok += 1
    return judged, ok, censored


def _episodes(summary: dict[str, Any]) -> list[dict[str, Any]]:
    return [e for f in summary["followers"] for e in f.get("recovery_episodes") or []]


def aggregate(runs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    n_breaks = n_ok = n_censored = 0
    for s in runs:
        b, ok, cen = healed(s)
        n_breaks += b
        n_ok += ok
        n_censored += cen
    down = [float(s.get("downtime_s") or 0.0) for s in runs]
    eps = [e for s in runs for e in _episodes(s)]
    outcomes: dict[str, int] = {}
    for e in eps:
        key = str(e["outcome"] or "open")
        outcomes[key] = outcomes.get(key, 0) + 1
    return {
        "runs": len(runs),
        "breaks": n_breaks,
        "healed": n_ok,
        "censored": n_censored,
        "rate": None if n_breaks == 0 else n_ok / n_breaks,
        "down_median_s": statistics.median(down) if down else None,
        "down_worst_s": max(down) if down else None,
        "collisions": sum(int(s["collisions"]) for s in runs),
        "goal": sum(1 for s in runs if s["goal_reached"]),
        "episodes": len(eps),
        "outcomes": outcomes,
        "episode_m_max": max((float(e["distance_m"]) for e in eps), default=0.0),
    }


def _rate(a: dict[str, Any]) -> str:
    return (
        "no breaks"
        if a["rate"] is None
        else f"{100 * a['rate']:.0f} % ({a['healed']}/{a['breaks']})"
    )


def table(rows: dict[str, dict[str, dict[str, Any]]]) -> str:
    head = (
        "| scenario | recovery | runs | breaks (censored) | healed <= 60 s | downtime median | downtime worst "
        "| goal reached | collisions | episodes (outcomes) | longest episode |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|"
    )
    lines = [head]
    for sc, by in rows.items():
        for mode in ("off", "on"):
            a = by.get(mode)
            if a is None:
                continue
            outs = ", ".join(f"{k} {v}" for k, v in sorted(a["outcomes"].items())) or "-"
            lines.append(
                f"| {sc} | {mode} | {a['runs']} | {a['breaks']} ({a['censored']}) | {_rate(a)} | {a['down_median_s']:.1f} s "
                f"| {a['down_worst_s']:.1f} s | {a['goal']}/{a['runs']} | {a['collisions']} "
                f"| {a['episodes']} ({outs}) | {a['episode_m_max']:.1f} m |"
            )
    return "\n".join(lines)


def measure(
    scenarios: Sequence[str],
    seeds: int,
    *,
    log: Any = None,
    keep: dict[str, Any] | None = None,
    scan: dict[str, Any] | None = None,
) -> dict[str, dict[str, dict[str, Any]]]:
    """Run every scenario and seed with recovery off and on; `keep` collects the summaries."""
    rows: dict[str, dict[str, dict[str, Any]]] = {}
    for sc in scenarios:
        runs: dict[str, list[dict[str, Any]]] = {"off": [], "on": []}
        for seed in range(1, seeds + 1):
            for mode in ("off", "on"):
                t0 = time.perf_counter()
                s = run_sim(sc, seed, mode == "on", scan)
                runs[mode].append(s)
                if keep is not None:
                    keep.setdefault(sc, {}).setdefault(mode, []).append(s)
                if log is not None:
                    b, ok, cen = healed(s)
                    print(
                        f"{sc} seed {seed} recovery {mode}: breaks {b} healed {ok} censored {cen} "
                        f"down {s['downtime_s']} s "
                        f"collisions {s['collisions']} goal {s['goal_reached']} "
                        f"({time.perf_counter() - t0:.0f} s wall)",
                        file=log,
                        flush=True,
                    )
        rows[sc] = {m: aggregate(r) for m, r in runs.items()}
    return rows


def results(rows: dict[str, dict[str, dict[str, Any]]], healing: Sequence[str]) -> list[Result]:
    out: list[Result] = []
    for sc, by in rows.items():
        on, off = by["on"], by["off"]
        if sc in healing:
            rate = on["rate"]
            out.append(
                Result(
                    NAME,
                    f"{sc}: breaks healed within 60 s, recovery on",
                    None if rate is None else 100 * rate,
                    "%",
                    ">= 95 %",
                    None if rate is None else rate >= TARGET_RATE,
                    f"off: {_rate(off)}; on: {_rate(on)}",
                )
            )
            out.append(
                Result(
                    NAME,
                    f"{sc}: downtime median / worst, recovery on",
                    on["down_median_s"],
                    "s",
                    "",
                    None,
                    f"worst {on['down_worst_s']:.1f} s; off: median {off['down_median_s']:.1f} s, "
                    f"worst {off['down_worst_s']:.1f} s",
                )
            )
        else:
            same = (
                on["goal"] >= off["goal"]
                and on["collisions"] <= off["collisions"]
                and (on["down_median_s"] or 0.0) <= (off["down_median_s"] or 0.0) + 1.0
            )
            out.append(
                Result(
                    NAME,
                    f"{sc}: unchanged with recovery on",
                    None,
                    "",
                    "as before",
                    same,
                    f"goal {on['goal']}/{on['runs']} vs {off['goal']}/{off['runs']}, collisions "
                    f"{on['collisions']} vs {off['collisions']}, downtime median "
                    f"{on['down_median_s']:.1f} vs {off['down_median_s']:.1f} s",
                )
            )
        out.append(
            Result(
                NAME,
                f"{sc}: collisions, recovery on",
                on["collisions"],
                "",
                "0",
                on["collisions"] == 0,
            )
        )
    return out


def run(quick: bool = False) -> BenchOutput:
    """bench/run.py's entry: a few seeds (the full figure is `python bench/recovery.py`)."""
    _quiet_daemons()
    seeds, checks = (2, 1) if quick else (5, 1)
    rows = measure(HEALING_SCENARIOS, seeds)
    rows.update(measure(CHECK_SCENARIOS, checks))
    out = BenchOutput(NAME, results(rows, HEALING_SCENARIOS))
    out.details.append(table(rows))
    return out


def _quiet_daemons() -> None:
    """The daemons' info lines would bury the table: warnings and up only."""
    import logging

    import structlog

    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.WARNING))


def main(argv: Sequence[str] | None = None) -> int:
    _quiet_daemons()
    p = argparse.ArgumentParser(
        prog="python bench/recovery.py", description=__doc__.splitlines()[0]
    )
    p.add_argument(
        "--seeds", type=int, default=20, help="seeds per self-healing scenario (default 20)"
    )
    p.add_argument(
        "--check-seeds", type=int, default=3, help="seeds per paper scenario (default 3)"
    )
    p.add_argument("--scenarios", default=",".join(HEALING_SCENARIOS))
    p.add_argument(
        "--checks", default=",".join(CHECK_SCENARIOS), help="paper scenarios ('' for none)"
    )
    p.add_argument("--results", type=Path, default=None, help="also write the table to this file")
    p.add_argument(
        "--summaries", type=Path, default=None, help="write every run's summary.json here (JSON)"
    )
    p.add_argument(
        "--estimator",
        choices=("wca", "lobe"),
        default=None,
        help="scan.estimator for every relay (default: the scenario's, else relayd's default)",
    )
    p.add_argument(
        "--window", choices=("full", "adaptive"), default=None, help="scan.window, likewise"
    )
    args = p.parse_args(argv)
    scan = {
        k: v for k, v in (("estimator", args.estimator), ("window", args.window)) if v is not None
    }
    healing = [s for s in args.scenarios.split(",") if s]
    checks = [s for s in args.checks.split(",") if s]
    t0 = time.perf_counter()
    keep: dict[str, Any] = {}
    rows = measure(healing, args.seeds, log=sys.stderr, keep=keep, scan=scan)
    if args.summaries is not None:
        args.summaries.write_text(json.dumps(keep) + "\n", encoding="utf-8")
    rows.update(measure(checks, args.check_seeds, log=sys.stderr, keep=keep, scan=scan))
    if args.summaries is not None:
        args.summaries.write_text(json.dumps(keep) + "\n", encoding="utf-8")
    res = results(rows, healing)
    text = [
        table(rows),
        "",
        "| benchmark | figure | value | target | result | notes |",
        "|---|---|---|---|---|---|",
    ]
    text += [
        f"| {r.bench} | {r.figure} | {r.value_text()} | {r.target} | {r.verdict()} | {r.note} |"
        for r in res
    ]
    text.append(
        f"\n{args.seeds} seeds per self-healing scenario, {args.check_seeds} per paper scenario, "
        f"scan {scan or 'as configured'}, {time.perf_counter() - t0:.0f} s wall"
    )
    doc = "\n".join(text)
    print(doc)
    if args.results is not None:
        args.results.write_text(doc + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
