"""The floor-plan generator's "corridors" kind: a network of corridors with L-corners and
T-junctions (relayd/sim/generate.py draws the kinds; this module draws this one).

The corridors join the points of a coarse lattice along a random spanning tree (a
randomised depth-first walk), so a corridor turns where the walk turns (an L-corner)
and branches where it branches (a T-junction, now and then a crossing). The entrance
corridor runs east along y = 0 from the building's west wall, where the command center
and the convoy stand. Each corridor gets its own width (1.5-4 m). The plan is drawn on a
0.25 m raster and its walls are the raster's free/solid boundary merged into straight
runs, so corridors of any widths meet cleanly. The person's goal is the lattice point
four to six corridors from the entrance along the tree.
"""

from __future__ import annotations

import random

Point = tuple[float, float]

CELL_M = 0.25
#: Lattice spacing (m) along x and y, the lattice's size, and where its first column is.
SPACING_M = (11.0, 9.0)
COLUMNS, ROWS = 4, 3
#: The goal is a lattice point this many corridors from the entrance (or the deepest).
GOAL_DEPTH = (4, 6)
X0_M = 6.0
WEST_M = -3.0


def _r(x: float) -> float:
    return round(x, 2)


def _carve(free: set[tuple[int, int]], x0: float, x1: float, y0: float, y1: float) -> None:
    """Mark free every cell whose centre lies inside [x0, x1] x [y0, y1]."""
    i0, i1 = round(x0 / CELL_M), round(x1 / CELL_M)
    j0, j1 = round(y0 / CELL_M), round(y1 / CELL_M)
    for i in range(i0, i1):
        for j in range(j0, j1):
            free.add((i, j))


def _walls(free: set[tuple[int, int]]) -> list[tuple[Point, Point]]:
    """The boundary between free and solid cells, merged into maximal straight runs."""
    horiz: dict[int, list[int]] = {}  # y line index -> x cell indices with an edge there
    vert: dict[int, list[int]] = {}
    for i, j in free:
        if (i, j - 1) not in free:
            horiz.setdefault(j, []).append(i)
        if (i, j + 1) not in free:
            horiz.setdefault(j + 1, []).append(i)
        if (i - 1, j) not in free:
            vert.setdefault(i, []).append(j)
        if (i + 1, j) not in free:
            vert.setdefault(i + 1, []).append(j)
    out: list[tuple[Point, Point]] = []
    for line, cells in sorted(horiz.items()):
        for a, b in _runs(sorted(cells)):
            y = _r(line * CELL_M)
            out.append(((_r(a * CELL_M), y), (_r((b + 1) * CELL_M), y)))
    for line, cells in sorted(vert.items()):
        for a, b in _runs(sorted(cells)):
            x = _r(line * CELL_M)
            out.append(((x, _r(a * CELL_M)), (x, _r((b + 1) * CELL_M))))
    return out


def _runs(cells: list[int]) -> list[tuple[int, int]]:
    """Consecutive runs [a, b] of sorted integers (a cell edge on both sides of a thin
    wall appears twice; it is one run)."""
    out: list[tuple[int, int]] = []
    for c in cells:
        if out and c <= out[-1][1] + 1:
            out[-1] = (out[-1][0], max(out[-1][1], c))
        else:
            out.append((c, c))
    return out


def _tree(rng: random.Random) -> tuple[list[tuple[int, int, int, int]], dict[tuple[int, int], int]]:
    """A random spanning tree of the lattice from its west-middle point: the edges in the
    order the walk made them, and each point's depth (edges from the entrance)."""
    start = (0, 0)
    depth = {start: 0}
    stack = [start]
    edges: list[tuple[int, int, int, int]] = []
    while stack:
        c, r = stack[-1]
        options = [
            (c + dc, r + dr)
            for dc, dr in ((1, 0), (-1, 0), (0, 1), (0, -1))
            if 0 <= c + dc < COLUMNS
            and -(ROWS // 2) <= r + dr <= ROWS - 1 - ROWS // 2
            and (c + dc, r + dr) not in depth
        ]
        if not options:
            stack.pop()
            continue
        nxt = rng.choice(options)
        depth[nxt] = depth[(c, r)] + 1
        edges.append((c, r, *nxt))
        stack.append(nxt)
    return edges, depth


def corridors(rng: random.Random, loss: dict[str, float]) -> dict[str, object]:
    """One corridor-network world (the generator's world dict; see generate._office)."""
    sx, sy = SPACING_M
    edges, depth = _tree(rng)

    def at(c: int, r: int) -> Point:
        return X0_M + c * sx, r * sy

    free: set[tuple[int, int]] = set()
    w0 = rng.choice([1.5, 2.0, 2.5, 3.0, 3.5, 4.0])
    _carve(free, WEST_M, X0_M, -w0 / 2, w0 / 2)
    widths = []
    for c, r, c2, r2 in edges:
        w = rng.choice([1.5, 2.0, 2.5, 3.0, 3.5, 4.0])
        widths.append(w)
        (ax, ay), (bx, by) = at(c, r), at(c2, r2)
        x0, x1, y0, y1 = min(ax, bx), max(ax, bx), min(ay, by), max(ay, by)
        _carve(free, x0 - w / 2, x1 + w / 2, y0 - w / 2, y1 + w / 2)
    # Furniture: a box against a wall of some wide corridors (a cabinet, a bench), away
    # from the junctions (the middle 30-70 % of the corridor).
    boxes: list[tuple[Point, Point]] = []
    for (c, r, c2, r2), w in zip(edges, widths, strict=True):
        if rng.random() < 0.4:
            (ax, ay), (bx, by) = at(c, r), at(c2, r2)
            h = w / 2
            if h < 1.5:
                continue
            f = rng.uniform(0.3, 0.7)
            mx, my = ax + f * (bx - ax), ay + f * (by - ay)
            side = rng.choice((-1.0, 1.0))
            length, depth_m = _r(rng.uniform(0.6, 1.4)), _r(rng.uniform(0.4, 0.6))
            if ay == by:  # an east-west corridor: the box against its north or south wall
                y_wall = my + side * h
                y_in = y_wall - side * (depth_m + 0.05)
                lo, hi = sorted((y_wall - side * 0.05, y_in))
                boxes.append(((_r(mx), _r(lo)), (_r(mx + length), _r(hi))))
            else:
                x_wall = mx + side * h
                x_in = x_wall - side * (depth_m + 0.05)
                lo, hi = sorted((x_wall - side * 0.05, x_in))
                boxes.append(((_r(lo), _r(my)), (_r(hi), _r(my + length))))
    material = rng.choice(["brick", "concrete", "brick", "light"])
    walls = [([a, b], material) for a, b in _walls(free)]
    lo, hi = GOAL_DEPTH
    picks = [p for p in sorted(depth) if lo <= depth[p] <= hi]
    far = rng.choice(picks) if picks else max(sorted(depth), key=lambda p: (depth[p], p))
    gx, gy = at(*far)
    return {"walls": walls, "doors": [], "boxes": boxes, "goal": (_r(gx), _r(gy)), "loss": loss}
