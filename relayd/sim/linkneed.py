"""How many relays a world needs, by its own radio's link budget.

The floor-plan generator (relayd/sim/generate.py) accepts a world only when two relays
are needed to keep the link to the person at the end of the route, and two are enough.
"Keep the link" is the rule the relays themselves keep: a relay stops when the hop behind
it fades to `threshold_b_dbm` (the shipped default, -60 dBm; docs/CONTROL.md 5), so a
hop is kept when its local-mean power is at or above that. A world needs

- no relay when the command center hears the goal at the threshold,
- one when a single relay somewhere on the person's route holds both its hops there,
- two when one cannot but some two on the route hold all three hops,
- more (returned as 3) otherwise.

Relays are placed anywhere on the route (every metre), with perfectly pointed antennas
(no pointing loss) and no fading or shadowing: the building's own budget, the same for
every run seed, and the most a convoy could get from it. A world that needs two by this
count cannot be held with one however well the relay is placed; one that needs three
could not be held by two, so failing it would say nothing about the convoy.

Pure: it takes the radio's power function, so the tests give it a hand-made one.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence

from relayd.config.model import ControlSettings

Point = tuple[float, float]
#: Local-mean power (dBm) of the link between two points.
PowerFn = Callable[[Point, Point], float]

#: The threshold a kept hop meets: the relays' own rear limit as shipped.
NEED_HOP_DBM: float = float(ControlSettings.model_fields["threshold_b_dbm"].default)
#: More than two relays (the generator refuses such a world).
MORE = 3


def along(route: Sequence[Point], step_m: float = 1.0) -> list[Point]:
    """The route's points every `step_m` (each leg's start, then evenly along it), and its end."""
    pts: list[Point] = []
    for a, b in itertools.pairwise(route):
        k = max(1, int(math.dist(a, b) / step_m))
        pts += [(a[0] + (b[0] - a[0]) * i / k, a[1] + (b[1] - a[1]) * i / k) for i in range(k)]
    return pts + list(route[-1:])


def relays_needed(
    power: PowerFn,
    cc: Point,
    route: Sequence[Point],
    hop_dbm: float = NEED_HOP_DBM,
    most: int = 2,
) -> int:
    """Relays needed to hold every hop from `cc` to the route's end at `hop_dbm` (0-2, or
    MORE), relays standing on the route; with `most` = 1 it stops at "more than one"
    (returned as 2) without the search for a pair."""
    goal = route[-1]
    if power(cc, goal) >= hop_dbm:
        return 0
    pts = along(route)
    # The points each end of the chain reaches on its own: relay 2's (behind) and relay 1's.
    near_cc = [p for p in pts if power(cc, p) >= hop_dbm]
    near_goal = [p for p in pts if power(p, goal) >= hop_dbm]
    if set(near_cc) & set(near_goal):
        return 1
    if most < 2:
        return 2
    # Nearest pairs first (relay 2 far along, relay 1 early): the likeliest to hold, so an
    # accepted world is found after a few queries; a refused one costs them all.
    pairs = sorted(itertools.product(near_cc, near_goal), key=lambda pq: math.dist(pq[0], pq[1]))
    if any(power(p, q) >= hop_dbm for p, q in pairs):
        return 2
    return MORE
