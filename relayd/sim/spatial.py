"""A uniform-grid spatial index for the simulated world's static walls and map points.

A building's ARIA map holds hundreds of wall lines and tens of thousands of scan points;
the world asks "what is near this robot" for every sonar ring and every motion step, so
a scan of everything each time would cost O(map) per question. `GridIndex` buckets
bounding boxes into square cells and answers a box query with the indices of the items
whose boxes may meet it, ascending: callers keep the items in their original order (so
a world with an index computes exactly what it computed without one) and still run
their exact tests. Pure Python, no dependencies: the items are few per cell, and a
dict of lists beats an R-tree's per-query overhead at this size.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

Box = tuple[float, float, float, float]  # x_min, y_min, x_max, y_max (m)

#: Cell side (m): about a robot's size, so a footprint or a sonar's reach spans a few cells.
DEFAULT_CELL_M = 1.0


class GridIndex:
    """Items' bounding boxes bucketed into `cell_m` squares."""

    __slots__ = ("_cells", "cell_m", "size")

    def __init__(self, boxes: Sequence[Box], cell_m: float = DEFAULT_CELL_M) -> None:
        if cell_m <= 0:
            raise ValueError("cell_m must be > 0")
        self.cell_m = cell_m
        self.size = len(boxes)
        cells: dict[tuple[int, int], list[int]] = {}
        c = cell_m
        for k, (x0, y0, x1, y1) in enumerate(boxes):
            for i in range(math.floor(x0 / c), math.floor(x1 / c) + 1):
                for j in range(math.floor(y0 / c), math.floor(y1 / c) + 1):
                    cells.setdefault((i, j), []).append(k)
        self._cells = cells

    def query(self, x0: float, y0: float, x1: float, y1: float) -> list[int]:
        """Ascending indices of the items whose cells meet the box (a superset of the hits)."""
        c = self.cell_m
        i0, i1 = math.floor(x0 / c), math.floor(x1 / c)
        j0, j1 = math.floor(y0 / c), math.floor(y1 / c)
        cells = self._cells
        if (i1 - i0 + 1) * (j1 - j0 + 1) > len(cells):
            # A box larger than the populated area: walk the cells that exist instead.
            found = {
                k for (i, j), ks in cells.items() if i0 <= i <= i1 and j0 <= j <= j1 for k in ks
            }
            return sorted(found)
        out: set[int] = set()
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                ks = cells.get((i, j))
                if ks is not None:
                    out.update(ks)
        return sorted(out)
