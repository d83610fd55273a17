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

Relays are tried at points 1-2 m apart along the route, relay 2 no further along it than
relay 1 (a convoy keeps its order), with perfectly pointed antennas (no pointing loss) and
no fading or shadowing: the building's own budget, the same for every run seed. A world
that needs two by this count is not held by one relay at any of those points; one that
needs three is not held by two, so failing it would say little about the convoy. The
person's own hop (to relay 1, or to the command center) is held to the same -60 dBm: on
the robots that hop is the leader's, which `threshold_l_dbm` governs, but a kept link
needs it as much as the others.

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
    """Points along the route: each leg's start, then evenly along it at least `step_m`
    and less than twice that apart (a 1.9 m leg gives its start only), and the route's end."""
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
    if not route:
        raise ValueError("relays_needed: the route has no points")
    goal = route[-1]
    if power(cc, goal) >= hop_dbm:
        return 0
    pts = along(route)
    # Where each end of the chain can stand: relay 2 (behind, by the command center) and
    # relay 1 (ahead, by the goal), as indices along the route.
    behind = [i for i, p in enumerate(pts) if power(cc, p) >= hop_dbm]
    ahead = [j for j, p in enumerate(pts) if power(p, goal) >= hop_dbm]
    if set(behind) & set(ahead):
        return 1
    if most < 2:
        return 2
    # A convoy keeps its order: relay 2 stands no further along the route than relay 1.
    # Nearest pairs first, the likeliest to hold, so an accepted world is found after a
    # few queries; a refused one costs them all.
    pairs = sorted(((i, j) for i in behind for j in ahead if i <= j), key=lambda ij: ij[1] - ij[0])
    if any(power(pts[i], pts[j]) >= hop_dbm for i, j in pairs):
        return 2
    return MORE
