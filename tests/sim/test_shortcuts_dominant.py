"""The dominant-path radio's shortcuts give exactly, bit for bit, what they stand in for.

relayd/sim/dominant.py writes the sight-line test out over plain coordinates and costs
each end turn of a query once; a run must not change by a single bit for it
(bench/simspeed.py compares whole runs). Each is checked here against its definition:
`segments_intersect` for the sight line, the plain search over every chain for `best`.
"""

from __future__ import annotations

import math
import random

from hypothesis import given, settings
from hypothesis import strategies as st

from relayd.sim.dominant import (
    BentPath,
    CornerGraph,
    _clear,
    _turn_deg,
    turn_loss_db,
)
from relayd.sim.geometry import Point, Segment, segments_intersect
from relayd.sim.scenario import load_scenario

# Coordinates on a coarse grid as often as not: shared end points, collinear and
# axis-parallel walls, zero-length pieces, the cases where rounding could decide.
coord = st.one_of(st.integers(-6, 6).map(float), st.floats(-6.0, 6.0, allow_nan=False))
wall = st.tuples(coord, coord, coord, coord)


@settings(max_examples=300, deadline=None)
@given(p=st.tuples(coord, coord), q=st.tuples(coord, coord), walls=st.lists(wall, max_size=8))
def test_clear_is_no_wall_intersecting(
    p: Point, q: Point, walls: list[tuple[float, float, float, float]]
) -> None:
    want = not any(segments_intersect(p, q, (x1, y1), (x2, y2)) for x1, y1, x2, y2 in walls)
    assert _clear(p, q, walls) == want


def test_clear_counts_touching_and_collinear_walls() -> None:
    assert not _clear((0.0, 0.0), (2.0, 0.0), [(2.0, 0.0, 2.0, 3.0)])  # ends on its end
    assert not _clear((0.0, 0.0), (4.0, 0.0), [(2.0, 0.0, 2.0, 3.0)])  # grazes its end
    assert not _clear((0.0, 0.0), (4.0, 0.0), [(1.0, 0.0, 3.0, 0.0)])  # along it
    assert _clear((0.0, -1.0), (4.0, -1.0), [(2.0, 0.0, 2.0, 3.0)])  # passes below it


def best_by_definition(
    g: CornerGraph, a: Point, b: Point, va: list[int], vb: list[int]
) -> BentPath | None:
    """CornerGraph.best as the search defines it (every chain costed afresh)."""
    nodes, per90, k = g.nodes, g.per_90_db, 10.0 * g.exponent
    found: tuple[float, float, float, tuple[int, ...]] | None = None
    for i in va:
        ni = nodes[i]
        da = math.dist(a, ni)
        if i in vb:
            length = da + math.dist(ni, b)
            t = turn_loss_db(_turn_deg(a, ni, b), per90)
            cost = k * math.log10(max(length, 0.5)) + t
            if found is None or cost < found[0]:
                found = (cost, length, t, (i,))
        for j in vb:
            if j == i:
                continue
            nj = nodes[j]
            db = math.dist(nj, b)
            for c in g.chains[i].get(j, ()):
                length = da + c.length_m + db
                t = (
                    c.turns_db
                    + turn_loss_db(_turn_deg(a, ni, nodes[c.second]), per90)
                    + turn_loss_db(_turn_deg(nodes[c.before_last], nj, b), per90)
                )
                cost = k * math.log10(max(length, 0.5)) + t
                if found is None or cost < found[0]:
                    found = (cost, length, t, (i, c.second, c.before_last, j))
    if found is None:
        return None
    _, length, t, ids = found
    return BentPath(length, t, nodes[ids[0]], nodes[ids[-1]])


def test_visible_and_best_are_their_definitions_in_generated_worlds() -> None:
    rng = random.Random(11)
    bent = 0
    for name in ("generated:corridors:3", "generated:office:1"):
        sc = load_scenario(name)
        walls: list[Segment] = sc.wall_segments() + [
            s for b in sc.box_shapes() for s in b.segments()
        ]
        g = CornerGraph(walls, 10.0, 3.0)
        route = [(w.x, w.y) for w in sc.leader.waypoints]
        for _ in range(40):
            a, b = rng.choice(route), rng.choice(route)
            a = (a[0] + rng.uniform(-0.5, 0.5), a[1] + rng.uniform(-0.5, 0.5))
            b = (b[0] + rng.uniform(-0.5, 0.5), b[1] + rng.uniform(-0.5, 0.5))
            va, vb = g.visible(a), g.visible(b)
            assert va == [i for i in range(len(g.nodes)) if g._sees(i, a)]
            got = g.best(a, b, va, vb)
            assert got == best_by_definition(g, a, b, va, vb)
            bent += got is not None
    assert bent >= 40  # most of these pairs have a way round corners to compare
