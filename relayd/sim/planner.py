"""A* on an occupancy grid with a clearance margin (used by the floor-plan generator).

`plan(walls, start, goal, clearance_m)` rasterises the wall segments onto a grid, grows
them by `clearance_m` (the robot's half-width plus a margin), and returns the route as
corner waypoints, start and goal included, or None when there is no way through.
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Sequence

Point = tuple[float, float]
Segment = tuple[Point, Point]


def _seg_dist(p: Point, a: Point, b: Point) -> float:
    ax, ay = a
    bx, by = b
    dx, dy = bx - ax, by - ay
    L2 = dx * dx + dy * dy
    t = 0.0 if L2 == 0 else max(0.0, min(1.0, ((p[0] - ax) * dx + (p[1] - ay) * dy) / L2))
    return math.hypot(p[0] - ax - t * dx, p[1] - ay - t * dy)


class Grid:
    """Blocked cells: every cell whose centre is within `clearance_m` of a wall."""

    def __init__(
        self,
        walls: Sequence[Segment],
        clearance_m: float,
        cell_m: float = 0.2,
        pad_m: float = 2.0,
        points: Sequence[Point] = (),
    ) -> None:
        xs = [p[0] for s in walls for p in s] + [p[0] for p in points] or [0.0]
        ys = [p[1] for s in walls for p in s] + [p[1] for p in points] or [0.0]
        self.cell_m = cell_m
        self.x0 = min(xs) - pad_m
        self.y0 = min(ys) - pad_m
        self.nx = math.ceil((max(xs) + pad_m - self.x0) / cell_m) + 1
        self.ny = math.ceil((max(ys) + pad_m - self.y0) / cell_m) + 1
        self.blocked = bytearray(self.nx * self.ny)
        r = math.ceil(clearance_m / cell_m) + 1
        for a, b in walls:
            i0, j0 = self.cell((min(a[0], b[0]), min(a[1], b[1])))
            i1, j1 = self.cell((max(a[0], b[0]), max(a[1], b[1])))
            for i in range(max(0, i0 - r), min(self.nx, i1 + r + 1)):
                for j in range(max(0, j0 - r), min(self.ny, j1 + r + 1)):
                    if _seg_dist(self.centre(i, j), a, b) < clearance_m:
                        self.blocked[i * self.ny + j] = 1
        if points:
            # Obstacle points (a map's scan): one stamp of the cells within clearance of a
            # point placed at a cell centre, grown by half a cell's diagonal so that a
            # point anywhere in its cell blocks every cell within clearance of it.
            reach = clearance_m + cell_m * math.sqrt(0.5)
            stamp = [
                (di, dj)
                for di in range(-r, r + 1)
                for dj in range(-r, r + 1)
                if math.hypot(di, dj) * cell_m < reach
            ]
            for p in points:
                i, j = self.cell(p)
                for di, dj in stamp:
                    u, v = i + di, j + dj
                    if 0 <= u < self.nx and 0 <= v < self.ny:
                        self.blocked[u * self.ny + v] = 1

    def cell(self, p: Point) -> tuple[int, int]:
        return round((p[0] - self.x0) / self.cell_m), round((p[1] - self.y0) / self.cell_m)

    def centre(self, i: int, j: int) -> Point:
        return self.x0 + i * self.cell_m, self.y0 + j * self.cell_m

    def free(self, p: Point) -> bool:
        i, j = self.cell(p)
        return 0 <= i < self.nx and 0 <= j < self.ny and not self.blocked[i * self.ny + j]


_STEPS = [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)]


def plan(
    walls: Sequence[Segment],
    start: Point,
    goal: Point,
    clearance_m: float,
    cell_m: float = 0.2,
    points: Sequence[Point] = (),
) -> list[Point] | None:
    """The shortest 8-connected grid route keeping `clearance_m` from every wall (and point)."""
    return plan_on(Grid(walls, clearance_m, cell_m, points=points), start, goal)


def plan_on(g: Grid, start: Point, goal: Point) -> list[Point] | None:
    """`plan` on a grid already made (several legs through one map)."""
    if not (g.free(start) and g.free(goal)):
        return None
    s, t = g.cell(start), g.cell(goal)
    came: dict[tuple[int, int], tuple[int, int]] = {}
    cost = {s: 0.0}
    heap = [(0.0, 0.0, s)]
    while heap:
        _, c, u = heapq.heappop(heap)
        if u == t:
            break
        if c > cost[u]:
            continue
        for di, dj in _STEPS:
            v = (u[0] + di, u[1] + dj)
            if not (0 <= v[0] < g.nx and 0 <= v[1] < g.ny) or g.blocked[v[0] * g.ny + v[1]]:
                continue
            if (
                di
                and dj
                and (g.blocked[(u[0] + di) * g.ny + u[1]] or g.blocked[u[0] * g.ny + u[1] + dj])
            ):
                continue  # no corner cutting past a blocked cell
            nc = c + (math.sqrt(2.0) if di and dj else 1.0)
            if nc < cost.get(v, math.inf):
                cost[v] = nc
                came[v] = u
                h = math.hypot(t[0] - v[0], t[1] - v[1])
                heapq.heappush(heap, (nc + h, nc, v))
    if t not in cost:
        return None
    cells = [t]
    while cells[-1] != s:
        cells.append(came[cells[-1]])
    cells.reverse()
    # Keep only the cells where the direction changes: the route's corners.
    pts: list[Point] = [start]
    for k in range(1, len(cells) - 1):
        d0 = (cells[k][0] - cells[k - 1][0], cells[k][1] - cells[k - 1][1])
        d1 = (cells[k + 1][0] - cells[k][0], cells[k + 1][1] - cells[k][1])
        if d0 != d1:
            pts.append(g.centre(*cells[k]))
    pts.append(goal)
    return pts


def route_length_m(points: Sequence[Point]) -> float:
    return sum(math.dist(a, b) for a, b in itertools.pairwise(points))
