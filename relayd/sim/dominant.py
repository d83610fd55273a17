"""Dominant paths: the radio's way round corners and through doorways (`[radio] model`).

The wall-count model charges every wall on the straight line between two antennas. In a
building the strongest signal often takes another way: down a corridor, round its
corner, through a doorway. The dominant path model of Wölfle and Landstorfer (docs/
SIMULATOR.md, "Radio that turns corners") keeps only the strongest path between the two
antennas and charges it for its unfolded length and for every turn it takes, more for a
sharper turn. Here the candidates are the straight path through the walls (the
wall-count model) and the best path that bends at corners and door jambs and crosses no
wall at all; the stronger of the two wins.

What is precomputed once per set of walls (`CornerGraph`): the points a path may bend
at (a little way off every free wall end and every convex wall corner), which of them see
each other, and for every ordered pair the best chain of bends between them (a
Dijkstra search over (node, previous node) states, so each turn's angle is known). The
search follows only lines tangent to the corners at both ends and bends that wrap their
corner, as a taut string would: for points on corners themselves the others never carry
a best path, and leaving them out makes a hall of pillars' graph several times cheaper.
Bend points sit 5 cm off their corners, so now and then (a line that skims a second
corner, a box against a door jamb) the best path was one of the others and the search
takes the next best: tests/sim/test_dominant.py bounds how often and by how much. A
query then only finds which nodes each end sees and joins the two ends to the
precomputed chains, exactly costing the turns at the first and last node.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from dataclasses import dataclass

from relayd.sim.geometry import Point, Segment

#: How far off a wall end or corner a bend point sits (clear of the wall it turns round).
NODE_OFFSET_M = 0.05
#: Chains kept per (first node, last node) pair, each ending in a different previous node.
LABELS_PER_PAIR = 3
#: Chains whose inner bends cost more than this are not searched further (four right
#: angles at the default 10 dB: the straight path through a few walls is stronger).
MAX_INNER_TURNS_DB = 40.0
_SLACK = 1e-9
#: Bend points sit NODE_OFFSET_M off their corners, so a best path may turn a hair the
#: wrong way at one, or leave it a hair inside its walls' angle: `_wraps` lets turns of
#: about 0.6 degrees the wrong way through, `_tangent` lines about 3 degrees inside (the
#: sines). The pruning is still not exact everywhere (`CornerGraph._tangent`).
WRAP_SLACK = 0.01
TANGENT_SLACK = 0.05
#: CornerGraph._longest's margin (relative): far above the rounding of log10 and of the
#: power, so a chain it passes over costs more than the best path, never the same.
LONGEST_SLACK = 1e-9
#: segments_intersect's touching tolerance (relayd/sim/geometry.py), written out in _clear.
_TOUCH = 1e-12


def turn_loss_db(turn_deg: float, per_90_db: float) -> float:
    """Loss of one bend: proportional to how far the path turns (0 straight on, 2x at a U-turn)."""
    return per_90_db * abs(turn_deg) / 90.0


def _turn_deg(a: Point, b: Point, c: Point) -> float:
    """How far the path a -> b -> c turns at b (0 straight on, 180 back on itself)."""
    ux, uy = b[0] - a[0], b[1] - a[1]
    vx, vy = c[0] - b[0], c[1] - b[1]
    nu, nv = math.hypot(ux, uy), math.hypot(vx, vy)
    if nu < 1e-12 or nv < 1e-12:
        return 0.0
    cos = max(-1.0, min(1.0, (ux * vx + uy * vy) / (nu * nv)))
    return math.degrees(math.acos(cos))


def _on_interior(p: Point, s: Segment) -> bool:
    """True if p lies on s away from its ends (a wall ending against another: a T joint)."""
    ex, ey = s.x2 - s.x1, s.y2 - s.y1
    n2 = ex * ex + ey * ey
    if n2 < 1e-18:
        return False
    u = ((p[0] - s.x1) * ex + (p[1] - s.y1) * ey) / n2
    if u <= 1e-6 or u >= 1 - 1e-6:
        return False
    return math.hypot(p[0] - s.x1 - u * ex, p[1] - s.y1 - u * ey) < 1e-6


def bend_points(walls: Sequence[Segment], offset_m: float = NODE_OFFSET_M) -> list[Point]:
    """Where a path may bend: just past every free wall end (a door jamb, the end of a
    partition) and just outside every convex corner (where two walls meet at an angle, on
    the side of the larger angle). Ends that butt against another wall, junctions of three
    or more walls and straight joints are no bend points."""
    return [p for p, _ in bend_corners(walls, offset_m)]


#: A bend point's corner: the wall end it bends round and the walls' directions from it.
Corner = tuple[Point, tuple[tuple[float, float], ...]]


def bend_corners(
    walls: Sequence[Segment], offset_m: float = NODE_OFFSET_M
) -> list[tuple[Point, Corner]]:
    """`bend_points`, each with the corner it sits off (what a path bending there wraps)."""
    ends: dict[tuple[float, float], list[tuple[float, float]]] = {}
    for s in walls:
        length = s.length_m
        if length < 1e-9:
            continue
        ux, uy = (s.x2 - s.x1) / length, (s.y2 - s.y1) / length
        ends.setdefault((round(s.x1, 9), round(s.y1, 9)), []).append((ux, uy))
        ends.setdefault((round(s.x2, 9), round(s.y2, 9)), []).append((-ux, -uy))
    out: list[tuple[Point, Corner]] = []
    for p, dirs in ends.items():
        if len(dirs) == 1:
            if any(_on_interior(p, s) for s in walls):
                continue
            (ux, uy) = dirs[0]
            out.append(((p[0] - offset_m * ux, p[1] - offset_m * uy), (p, tuple(dirs))))
        elif len(dirs) == 2:
            (ax, ay), (bx, by) = dirs
            if abs(ax * by - ay * bx) < 1e-6:
                continue  # straight on (or a wall folded back on itself)
            mx, my = ax + bx, ay + by
            n = math.hypot(mx, my)
            out.append(((p[0] - offset_m * mx / n, p[1] - offset_m * my / n), (p, tuple(dirs))))
    return sorted(out)


#: A wall as its end points' coordinates (x1, y1, x2, y2): what the sight-line test reads.
WallXY = tuple[float, float, float, float]


def _clear(p: Point, q: Point, walls: Sequence[WallXY]) -> bool:
    """True if the straight line p-q touches no wall.

    `segments_intersect(p, q, wall's ends)` for each wall, written out (its four
    orientations and its touching tests, the same operations on the same floats, so the
    same answers: tests/sim/test_dominant.py checks it against it), because every bend
    point runs it for every new antenna position.
    """
    px, py = p
    qx, qy = q
    x0, x1 = min(px, qx) - _SLACK, max(px, qx) + _SLACK
    y0, y1 = min(py, qy) - _SLACK, max(py, qy) + _SLACK
    ex, ey = qx - px, qy - py
    for sx1, sy1, sx2, sy2 in walls:
        if (
            (sx1 < x0 and sx2 < x0)
            or (sx1 > x1 and sx2 > x1)
            or (sy1 < y0 and sy2 < y0)
            or (sy1 > y1 and sy2 > y1)
        ):
            continue
        fx, fy = sx2 - sx1, sy2 - sy1
        d1 = fx * (py - sy1) - fy * (px - sx1)
        d2 = fx * (qy - sy1) - fy * (qx - sx1)
        d3 = ex * (sy1 - py) - ey * (sx1 - px)
        d4 = ex * (sy2 - py) - ey * (sx2 - px)
        if (
            (d1 > 0) != (d2 > 0)
            and d1 != 0
            and d2 != 0
            and (d3 > 0) != (d4 > 0)
            and d3 != 0
            and d4 != 0
        ):
            return False
        if (
            abs(d1) < _TOUCH
            and min(sx1, sx2) - _TOUCH <= px <= max(sx1, sx2) + _TOUCH
            and min(sy1, sy2) - _TOUCH <= py <= max(sy1, sy2) + _TOUCH
        ) or (
            abs(d2) < _TOUCH
            and min(sx1, sx2) - _TOUCH <= qx <= max(sx1, sx2) + _TOUCH
            and min(sy1, sy2) - _TOUCH <= qy <= max(sy1, sy2) + _TOUCH
        ):
            return False
        if (
            abs(d3) < _TOUCH
            and min(px, qx) - _TOUCH <= sx1 <= max(px, qx) + _TOUCH
            and min(py, qy) - _TOUCH <= sy1 <= max(py, qy) + _TOUCH
        ) or (
            abs(d4) < _TOUCH
            and min(px, qx) - _TOUCH <= sx2 <= max(px, qx) + _TOUCH
            and min(py, qy) - _TOUCH <= sy2 <= max(py, qy) + _TOUCH
        ):
            return False
    return True


#: Sectors of a bend point's view: a line from it lies in one, and only the walls that
#: reach into that sector can cross the line.
SECTORS = 64
_SECTOR = 2 * math.pi / SECTORS


def _sectors(node: Point, walls: Sequence[Segment]) -> list[list[WallXY]]:
    """The walls reaching into each sector round `node` (one sector of slack each side)."""
    out: list[list[WallXY]] = [[] for _ in range(SECTORS)]
    x, y = node
    for w in walls:
        a1 = math.atan2(w.y1 - y, w.x1 - x)
        a2 = math.atan2(w.y2 - y, w.x2 - x)
        span = math.remainder(a2 - a1, 2 * math.pi)
        start = a1 if span >= 0 else a2
        k0 = math.floor((start + math.pi) / _SECTOR) - 1
        k1 = math.floor((start + abs(span) + math.pi) / _SECTOR) + 1
        for k in range(k0, k1 + 1):
            out[k % SECTORS].append((w.x1, w.y1, w.x2, w.y2))
    return out


@dataclass(frozen=True, slots=True)
class Chain:
    """A precomputed chain of bends from node i to node j: its length, the loss of its
    inner turns, the node after i (fixes the turn at i) and the node before j."""

    length_m: float
    turns_db: float
    second: int
    before_last: int


@dataclass(frozen=True, slots=True)
class BentPath:
    """The best indirect path between two points: unfolded length, turn losses, and its
    first and last bends (the directions it leaves one end and reaches the other)."""

    length_m: float
    turns_db: float
    first: Point
    last: Point


class CornerGraph:
    """Bend points of one set of walls, which see which, and the best chains between them."""

    def __init__(self, walls: Sequence[Segment], per_90_db: float, exponent: float = 3.0) -> None:
        self.walls = tuple(walls)
        self.per_90_db = per_90_db
        self.exponent = exponent
        corners = bend_corners(self.walls)
        self.nodes = [p for p, _ in corners]
        #: Unit vector from each bend point to the corner it wraps.
        self._to_corner = [
            ((cx - x) / NODE_OFFSET_M, (cy - y) / NODE_OFFSET_M)
            for (x, y), ((cx, cy), _) in corners
        ]
        #: Directions of each corner's walls, from the corner.
        self._walls_at = [dirs for _, (_, dirs) in corners]
        n = len(self.nodes)
        self._sectors = [_sectors(node, self.walls) for node in self.nodes]
        self.sees: list[list[int]] = [[] for _ in range(n)]
        self._dist: dict[tuple[int, int], float] = {}
        self._unit: dict[tuple[int, int], tuple[float, float]] = {}
        self._next: dict[tuple[int, int], list[tuple[int, float, float]]] = {}
        for i in range(n):
            for j in range(i + 1, n):
                if self._tangent(i, j) and self._tangent(j, i) and self._sees(i, self.nodes[j]):
                    self.sees[i].append(j)
                    self.sees[j].append(i)
                    (xi, yi), (xj, yj) = self.nodes[i], self.nodes[j]
                    d = math.hypot(xj - xi, yj - yi)
                    self._dist[(i, j)] = self._dist[(j, i)] = d
                    ux, uy = (xj - xi) / d, (yj - yi) / d
                    self._unit[(i, j)], self._unit[(j, i)] = (ux, uy), (-ux, -uy)
        self.chains: list[dict[int, list[Chain]]] = [self._from(i) for i in range(n)]
        self._next.clear()  # the searches' working lists; the chains are what queries read

    def _turn_db(self, prev: int, u: int, w: int) -> float:
        """Loss of the bend prev -> u -> w."""
        (ax, ay), (bx, by) = self._unit[(prev, u)], self._unit[(u, w)]
        cos = max(-1.0, min(1.0, ax * bx + ay * by))
        return turn_loss_db(math.degrees(math.acos(cos)), self.per_90_db)

    def _tangent(self, i: int, j: int) -> bool:
        """True if the line from bend point i to j leaves i's corner with all its walls on
        one side. A path that bends at i and goes on to j wraps the corner only then; a
        line between the corner's walls cuts into the obstacle's angle and is (nearly) never
        part of a best path bending there (the same taut-string argument as `_wraps`)."""
        (xi, yi), (xj, yj) = self.nodes[i], self.nodes[j]
        dx, dy = xj - xi, yj - yi
        slack = TANGENT_SLACK * math.hypot(dx, dy)
        sides = [dx * ey - dy * ex for ex, ey in self._walls_at[i]]
        return all(c >= -slack for c in sides) or all(c <= slack for c in sides)

    def _wraps(self, prev: int, u: int, w: int) -> bool:
        """True if the bend prev -> u -> w turns round u's corner (or goes straight on).

        A path that bends away from the corner is (nearly) never the best: inside the
        triangle (prev, u, w) the taut string from prev to w is no longer and turns no
        more, and it bends only at corners (a visibility graph's shortest paths are
        taut). Searching only taut bends halves the states of a hall of pillars.
        """
        (ax, ay), (bx, by) = self._unit[(prev, u)], self._unit[(u, w)]
        turn = ax * by - ay * bx
        if abs(turn) < WRAP_SLACK and ax * bx + ay * by > 0:
            return True
        cx, cy = self._to_corner[u]
        return (turn > 0) == (ax * cy - ay * cx > 0)

    def _from(self, src: int) -> dict[int, list[Chain]]:
        """Best chains from node src: Dijkstra over (node, previous node) states, ordered by
        the loss a path of that length and those inner turns would have (turns at src are
        the query's: they depend on where the path comes from)."""
        k, dist, log10 = 10.0 * self.exponent, self._dist, math.log10
        done: set[tuple[int, int]] = set()
        heap: list[tuple[float, int, int, float, float, int]] = []
        for v in self.sees[src]:
            d = dist[(src, v)]
            heapq.heappush(heap, (k * log10(max(d, 0.5)), v, src, d, 0.0, v))
        out: dict[int, list[Chain]] = {}
        while heap:
            _, u, prev, length, turns, second = heapq.heappop(heap)
            if (u, prev) in done:
                continue
            done.add((u, prev))
            labels = out.setdefault(u, [])
            if len(labels) < LABELS_PER_PAIR:
                labels.append(Chain(length, turns, second, prev))
            for w, turn_db, d_uw in self._onward(prev, u):
                t = turns + turn_db
                if t > MAX_INNER_TURNS_DB:
                    break  # a path bent this much never dominates; the rest turn more
                if w == src or (w, u) in done:
                    continue
                d = length + d_uw
                heapq.heappush(heap, (k * log10(max(d, 0.5)) + t, w, u, d, t, second))
        return out

    def _onward(self, prev: int, u: int) -> list[tuple[int, float, float]]:
        """Where a path that came from prev may bend on to at u: (w, the bend's loss, u-w
        length) for every taut bend, least loss first. Every source's search meets the same
        bends, so each list is worked out once."""
        key = (prev, u)
        out = self._next.get(key)
        if out is None:
            out = self._next[key] = sorted(
                (
                    (w, self._turn_db(prev, u, w), self._dist[(u, w)])
                    for w in self.sees[u]
                    if w != prev and self._wraps(prev, u, w)
                ),
                key=lambda e: e[1],
            )
        return out

    def _sees(self, i: int, p: Point) -> bool:
        """True if bend point i sees p: only the walls in the sector of i's view that p
        lies in can be on the line between them."""
        x, y = self.nodes[i]
        a = math.atan2(p[1] - y, p[0] - x)
        k = int((a + math.pi) / _SECTOR) % SECTORS
        return _clear(p, self.nodes[i], self._sectors[i][k])

    def visible(self, p: Point) -> list[int]:
        """The bend points p sees (no wall on the line): `_sees` for every node, written
        out (it runs for every new position of a moving antenna)."""
        x, y = p
        atan2, pi = math.atan2, math.pi
        out = []
        for i, ((nx, ny), sectors) in enumerate(zip(self.nodes, self._sectors, strict=True)):
            k = int((atan2(y - ny, x - nx) + pi) / _SECTOR) % SECTORS
            if _clear(p, (nx, ny), sectors[k]):
                out.append(i)
        return out

    def best(self, a: Point, b: Point, va: Sequence[int], vb: Sequence[int]) -> BentPath | None:
        """The indirect path a -> ... -> b of least loss (length term plus turns), given the
        bend points each end sees; None when no chain joins them.

        Shortcuts that change no answer: the turn at the first bend depends only on
        (first, second) and the turn at the last only on (before last, last), so each is
        costed once per query; and a chain longer than the best path so far could cost
        with no turns at all (`_longest`) is passed over unpriced, as it could not win.
        """
        nodes, per90, k = self.nodes, self.per_90_db, 10.0 * self.exponent
        log10, dist = math.log10, math.dist
        found: tuple[float, float, float, tuple[int, ...]] | None = None
        longest = math.inf
        vb_set = set(vb)
        to_b = {j: dist(nodes[j], b) for j in vb}
        last_turn: dict[tuple[int, int], float] = {}
        for i in va:
            ni = nodes[i]
            da = dist(a, ni)
            if i in vb_set:  # one bend
                length = da + to_b[i]
                t = turn_loss_db(_turn_deg(a, ni, b), per90)
                cost = k * log10(max(length, 0.5)) + t
                if found is None or cost < found[0]:
                    found = (cost, length, t, (i,))
                    longest = self._longest(cost)
            chains = self.chains[i]
            first_turn: dict[int, float] = {}
            for j in vb:
                if j == i:
                    continue
                cs = chains.get(j)
                if not cs:
                    continue
                db = to_b[j]
                for c in cs:
                    length = da + c.length_m + db
                    if length > longest:
                        continue
                    ti = first_turn.get(c.second)
                    if ti is None:
                        ti = first_turn[c.second] = turn_loss_db(
                            _turn_deg(a, ni, nodes[c.second]), per90
                        )
                    tj = last_turn.get((c.before_last, j))
                    if tj is None:
                        tj = last_turn[(c.before_last, j)] = turn_loss_db(
                            _turn_deg(nodes[c.before_last], nodes[j], b), per90
                        )
                    t = c.turns_db + ti + tj
                    cost = k * log10(max(length, 0.5)) + t
                    if found is None or cost < found[0]:
                        found = (cost, length, t, (i, c.second, c.before_last, j))
                        longest = self._longest(cost)
        if found is None:
            return None
        _, length, t, ids = found
        return BentPath(length, t, nodes[ids[0]], nodes[ids[-1]])

    def _longest(self, cost: float) -> float:
        """A length beyond which a path costs more than `cost` whatever its turns: turns
        cost >= 0, so its cost is at least k log10(length), which exceeds `cost` past
        10^(cost / k); LONGEST_SLACK keeps float rounding (~1e-15) from deciding."""
        k = 10.0 * self.exponent
        if k <= 0 or self.per_90_db < 0:
            return math.inf
        try:
            return float(10.0 ** (cost / k)) * (1.0 + LONGEST_SLACK)
        except OverflowError:
            return math.inf
