"""Every shipped scenario with `control.pursuit` = "trail" and "bearing" side by side.

For each scenario (its own relay count, at least 2 where it has them), each seed and
each pursuit, one `relayd sim` run in virtual time; per relay the reason it ended on
and its final gap to its own leader. A relay "ends on the link rule" when its last
reason is one of relayd.core.vocab.LINK_RULE_ENDS: leader_near / rear_weak (or their
adaptive forms), or still following (driving, detour, leader_far_sonar, trail_head);
anything else (avoiding, rejoining, blocked, trail_blocked, leader_lost, leader_search)
is counted against the pursuit. "obstacle" (the paper's slow-down by a near echo) counts
only while the relay is closing on a leader within 3 m (0.3 m on in the last 3 s, its
gap not grown): one standing at a wall on it, or crawling along one, does not (summary.json's on_link_rule,
relayd.sim.summary.ended_on_rule). The table says how many ends counted so.

Each scenario runs with its own configuration (the project's defaults where it sets
nothing); `--calibrated` sets the path-loss keys as `relayd calibrate` would find them.
The runs go to `--jobs` worker processes (default 2, the machine's cores).

    nice python bench/pursuit.py                           # every scenario, seeds 1-10
    python bench/pursuit.py --scenarios doorway u-trap --seeds 3
"""

from __future__ import annotations

import argparse
import collections
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: The laws compared, each as its `[control]` keys over the scenario's own: the shipped
#: default (the paper's direct pursuit at the scan bearing, with the escape), the same
#: with the detour round the sonar map (`control.detour`), and the trail pursuit with it.
VARIANTS: dict[str, dict[str, object]] = {
    "default": {},
    "detour": {"detour": True},
    "trail": {"pursuit": "trail", "detour": True},
    "lane": {},  # [avoidance] keys only, below
    # The paper's law as it was: no push off a side wall, no slide along one, the
    # slow-down by the nearest echo wherever it is; the escape's lane change handing back
    # only beyond 1.2 m, every stop forgetting it, a lost leader stopping it, a block
    # held for good, a refused turn held, a jamb gone round, a graze backed from.
    "paper": {"side_keep_m": 0.0, "wall_slide_m": 0.0, "beside_speed_floor": 0.0},
    "nokeep": {},  # [avoidance] keys only, below
    "noround": {},  # [avoidance] keys only, below
}
#: Each variant's `[avoidance]` keys: "lane" is the escape leaving by the lane test.
AVOIDANCE: dict[str, dict[str, object]] = {
    "lane": {"leave_by_lane": True},
    "paper": {
        "lane_pass_margin_m": 0.0,
        "keep_episode_when_lost": False,
        "lost_manoeuvre_s": 0.0,
        "blocked_retry_s": 0.0,
        "unpin": False,
        "align_open_deg": 0.0,
        "beside_turn": False,
    },
    # The shipped configuration but every stop forgetting the escape.
    "nokeep": {"keep_episode_when_lost": False},
    # The shipped configuration but a lost leader stopping the escape's manoeuvre.
    "noround": {"lost_manoeuvre_s": 0.0},
}


def variant_of(sc: Any, variant: str, extra: Mapping[str, object]) -> Any:
    """The scenario with the variant's `[control]` keys (over `extra`) and `[avoidance]` keys."""
    return sc.model_copy(
        update={
            "control": {**sc.control, **extra, **VARIANTS[variant]},
            "avoidance": {**sc.avoidance, **AVOIDANCE.get(variant, {})},
        }
    )


PURSUITS = tuple(VARIANTS)


@dataclass(frozen=True, slots=True)
class Ending:
    scenario: str
    seed: int
    pursuit: str
    relay: str
    reason: str
    gap_m: float
    collisions: int
    #: summary.json's on_link_rule (relayd.sim.summary.ended_on_rule)
    on_rule: bool

    @property
    def good(self) -> bool:
        return self.on_rule


def calibrated(sc: Any) -> dict[str, float]:
    """The path-loss keys as `relayd calibrate` would find them for the scenario's radio (its
    L0 and n; sigma its shadowing with 3 dB for the walls and fading on top), as
    bench/followshare.py calibrates: the range model is the site's, not a default."""
    r = sc.radio_params()
    return {
        "pathloss_l0_dbm": float(r.l0_dbm),
        "pathloss_exponent": float(r.exponent),
        "pathloss_sigma_db": round(math.hypot(float(r.shadow_sigma_db), 3.0), 2),
    }


def shipped() -> list[str]:
    return sorted(p.stem for p in (ROOT / "relayd" / "sim" / "scenarios").glob("*.toml"))


async def _one(scenario: str, seed: int, pursuit: str, calibrate: bool) -> list[Ending]:
    from relayd.sim.runner import SimRunner
    from relayd.sim.scenario import load_scenario

    sc = load_scenario(scenario)
    keys = calibrated(sc) if calibrate else {}
    sc = variant_of(sc, pursuit, keys)
    result = await SimRunner(sc, speed=None, seed=seed).run()
    last: dict[str, Any] = result.records[-1]
    on_rule = {f["name"]: bool(f["on_link_rule"]) for f in result.summary["followers"]}
    return [
        Ending(
            scenario,
            seed,
            pursuit,
            r["name"],
            str(r["reason"]),
            float(r["gap_m"]),
            int(r["collisions"]),
            on_rule[r["name"]],
        )
        for r in last["relays"]
    ]


def _job(job: tuple[str, int, str, bool]) -> list[Ending]:
    from relayd.runtime import vtime
    from relayd.runtime.logsetup import StdStream, setup_logging

    setup_logging("error", "console", StdStream("stderr"))
    return vtime.run(_one(*job))


def run(
    scenarios: Sequence[str], seeds: int, calibrate: bool, jobs: int, variants: Sequence[str]
) -> list[Ending]:
    import concurrent.futures
    import multiprocessing

    todo = [
        (scenario, seed, pursuit, calibrate)
        for scenario in scenarios
        for seed in range(1, seeds + 1)
        for pursuit in variants  # side by side, seed by seed
    ]
    out: list[Ending] = []
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=ctx) as pool:
        for (scenario, seed, pursuit, _), got in zip(todo, pool.map(_job, todo), strict=True):
            out += got
            print(
                f"# {scenario} seed {seed} {pursuit}: "
                + ", ".join(f"{e.relay} {e.reason} {e.gap_m:.1f} m" for e in got),
                file=sys.stderr,
                flush=True,
            )
    return out


def _shown(e: Ending) -> str:
    """The end's reason, "obstacle (closing)" where summary.json counts it as following."""
    return f"{e.reason} (closing)" if e.good and e.reason == "obstacle" else e.reason


def table(endings: Sequence[Ending]) -> str:
    by: dict[tuple[str, str], list[Ending]] = collections.defaultdict(list)
    for e in endings:
        by[(e.scenario, e.pursuit)].append(e)
    lines = [
        "| scenario | law | relay-runs on the link rule | final reasons | mean final gap (m) |",
        "|---|---|---|---|---|",
    ]
    for scenario in sorted({e.scenario for e in endings}):
        for pursuit in PURSUITS:
            es = by.get((scenario, pursuit), [])
            if not es:
                continue
            good = sum(e.good for e in es)
            reasons = collections.Counter(_shown(e) for e in es)
            rs = ", ".join(f"{k} {v}" for k, v in sorted(reasons.items()))
            gap = sum(e.gap_m for e in es) / len(es)
            lines.append(f"| {scenario} | {pursuit} | {good}/{len(es)} | {rs} | {gap:.1f} |")
    for pursuit in PURSUITS:
        es = [e for e in endings if e.pursuit == pursuit]
        if es:
            lines.append(
                f"| **all** | {pursuit} | {sum(e.good for e in es)}/{len(es)} | | "
                f"{sum(e.gap_m for e in es) / len(es):.1f} |"
            )
    return "\n".join(lines)


def _share_job(job: tuple[str, int]) -> list[float]:
    """One seed of bench/followshare.py's convoy figure (the "within 5 m" close-following
    policy, the default estimator and window) under one variant: each relay's share."""
    from bench.followshare import POLICIES, policy_scenario, relay_shares
    from relayd.runtime import vtime
    from relayd.runtime.logsetup import StdStream, setup_logging
    from relayd.sim.runner import SimRunner

    variant, seed = job
    setup_logging("error", "console", StdStream("stderr"))
    sc = policy_scenario("convoy", POLICIES[2], {"estimator": "lobe", "window": "adaptive"})
    sc = variant_of(sc, variant, calibrated(sc))
    result = vtime.run(SimRunner(sc, speed=None, seed=seed).run())
    return [s.within for s in relay_shares(result.records)]


def convoy_share(seeds: int, variants: Sequence[str], jobs: int) -> dict[str, float]:
    """The mean share of time within 5 m of the leader over seeds 1..seeds, per variant."""
    import concurrent.futures
    import multiprocessing

    todo = [(v, seed) for v in variants for seed in range(1, seeds + 1)]
    got: dict[str, list[float]] = collections.defaultdict(list)
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=ctx) as pool:
        for (v, _), shares in zip(todo, pool.map(_share_job, todo), strict=True):
            got[v] += shares
    return {v: sum(x) / len(x) for v, x in got.items()}


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="*", default=None)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--per-run", action="store_true", help="also print every relay-run")
    ap.add_argument("--calibrated", action="store_true", help="path-loss keys from the radio")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes")
    ap.add_argument(
        "--variants", nargs="*", default=["default", "detour", "trail"], choices=PURSUITS
    )
    ap.add_argument(
        "--convoy-share",
        action="store_true",
        help="instead: bench/followshare.py's convoy share within 5 m, per variant",
    )
    args = ap.parse_args(argv)
    if args.convoy_share:
        for v, share in convoy_share(args.seeds, args.variants, args.jobs).items():
            print(f"convoy within 5 m, {v}: {100 * share:.2f} % ({args.seeds} seeds)")
        return 0
    endings = run(
        args.scenarios or shipped(), args.seeds, args.calibrated, args.jobs, args.variants
    )
    print(table(endings))
    if args.per_run:
        for e in endings:
            print(f"{e.scenario},{e.seed},{e.pursuit},{e.relay},{e.reason},{e.gap_m:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
