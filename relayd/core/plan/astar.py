"""A path round what the sonars have seen: A* on the sonar grid (pure).

The search runs on the grid's own cells, 8-connected, with the octile distance as its
heuristic, weighted by `greed` (weighted A*: a path at most that factor longer than the
shortest on the grid, for a fraction of the expansions). A cell is blocked when
an occupied cell lies within `inflate_m` of it (the robot's half width and a margin: the
robot is then a point); cells within `soft_m` cost `soft_cost` more, so the path keeps
to the middle of a door rather than brushing its jamb. Unknown cells are passable at
`unknown_cost` more: the relay plans optimistically and replans as the sonars see
more, which is how a robot finds the door in a wall it has only seen part of.

The search is bounded (a box round start and goal with `margin_m`, at most
`max_expand` cells). When the goal cannot be reached (the estimate lies inside a wall,
or every way is closed) it returns the path to the reachable cell nearest the goal, if
that is nearer than the start; a search that ran out of expansions returns none. The path is then shortened by line of sight
(string pulling), so the robot drives straight between its corners.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

from relayd.core.plan.grid import Cell, SonarGrid

Path = tuple[tuple[float, float], ...]
_SQRT2 = math.sqrt(2.0)
_STEPS = (
    (1, 0, 1.0),
    (-1, 0, 1.0),
    (0, 1, 1.0),
    (0, -1, 1.0),
    *((dx, dy, _SQRT2) for dx in (-1, 1) for dy in (-1, 1)),
)


@dataclass(frozen=True, slots=True)
class PlanParams:
    inflate_m: float = 0.28
    soft_m: float = 0.5
    soft_cost: float = 2.0
    margin_m: float = 3.0
    #: Weighted A*: the heuristic counts this much (a path at most this factor longer than
    #: the best, found in a fraction of the expansions: a relay replans every second).
    greed: float = 2.0
    #: A cell no beam has touched costs this much more than a known free one: the relay
    #: goes through the unknown only when the known way is closed.
    unknown_cost: float = 0.5
    max_expand: int = 8000


def _disc(radius_m: float, cell_m: float) -> tuple[Cell, ...]:
    n = math.ceil(radius_m / cell_m)
    return tuple(
        (i, j)
        for i in range(-n, n + 1)
        for j in range(-n, n + 1)
        if math.hypot(i, j) * cell_m <= radius_m + 1e-9
    )


def costs(
    grid: SonarGrid, box: tuple[int, int, int, int], p: PlanParams
) -> tuple[set[Cell], set[Cell]]:
    """(blocked, soft) cells inside the box: the occupied cells grown by the two radii."""
    x0, y0, x1, y1 = box
    hard, soft = _disc(p.inflate_m, grid.p.cell_m), _disc(p.soft_m, grid.p.cell_m)
    blocked: set[Cell] = set()
    near: set[Cell] = set()
    cm = grid.p.cell_m
    reach = max(p.inflate_m, p.soft_m) + cm
    for cx, cy in grid.occupied_in(
        x0 * cm - reach, y0 * cm - reach, x1 * cm + reach, y1 * cm + reach
    ):
        blocked.update((cx + i, cy + j) for i, j in hard)
        near.update((cx + i, cy + j) for i, j in soft)
    return blocked, near - blocked


def plan(
    grid: SonarGrid, start_xy: tuple[float, float], goal_xy: tuple[float, float], p: PlanParams
) -> Path | None:
    """The path from start to goal (or to the reachable cell nearest it); None: no progress."""
    s, g = grid.cell(*start_xy), grid.cell(*goal_xy)
    m = math.ceil(p.margin_m / grid.p.cell_m)
    box = (min(s[0], g[0]) - m, min(s[1], g[1]) - m, max(s[0], g[0]) + m, max(s[1], g[1]) + m)
    blocked, soft = costs(grid, box, p)
    blocked.discard(s)  # the robot may stand close to a wall; it must still leave
    known = grid.logodds

    gx, gy = g
    k = _SQRT2 - 1.0

    def h(c: Cell) -> float:
        dx, dy = abs(c[0] - gx), abs(c[1] - gy)
        return dx + k * dy if dx > dy else dy + k * dx

    came: dict[Cell, Cell] = {}
    cost: dict[Cell, float] = {s: 0.0}
    greed = p.greed
    frontier: list[tuple[float, float, Cell]] = [(greed * h(s), 0.0, s)]
    best, best_h = s, h(s)
    expanded = 0
    while frontier and expanded < p.max_expand:
        _, gc, c = heapq.heappop(frontier)
        if gc > cost.get(c, math.inf):
            continue
        expanded += 1
        hc = h(c)
        if hc < best_h:
            best, best_h = c, hc
        if c == g:
            break
        for dx, dy, w in _STEPS:
            n = (c[0] + dx, c[1] + dy)
            if n in blocked or not (box[0] <= n[0] <= box[2] and box[1] <= n[1] <= box[3]):
                continue
            if dx and dy and ((c[0] + dx, c[1]) in blocked or (c[0], c[1] + dy) in blocked):
                continue  # no corner cutting between two blocked cells
            ng = gc + w * (p.soft_cost if n in soft else 1.0)
            if n not in known:
                ng += w * p.unknown_cost
            if ng < cost.get(n, math.inf):
                cost[n], came[n] = ng, c
                heapq.heappush(frontier, (ng + greed * h(n), ng, n))
    if best == s or (frontier and expanded >= p.max_expand and best != g):
        # No way nearer, or the search ran out before it knew: a greedy partial path may
        # lead into a dead end (the back of a U), so none; the escape handles it.
        return None
    cells = [best]
    while cells[-1] != s:
        cells.append(came[cells[-1]])
    cells.reverse()
    return _pull(grid, cells, blocked | soft, blocked)


def _sees(a: Cell, b: Cell, avoid: set[Cell]) -> bool:
    """No cell of `avoid` on the straight line between the two cells' centres."""
    n = 2 * max(abs(b[0] - a[0]), abs(b[1] - a[1]))
    for i in range(1, n):
        f = i / n
        c = (round(a[0] + f * (b[0] - a[0])), round(a[1] + f * (b[1] - a[1])))
        if c in avoid:
            return False
    return True


def _pull(grid: SonarGrid, cells: list[Cell], avoid: set[Cell], blocked: set[Cell]) -> Path:
    """String pulling: keep a cell only where the straight line past it would touch `avoid`
    (a soft zone the search chose to cross is crossed on its own cells, not cut)."""
    out = [cells[0]]
    i = 0
    while i < len(cells) - 1:
        j = len(cells) - 1
        zone = avoid if cells[i] not in avoid else blocked
        while j > i + 1 and not _sees(cells[i], cells[j], zone):
            j -= 1
        out.append(cells[j])
        i = j
    return tuple(grid.centre(c) for c in out)
