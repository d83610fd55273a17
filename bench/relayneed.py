"""How many relays a generated world needs by its own radio's link budget.

    python -m bench.relayneed [--worlds 40] [--kind office] [--dbm -82 --dbm -70]

The generator accepts a world when the person's route is at least 40 m long, a proxy for
"needs two relays". This checks the proxy against the world's radio model (the same
dominant-path model the runs use, local mean power between omnidirectional antennas, no
fading): per kind and threshold, how many worlds the command center reaches at the
person's goal directly (no relay), how many more one relay somewhere on the route joins
with both hops at or above the threshold (one relay), and the rest (two or more).
-82 dBm is the slowest rate's sensitivity (a hop that is up at all); -70 dBm leaves a
fading margin and about 24 Mbps of PHY rate.
"""

from __future__ import annotations

import argparse
import itertools
import math

from relayd.sim.generate import KINDS
from relayd.sim.scenario import load_scenario
from relayd.sim.world import World

Point = tuple[float, float]


def _along(route: list[Point], step_m: float = 1.0) -> list[Point]:
    pts: list[Point] = []
    for a, b in itertools.pairwise(route):
        k = max(1, int(math.dist(a, b) / step_m))
        pts += [(a[0] + (b[0] - a[0]) * i / k, a[1] + (b[1] - a[1]) * i / k) for i in range(k)]
    return pts + route[-1:]


def needs(kind: str, seed: int, thresholds_dbm: list[float]) -> list[int]:
    """Relays the world needs (0, 1 or 2 meaning two or more) at each threshold."""
    sc = load_scenario(f"generated:{kind}:{seed}")
    world = World(sc, 0)
    route = [(w.x, w.y) for w in sc.leader.waypoints]
    goal = route[-1]
    power = world.radio.mean_power_dbm
    direct = power(world.cc, goal)[0]
    one = max(min(power(world.cc, p)[0], power(p, goal)[0]) for p in _along(route))
    return [0 if direct >= t else 1 if one >= t else 2 for t in thresholds_dbm]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--worlds", type=int, default=40)
    ap.add_argument("--kind", action="append", choices=KINDS, default=None)
    ap.add_argument("--dbm", action="append", type=float, default=None)
    args = ap.parse_args()
    thresholds = args.dbm or [-82.0, -70.0]
    print("| kind | worlds | threshold (dBm) | no relay | one relay | two or more |")
    print("|---|---|---|---|---|---|")
    for kind in args.kind or list(KINDS):
        counts = [[0, 0, 0] for _ in thresholds]
        for seed in range(args.worlds):
            for k, n in enumerate(needs(kind, seed, thresholds)):
                counts[k][n] += 1
        for t, (c0, c1, c2) in zip(thresholds, counts, strict=True):
            print(f"| {kind} | {args.worlds} | {t:.0f} | {c0} | {c1} | {c2} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
