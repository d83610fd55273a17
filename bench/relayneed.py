"""How many relays a generated world needs by its own radio's link budget.

    python -m bench.relayneed [--worlds 40] [--kind office] [--dbm -60 --dbm -70 --dbm -82]

The generator keeps a world only when two relays are needed at the relays' own rear
limit (-60 dBm, relayd/sim/linkneed.py) and two are enough. This counts, per kind and
threshold, how many worlds the command center reaches at the person's goal directly (no
relay), with one relay somewhere on the route, with two, and only with more: at -60 dBm
every world must read "two"; the other thresholds show what the same buildings ask of a
link that must only stay up (-82 dBm, the slowest rate's sensitivity) or keep 36 Mbit/s
of PHY rate (-70 dBm). Local mean power between perfectly pointed antennas, no fading or
shadowing: the count the generator itself makes.
"""

from __future__ import annotations

import argparse

from relayd.sim.generate import KINDS, budget
from relayd.sim.linkneed import NEED_HOP_DBM, relays_needed
from relayd.sim.scenario import load_scenario

COLUMNS = ("no relay", "one relay", "two relays", "more")


def needs(kind: str, seed: int, thresholds_dbm: list[float]) -> list[int]:
    """Relays the world needs at each threshold (0, 1, 2, or 3 meaning more than two)."""
    sc = load_scenario(f"generated:{kind}:{seed}")
    power = budget(sc)
    route = [(w.x, w.y) for w in sc.leader.waypoints]
    cc = (sc.command_center.x, sc.command_center.y)
    return [relays_needed(power, cc, route, t) for t in thresholds_dbm]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--worlds", type=int, default=40)
    ap.add_argument("--kind", action="append", choices=KINDS, default=None)
    ap.add_argument("--dbm", action="append", type=float, default=None)
    args = ap.parse_args()
    thresholds = args.dbm or [NEED_HOP_DBM, -70.0, -82.0]
    print("| kind | worlds | threshold (dBm) | " + " | ".join(COLUMNS) + " |")
    print("|---|---|---|" + "---|" * len(COLUMNS))
    for kind in args.kind or list(KINDS):
        counts = [[0] * len(COLUMNS) for _ in thresholds]
        for seed in range(args.worlds):
            for k, n in enumerate(needs(kind, seed, thresholds)):
                counts[k][n] += 1
        for t, row in zip(thresholds, counts, strict=True):
            print(f"| {kind} | {args.worlds} | {t:.0f} | " + " | ".join(map(str, row)) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
