"""Every shipped scenario with `control.pursuit` = "trail" and "bearing" side by side.

For each scenario (its own relay count, at least 2 where it has them), each seed and
each pursuit, one `relayd sim` run in virtual time; per relay the reason it ended on
and its final gap to its own leader. A relay "ends on the link rule" when its last
reason is leader_near / rear_weak (or their adaptive forms) or it is still following
(driving, obstacle, leader_far_sonar, trail_head); anything else (avoiding, rejoining,
blocked, trail_blocked, leader_lost, leader_search) is counted against the pursuit.

    nice python bench/pursuit.py                           # every scenario, seeds 1-10
    python bench/pursuit.py --scenarios doorway u-trap --seeds 3
    python bench/pursuit.py --markdown > table.md          # the table in bench/RESULTS.md
"""

from __future__ import annotations

import argparse
import collections
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

PURSUITS = ("trail", "bearing")
#: Ending on the link rule or still following: what a relay should be doing at the end.
GOOD = frozenset(
    {"leader_near", "rear_weak", "driving", "obstacle", "leader_far_sonar", "trail_head"}
)


@dataclass(frozen=True, slots=True)
class Ending:
    scenario: str
    seed: int
    pursuit: str
    relay: str
    reason: str
    gap_m: float
    collisions: int

    @property
    def good(self) -> bool:
        return self.reason in GOOD


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


async def _one(scenario: str, seed: int, pursuit: str) -> list[Ending]:
    from relayd.sim.runner import SimRunner
    from relayd.sim.scenario import load_scenario

    sc = load_scenario(scenario)
    sc = sc.model_copy(update={"control": {**sc.control, **calibrated(sc), "pursuit": pursuit}})
    result = await SimRunner(sc, speed=None, seed=seed).run()
    last: dict[str, Any] = result.records[-1]
    return [
        Ending(
            scenario,
            seed,
            pursuit,
            r["name"],
            str(r["reason"]),
            float(r["gap_m"]),
            int(r["collisions"]),
        )
        for r in last["relays"]
    ]


def run(scenarios: Sequence[str], seeds: int) -> list[Ending]:
    from relayd.runtime import vtime
    from relayd.runtime.logsetup import StdStream, setup_logging

    setup_logging("error", "console", StdStream("stderr"))
    out: list[Ending] = []
    for scenario in scenarios:
        for seed in range(1, seeds + 1):
            for pursuit in PURSUITS:  # side by side, seed by seed
                got = vtime.run(_one(scenario, seed, pursuit))
                out += got
                print(
                    f"# {scenario} seed {seed} {pursuit}: "
                    + ", ".join(f"{e.relay} {e.reason} {e.gap_m:.1f} m" for e in got),
                    file=sys.stderr,
                    flush=True,
                )
    return out


def table(endings: Sequence[Ending]) -> str:
    by: dict[tuple[str, str], list[Ending]] = collections.defaultdict(list)
    for e in endings:
        by[(e.scenario, e.pursuit)].append(e)
    lines = [
        "| scenario | pursuit | relay-runs on the link rule | final reasons | mean final gap (m) |",
        "|---|---|---|---|---|",
    ]
    for scenario in sorted({e.scenario for e in endings}):
        for pursuit in PURSUITS:
            es = by.get((scenario, pursuit), [])
            if not es:
                continue
            good = sum(e.good for e in es)
            reasons = collections.Counter(e.reason for e in es)
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


def convoy_share(seeds: int, pursuit: str) -> float:
    """bench/followshare.py's convoy figure (the "within 5 m" close-following policy, the
    default estimator and window) with this pursuit: the mean share of time within 5 m."""
    from bench.followshare import POLICIES, policy_scenario, relay_shares, scenario_fit
    from relayd.runtime import vtime
    from relayd.runtime.logsetup import StdStream, setup_logging
    from relayd.sim.runner import SimRunner

    del scenario_fit  # the policy calibrates itself; imported to fail loudly if it moves
    setup_logging("error", "console", StdStream("stderr"))
    sc = policy_scenario("convoy", POLICIES[2], {"estimator": "lobe", "window": "adaptive"})
    sc = sc.model_copy(update={"control": {**sc.control, **calibrated(sc), "pursuit": pursuit}})
    shares = []
    for seed in range(1, seeds + 1):
        result = vtime.run(SimRunner(sc, speed=None, seed=seed).run())
        shares += [s.within for s in relay_shares(result.records)]
    return sum(shares) / len(shares)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="*", default=None)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--per-run", action="store_true", help="also print every relay-run")
    ap.add_argument(
        "--convoy-share",
        action="store_true",
        help="instead: bench/followshare.py's convoy share within 5 m, both pursuits",
    )
    args = ap.parse_args(argv)
    if args.convoy_share:
        for pursuit in PURSUITS:
            share = convoy_share(args.seeds, pursuit)
            print(f"convoy within 5 m, {pursuit}: {100 * share:.2f} % ({args.seeds} seeds)")
        return 0
    endings = run(args.scenarios or shipped(), args.seeds)
    print(table(endings))
    if args.per_run:
        for e in endings:
            print(f"{e.scenario},{e.seed},{e.pursuit},{e.relay},{e.reason},{e.gap_m:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
