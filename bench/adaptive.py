"""Adaptive vs fixed rear limits in the simulator, and `relayd calibrate`'s accuracy.

    python bench/adaptive.py                       # full: 10 seeds everywhere, ~140 runs, ~1.5 h on 2 cores
    python bench/adaptive.py --seeds 3 --jobs 2    # fewer seeds
    python bench/run.py --only adaptive            # the same, as part of the bench table

Three parts, side by side in one run:

1. **Calibration accuracy.** Synthetic straight drives (relayd/calibrate/synthetic.py)
   with known L0, n and sigma, recorded and read back as `relayd calibrate path-loss
   --from` reads them: the error of n and L0 over the seeds, with independent shadowing
   (the model's assumption) and with shadowing correlated over 2 m (a real corridor).
2. **`mixed`** (an open hall, then a dense corridor): the same seeds with
   `link_policy = "adaptive"` and with a range of fixed `threshold_b_dbm`, at the
   scenario's relay count. Per run: the minimum end-to-end throughput while the
   leader walks, the share of that time every hop carries `target_hop_mbps`, the
   seconds the chain was broken, whether the goal was reached, collisions.
3. **The other scenarios** with adaptive on and off: goal reached, link breaks,
   collisions, minimum throughput.

Every simulator run is on virtual time (deterministic for its seed). Runs go to
worker processes (`--jobs`, default 1: the machine is shared); each run's figures are
cached in `--cache` by (scenario, variant, seed), so an interrupted bench resumes.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.common import BenchOutput, Result

TARGET_MBPS = 10.0
FIXED_B = (-60.0, -63.0, -66.0, -69.0, -72.0)
OTHER_SCENARIOS = ("corridor", "convoy", "obstacle", "parking", "drift", "outdoor")
DEFAULT_CACHE = Path("/tmp/relayd-bench-adaptive")


# -- one simulator run ---------------------------------------------------------------------


def variants() -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {"adaptive": {"link_policy": "adaptive"}}
    for b in FIXED_B:
        out[f"fixed {b:g}"] = {"link_policy": "fixed", "threshold_b_dbm": b}
    return out


def scenario_with(name: str, control: dict[str, Any]) -> Any:
    """A shipped scenario with [control] keys replaced, validated like a file."""
    from relayd.sim.scenario import load_scenario, parse_scenario

    base = load_scenario(name)
    doc = base.model_dump()
    ctl = dict(doc.get("control") or {})
    ctl.update(control)
    if ctl.get("link_policy") == "adaptive":
        # Bounds that fit scenarios shipped without them (the paper's -40 dBm rear threshold).
        b = float(ctl.get("threshold_b_dbm", -60.0))
        ctl.setdefault("threshold_b_min_dbm", min(-78.0, b))
        ctl.setdefault("threshold_b_max_dbm", max(-55.0, b))
        ctl["threshold_b_max_dbm"] = min(
            ctl["threshold_b_max_dbm"], float(ctl.get("threshold_l_dbm", -30.0)) - 1
        )
    doc["control"] = ctl
    return parse_scenario(doc)


def metrics(
    records: Sequence[dict[str, Any]], summary: dict[str, Any], target: float
) -> dict[str, Any]:
    """The bench's figures from a trace: only while the leader walks (start to goal or end)."""
    walking = [r for r in records if r["leader"]["moving"]]
    if not walking:
        walking = list(records)
    dt = 0.1
    e2e = [r["e2e_mbps"] for r in walking]
    ok = [all(h["mbps"] >= target for h in r["hops"]) for r in walking]
    above = sum(ok)
    # The spells with a hop below target (a relay in a shadow): the longest one, and the
    # minimum over the rest of the walk, i.e. what the chain delivers with every hop at the target.
    longest = run = 0
    for good in ok:
        run = 0 if good else run + 1
        longest = max(longest, run)
    at_target = [x for x, good in zip(e2e, ok, strict=True) if good]
    return {
        # Per trace record (10 Hz): one record with a hop in a shadow sets it.
        "min_e2e_mbps": min(e2e) if e2e else 0.0,
        "min_e2e_at_target_mbps": min(at_target) if at_target else 0.0,
        "below_target_s": round((len(walking) - above) * dt, 1),
        "longest_below_s": round(longest * dt, 1),
        "mean_e2e_mbps": statistics.fmean(e2e) if e2e else 0.0,
        "share_above_target": above / len(walking) if walking else 0.0,
        "down_s": round(sum(dt for r in records if r["broken"]), 1),
        "goal_reached": bool(summary["goal_reached"]),
        "collisions": int(summary["collisions"]),
        "walk_s": round(len(walking) * dt, 1),
        "final_x": [r["x"] for r in records[-1]["relays"]] if records else [],
        "final_thr_b": [r.get("threshold_b_dbm") for r in records[-1]["relays"]] if records else [],
    }


def run_sim(scenario_name: str, variant: str, control: dict[str, Any], seed: int) -> dict[str, Any]:
    from relayd.runtime import vtime
    from relayd.runtime.logsetup import setup_logging
    from relayd.sim.runner import SimRunner

    setup_logging("error", "console")
    sc = scenario_with(scenario_name, control)
    t0 = time.perf_counter()
    result = vtime.run(SimRunner(sc, speed=None, seed=seed).run())
    target = float(sc.control.get("target_hop_mbps", TARGET_MBPS))
    out = metrics(result.records, result.summary, target)
    out.update(
        scenario=scenario_name,
        variant=variant,
        seed=seed,
        wall_s=round(time.perf_counter() - t0, 1),
    )
    return out


def _cached_run(
    cache: Path, scenario_name: str, variant: str, control: dict[str, Any], seed: int
) -> dict[str, Any]:
    key = cache / f"{scenario_name}--{variant.replace(' ', '_')}--{seed}.json"
    if key.exists():
        return dict(json.loads(key.read_text()))
    out = run_sim(scenario_name, variant, control, seed)
    cache.mkdir(parents=True, exist_ok=True)
    key.write_text(json.dumps(out))
    return out


def run_grid(
    jobs: list[tuple[str, str, dict[str, Any], int]],
    cache: Path,
    workers: int,
    cached_only: bool = False,
) -> list[dict[str, Any]]:
    if cached_only:  # what an interrupted bench finished
        found = [cache / f"{n}--{v.replace(' ', '_')}--{s}.json" for n, v, _c, s in jobs]
        return [dict(json.loads(f.read_text())) for f in found if f.exists()]
    if workers <= 1:
        return [_cached_run(cache, *j) for j in jobs]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(_cached_run, [cache] * len(jobs), *zip(*jobs, strict=True)))


# -- calibration accuracy ------------------------------------------------------------------


def calibration_rows(seeds: int, tmp: Path) -> tuple[list[dict[str, Any]], list[str]]:
    import random

    done = tmp / f"rows-{seeds}.json"
    if done.exists():
        return list(json.loads(done.read_text())), []

    from relayd.calibrate.fit import fit_path_loss
    from relayd.calibrate.sources import NEAR_M, readings_from_recording
    from relayd.calibrate.synthetic import drive_messages, write_recording

    rows = []
    for corr in (None, 2.0):
        for seed in range(seeds):
            rng = random.Random(7000 + seed)
            l0, n, sigma = rng.uniform(-25, -10), rng.uniform(2.0, 4.0), rng.uniform(2.0, 6.0)
            path = tmp / f"cal-{corr}-{seed}.mcap"
            # The guided drive from 1 m: a third of 0.15 m/s to 4 m, then 0.15 m/s to 40 m, a poll
            # every 0.5 s: ~600 readings, as `--drive` gives.
            write_recording(
                path,
                drive_messages(
                    l0_dbm=l0,
                    n=n,
                    sigma_db=sigma,
                    seed=seed,
                    far_m=40.0,
                    corr_m=corr,
                    poll_s=0.5,
                    near_m=NEAR_M,
                ),
            )
            readings = readings_from_recording(path)
            fit = fit_path_loss(
                [r.distance_m for r in readings],
                [r.rssi_dbm for r in readings],
                seed=seed,
                resamples=200,
            )
            rows.append(
                {
                    "corr_m": corr,
                    "seed": seed,
                    "n_err": fit.n - n,
                    "l0_err": fit.l0_dbm - l0,
                    "sigma_err": fit.sigma_db - sigma,
                    "n_in_ci": fit.n_ci.low <= n <= fit.n_ci.high,
                    "l0_in_ci": fit.l0_ci.low <= l0 <= fit.l0_ci.high,
                    "points": fit.points,
                }
            )
    done.write_text(json.dumps(rows))
    return rows, []


# -- the report ----------------------------------------------------------------------------


def _mean(values: Sequence[float]) -> float:
    return statistics.fmean(values) if values else float("nan")


def summarize_variant(rows: list[dict[str, Any]]) -> dict[str, float]:
    return {
        "min_e2e_worst": min(r["min_e2e_mbps"] for r in rows),
        "min_e2e_mean": _mean([r["min_e2e_mbps"] for r in rows]),
        "share_mean": _mean([r["share_above_target"] for r in rows]),
        "down_mean": _mean([r["down_s"] for r in rows]),
        "goal": sum(r["goal_reached"] for r in rows),
        "collisions": sum(r["collisions"] for r in rows),
        "runs": len(rows),
    }


def parking_table(results: list[dict[str, Any]], seeds: int) -> str:
    """Parking per seed: where the minimum comes from (a spell in a shadow, or the hops at the target)."""
    lines = [
        "parking per seed (min e2e / min e2e with every hop at the target, Mbit/s / share >= target / "
        "time below target, longest spell, s / link-down s):",
        "",
        "| seed | fixed | adaptive |",
        "|---|---|---|",
    ]

    def cell(r: dict[str, Any] | None) -> str:
        if r is None:
            return "not run"
        if "below_target_s" not in r:
            return f"{r['min_e2e_mbps']:.1f} / - / {r['share_above_target']:.1%} / - / {r['down_s']:.0f}"
        return (
            f"{r['min_e2e_mbps']:.1f} / {r['min_e2e_at_target_mbps']:.1f} / {r['share_above_target']:.1%} / "
            f"{r['below_target_s']:.1f}, {r['longest_below_s']:.1f} / {r['down_s']:.0f}"
        )

    for s in range(1, seeds + 1):
        found = {
            v: next(
                (
                    r
                    for r in results
                    if r["scenario"] == "parking" and r["variant"] == v and r["seed"] == s
                ),
                None,
            )
            for v in ("fixed", "adaptive")
        }
        lines.append(f"| {s} | {cell(found['fixed'])} | {cell(found['adaptive'])} |")
    means = []
    for v in ("fixed", "adaptive"):
        rows = [
            r
            for r in results
            if r["scenario"] == "parking" and r["variant"] == v and "below_target_s" in r
        ]
        means.append(
            "not run"
            if not rows
            else f"{_mean([r['min_e2e_mbps'] for r in rows]):.1f} / "
            f"{_mean([r['min_e2e_at_target_mbps'] for r in rows]):.1f} / "
            f"{_mean([r['share_above_target'] for r in rows]):.1%} / "
            f"{_mean([r['below_target_s'] for r in rows]):.1f}, {_mean([r['longest_below_s'] for r in rows]):.1f}"
            f" / {_mean([r['down_s'] for r in rows]):.1f}"
        )
    lines.append(f"| mean | {means[0]} | {means[1]} |")
    return "\n".join(lines)


def run(
    quick: bool = False,
    *,
    seeds: int | None = None,
    jobs: int = 1,
    cache: Path = DEFAULT_CACHE,
    others: Sequence[str] = OTHER_SCENARIOS,
    other_seeds: int | None = None,
    cached_only: bool = False,
) -> BenchOutput:
    t0 = time.perf_counter()
    n_seeds = seeds if seeds is not None else (2 if quick else 10)
    n_other = other_seeds if other_seeds is not None else (1 if quick else 10)
    out = BenchOutput("adaptive")
    (cache / "cal").mkdir(parents=True, exist_ok=True)
    cal, _ = calibration_rows(3 if quick else max(10, n_seeds), cache / "cal")
    for corr in (None, 2.0):
        rows = [r for r in cal if r["corr_m"] == corr]
        label = "independent shadowing" if corr is None else "shadowing correlated over 2 m"
        n_max = max(abs(r["n_err"]) for r in rows)
        l0_max = max(abs(r["l0_err"]) for r in rows)
        judged = corr is None
        out.results.append(
            Result(
                "adaptive",
                f"calibrate: worst |n error|, {label}, {len(rows)} seeds",
                n_max,
                "",
                "<= 0.2" if judged else "",
                (n_max <= 0.2) if judged else None,
            )
        )
        out.results.append(
            Result(
                "adaptive",
                f"calibrate: worst |L0 error|, {label}",
                l0_max,
                "dB",
                "<= 2 dB" if judged else "",
                (l0_max <= 2.0) if judged else None,
            )
        )
        cover = _mean([1.0 if r["n_in_ci"] else 0.0 for r in rows])
        out.results.append(
            Result(
                "adaptive",
                f"calibrate: share of seeds whose 95 % CI holds the true n, {label}",
                cover * 100,
                "%",
            )
        )
        out.details.append(
            f"calibration, {label}: n errors "
            + ", ".join(f"{r['n_err']:+.2f}" for r in rows)
            + "; L0 errors "
            + ", ".join(f"{r['l0_err']:+.1f}" for r in rows)
        )

    grid = [("mixed", v, c, s) for v, c in variants().items() for s in range(1, n_seeds + 1)]
    for name in others:
        for v in ("adaptive", "fixed"):
            grid += [(name, v, {"link_policy": v}, s) for s in range(1, n_other + 1)]
    results = run_grid(grid, cache, jobs, cached_only)

    mixed = {
        v: summarize_variant(rows)
        for v in variants()
        if (rows := [r for r in results if r["scenario"] == "mixed" and r["variant"] == v])
    }
    if "adaptive" not in mixed or len(mixed) < 2:
        out.details.append("mixed: no finished runs to compare")
        out.wall_s = time.perf_counter() - t0
        return out
    fixed_names = [v for v in mixed if v != "adaptive"]
    best = max(fixed_names, key=lambda v: (mixed[v]["share_mean"], mixed[v]["min_e2e_mean"]))
    a = mixed["adaptive"]
    lines = [
        f"| mixed, up to {n_seeds} seeds | worst min e2e (Mbit/s) | mean min e2e | mean share of walk >= "
        f"{TARGET_MBPS:g} Mbit/s on every hop | mean link-down (s) | goal reached | collisions |",
        "|---|---|---|---|---|---|---|",
    ]
    for v, m in mixed.items():
        lines.append(
            f"| {v} | {m['min_e2e_worst']:.1f} | {m['min_e2e_mean']:.1f} | {m['share_mean']:.1%} | "
            f"{m['down_mean']:.1f} | {m['goal']}/{m['runs']} | {m['collisions']} |"
        )
    out.details.append("\n".join(lines))
    out.results.append(
        Result(
            "adaptive",
            f"mixed: share of walk >= target, adaptive vs best fixed ({best})",
            a["share_mean"] * 100,
            "%",
            f"> {mixed[best]['share_mean']:.1%}",
            a["share_mean"] > mixed[best]["share_mean"],
        )
    )
    out.results.append(
        Result(
            "adaptive",
            f"mixed: mean min e2e, adaptive vs best fixed ({best})",
            a["min_e2e_mean"],
            "Mbit/s",
            f">= {mixed[best]['min_e2e_mean']:.1f}",
            a["min_e2e_mean"] >= mixed[best]["min_e2e_mean"],
        )
    )
    out.results.append(
        Result(
            "adaptive",
            f"mixed: mean link-down, adaptive vs best fixed ({best})",
            a["down_mean"],
            "s",
            f"<= {mixed[best]['down_mean']:.1f}",
            a["down_mean"] <= mixed[best]["down_mean"],
        )
    )
    per_seed = ["| seed | " + " | ".join(mixed) + " |", "|---|" + "---|" * len(mixed)]
    for s in range(1, n_seeds + 1):
        cells = []
        for v in mixed:
            found = [
                r
                for r in results
                if r["scenario"] == "mixed" and r["variant"] == v and r["seed"] == s
            ]
            cells.append(
                f"{found[0]['min_e2e_mbps']:.1f} / {found[0]['share_above_target']:.0%} / "
                f"{found[0]['down_s']:.0f}"
                if found
                else "not run"
            )
        per_seed.append(f"| {s} | " + " | ".join(cells) + " |")
    out.details.append(
        "mixed per seed (min e2e Mbit/s / share >= target / link-down s):\n\n" + "\n".join(per_seed)
    )
    if "parking" in others:
        out.details.append(parking_table(results, n_other))

    other_lines = [
        "| scenario | policy | goal reached | runs with a break | mean link-down (s) | worst min e2e | "
        "mean min e2e | mean share >= target | collisions |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name in others:
        for v in ("fixed", "adaptive"):
            rows = [r for r in results if r["scenario"] == name and r["variant"] == v]
            if not rows:
                continue
            m = summarize_variant(rows)
            breaks = sum(1 for r in rows if r["down_s"] > 0)
            other_lines.append(
                f"| {name} | {v} | {m['goal']}/{m['runs']} | {breaks} | {m['down_mean']:.1f} | "
                f"{m['min_e2e_worst']:.1f} | {m['min_e2e_mean']:.1f} | {m['share_mean']:.1%} | "
                f"{m['collisions']} |"
            )
        fx = [r for r in results if r["scenario"] == name and r["variant"] == "fixed"]
        ad = [r for r in results if r["scenario"] == name and r["variant"] == "adaptive"]
        if fx and ad:
            # Holds: as many goals, no more collisions, no more runs with a broken chain, and
            # the share of the walk at the target no more than 2 points below fixed's.
            share_ad = _mean([r["share_above_target"] for r in ad])
            share_fx = _mean([r["share_above_target"] for r in fx])
            held = (
                sum(r["goal_reached"] for r in ad) >= sum(r["goal_reached"] for r in fx)
                and sum(r["collisions"] for r in ad) <= sum(r["collisions"] for r in fx)
                and sum(r["down_s"] > 0 for r in ad) <= sum(r["down_s"] > 0 for r in fx)
                and share_ad >= share_fx - 0.02
            )
            out.results.append(
                Result(
                    "adaptive",
                    f"{name}: adaptive holds (goal, collisions, breaks, share >= "
                    f"target), {len(ad)} seeds",
                    share_ad * 100,
                    "%",
                    f"holds, share >= {(share_fx - 0.02):.1%}",
                    held,
                )
            )
    out.details.append("\n".join(other_lines))
    out.wall_s = time.perf_counter() - t0
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--other-seeds", type=int, default=10)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    ap.add_argument(
        "--others", default=",".join(OTHER_SCENARIOS), help="comma-separated; empty for none"
    )
    ap.add_argument("--quick", action="store_true")
    ap.add_argument(
        "--report-only", action="store_true", help="summarize the cached runs, run nothing new"
    )
    args = ap.parse_args(argv)
    others = [o for o in args.others.split(",") if o]
    out = run(
        args.quick,
        seeds=args.seeds,
        jobs=args.jobs,
        cache=args.cache,
        others=others,
        other_seeds=args.other_seeds,
        cached_only=args.report_only,
    )
    for r in out.results:
        print(f"| {r.figure} | {r.value_text()} | {r.target} | {r.verdict()} |")
    for d in out.details:
        print()
        print(d)
    print(f"\nwall {out.wall_s:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
