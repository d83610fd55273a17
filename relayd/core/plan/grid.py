"""What the sonar ring has seen: a sparse log-odds occupancy grid in the odometry frame (pure).

Each SIP's sixteen ranges update the grid the classic way (Moravec and Elfes' sonar
maps, as in Thrun, Burgard and Fox, "Probabilistic Robotics", ch. 9): the cell an echo
came from gains `hit`, the cells its beam passed through lose `miss`, each clamped to
[`floor`, `ceiling`]. An echo is spread over the beam's arc (a sonar reads the nearest
surface anywhere in its cone: a wall seen at a slant answers from the arc's edge, and an
echo laid on the axis would put a phantom in the middle of a corridor); the cone's
inside is cleared along three rays. Echoes beyond `use_m` are too often a side lobe or a multiple bounce to map,
and a ray with no echo clears only weakly (a smooth wall at a grazing angle returns
nothing, and that must not erase the wall another sonar saw). Cells are keyed by their
integer indices; only cells a beam touched are stored, so memory grows with the area
explored, and `forget` drops what lies far behind. An occupied cell counts only while
it echoed within `ttl_s`: a person or a robot that stood there has moved on.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from relayd.core.geometry import SONAR_MAX_RANGE_MM, SONAR_POSES

Cell = tuple[int, int]
#: The occupied-cell index's block side, in cells.
BUCKET = 10
#: The beam's arc where an echo is laid (rad): a sonar reads the nearest surface anywhere
#: in its +-15 deg cone, so a wall seen at a slant echoes from the arc's edge, not its axis.
ARC = tuple(math.radians(a) for a in (-12.0, -6.0, 0.0, 6.0, 12.0))
#: The arc's cells share this many hits' worth: two readings that agree make a cell occupied.
ARC_WEIGHT = 2.0
#: The rays (rad off the axis) along which the inside of the cone is cleared.
CLEAR_RAYS = tuple(math.radians(a) for a in (-8.0, 0.0, 8.0))


@dataclass(frozen=True, slots=True)
class GridParams:
    cell_m: float = 0.1
    #: Echoes farther than this are not mapped (m).
    use_m: float = 3.0
    #: A ray without an echo clears this far (m), with `miss_no_echo` per cell.
    clear_no_echo_m: float = 3.0
    hit: float = 0.9
    miss: float = 0.3
    miss_no_echo: float = 0.2
    floor: float = -2.0
    ceiling: float = 3.0
    #: A cell at or above this log-odds is occupied ...
    occupied: float = 0.5
    #: ... while its last echo is no older than this (s): people and robots move on, and
    #: a place no beam has looked at since may have changed.
    ttl_s: float = 10.0
    #: At most one ring every this many seconds (the SIP's 10 Hz halved: at walking speed
    #: the robot moves 8 cm between two, far less than a beam's width at any range).
    every_s: float = 0.2


class SonarGrid:
    """The one writer of the sonar map; `occupied_near` and `occupied_cells` read it."""

    def __init__(self, params: GridParams | None = None) -> None:
        self.p = params or GridParams()
        self.logodds: dict[Cell, float] = {}
        #: When each cell last echoed (s, the SIP's time), and the newest update's time.
        self.hit_t: dict[Cell, float] = {}
        self.now_s = 0.0
        #: Readings not yet laid (sonar index -> mm), and when the last were.
        self._pending: dict[int, int] = {}
        self._last_t = -math.inf
        #: The cells at or above `occupied`, by BUCKET x BUCKET block: the queries read
        #: these few instead of every cell a beam has touched.
        self._occ: dict[Cell, set[Cell]] = {}

    def cell(self, x_m: float, y_m: float) -> Cell:
        c = self.p.cell_m
        return (math.floor(x_m / c), math.floor(y_m / c))

    def centre(self, cell: Cell) -> tuple[float, float]:
        c = self.p.cell_m
        return ((cell[0] + 0.5) * c, (cell[1] + 0.5) * c)

    def set_occupied(self, cell: Cell, t_s: float) -> None:
        """Mark a cell occupied as of t_s, at full confidence (for a known map: tests, tools)."""
        self._add(cell, self.p.ceiling - self.logodds.get(cell, 0.0))
        self.hit_t[cell] = t_s

    def _fresh(self, cell: Cell) -> bool:
        return self.now_s - self.hit_t.get(cell, -math.inf) <= self.p.ttl_s

    def update(
        self,
        t_s: float,
        pose_mm_deg: tuple[float, float, float],
        readings: Sequence[tuple[int, int]],
        skip_xy: tuple[float, float] | None = None,
        skip_m: float = 0.0,
    ) -> None:
        """A SIP's new readings (sonar index, range mm) seen from this odometry pose at t_s.

        Readings come as the SIPs carry them (each only the sonars it updated) and are laid
        every `every_s` at the pose of that moment, each reading once."""
        self.now_s = t_s
        for index, mm in readings:
            if 0 <= index < len(SONAR_POSES) and mm >= 0:
                self._pending[index] = mm
        if not self._pending or t_s - self._last_t < self.p.every_s - 1e-9:
            return
        pending, self._pending, self._last_t = self._pending, {}, t_s
        x0, y0, th_deg = pose_mm_deg[0] / 1000.0, pose_mm_deg[1] / 1000.0, pose_mm_deg[2]
        th = math.radians(th_deg)
        c, s = math.cos(th), math.sin(th)
        p = self.p
        share = p.hit * ARC_WEIGHT / len(ARC)
        for index, mm in pending.items():
            pose = SONAR_POSES[index]
            sx = x0 + (pose.x_mm * c - pose.y_mm * s) / 1000.0
            sy = y0 + (pose.x_mm * s + pose.y_mm * c) / 1000.0
            h = th + math.radians(pose.heading_deg)
            if mm >= SONAR_MAX_RANGE_MM or mm / 1000.0 > p.use_m:
                self._clear(sx, sy, math.cos(h), math.sin(h), p.clear_no_echo_m, p.miss_no_echo)
                continue
            r = mm / 1000.0
            for off in CLEAR_RAYS:
                self._clear(sx, sy, math.cos(h + off), math.sin(h + off), r - p.cell_m, p.miss)
            # The echo came from somewhere on the beam's arc: each of its points gets a share
            # (a near echo's points fall in fewer cells, each summing its points' shares).
            for a in ARC:
                ex, ey = sx + r * math.cos(h + a), sy + r * math.sin(h + a)
                if skip_xy is not None and math.hypot(ex - skip_xy[0], ey - skip_xy[1]) < skip_m:
                    continue  # the leader's own echo (the caller's estimate of where it is)
                cell = self.cell(ex, ey)
                self._add(cell, share)
                self.hit_t[cell] = t_s

    def _clear(self, sx: float, sy: float, dx: float, dy: float, to_m: float, miss: float) -> None:
        c = self.p.cell_m
        floor = math.floor
        last: Cell | None = None
        for i in range(1, int(to_m / c) + 1):
            d = i * c
            cell = (floor((sx + d * dx) / c), floor((sy + d * dy) / c))
            if cell != last:
                self._add(cell, -miss)
                last = cell

    def _add(self, cell: Cell, delta: float) -> None:
        p = self.p
        old = self.logodds.get(cell, 0.0)
        v = old + delta
        v = p.ceiling if v > p.ceiling else (p.floor if v < p.floor else v)
        self.logodds[cell] = v
        was, now = old >= p.occupied, v >= p.occupied
        if was != now:
            key = (cell[0] // BUCKET, cell[1] // BUCKET)
            if now:
                self._occ.setdefault(key, set()).add(cell)
            else:
                block = self._occ[key]
                block.discard(cell)
                if not block:
                    del self._occ[key]

    def occupied_cells(self) -> Iterable[Cell]:
        return (c for block in self._occ.values() for c in block if self._fresh(c))

    def occupied_in(self, x0_m: float, y0_m: float, x1_m: float, y1_m: float) -> list[Cell]:
        """The occupied cells whose centres may lie in this box (whole blocks: a superset)."""
        (i0, j0), (i1, j1) = self.cell(x0_m, y0_m), self.cell(x1_m, y1_m)
        out: list[Cell] = []
        occ, fresh = self._occ, self._fresh
        for bi in range(i0 // BUCKET, i1 // BUCKET + 1):
            for bj in range(j0 // BUCKET, j1 // BUCKET + 1):
                block = occ.get((bi, bj))
                if block:
                    out.extend(c for c in block if fresh(c))
        return out

    def occupied_near(self, x_m: float, y_m: float, radius_m: float) -> bool:
        """Is any occupied cell's centre within radius_m of this point?"""
        return not self.segment_clear((x_m, y_m), (x_m, y_m), radius_m)

    def segment_clear(
        self, a: tuple[float, float], b: tuple[float, float], radius_m: float
    ) -> bool:
        """No occupied cell's centre within radius_m of the segment a-b."""
        r = radius_m
        cells = self.occupied_in(
            min(a[0], b[0]) - r, min(a[1], b[1]) - r, max(a[0], b[0]) + r, max(a[1], b[1]) + r
        )
        if not cells:
            return True
        cm = self.p.cell_m
        ax, ay = a
        dx, dy = b[0] - ax, b[1] - ay
        n2 = dx * dx + dy * dy
        r2 = r * r
        for i, j in cells:
            px, py = (i + 0.5) * cm - ax, (j + 0.5) * cm - ay
            f = 0.0 if n2 < 1e-12 else min(1.0, max(0.0, (px * dx + py * dy) / n2))
            ex, ey = px - f * dx, py - f * dy
            if ex * ex + ey * ey <= r2:
                return False
        return True

    def forget(self, x_m: float, y_m: float, keep_m: float) -> None:
        """Drop every cell outside the square of half-side keep_m round this point (bounded memory)."""
        cx, cy = self.cell(x_m, y_m)
        n = keep_m / self.p.cell_m
        self.logodds = {
            k: v for k, v in self.logodds.items() if abs(k[0] - cx) <= n and abs(k[1] - cy) <= n
        }
        self.hit_t = {k: t for k, t in self.hit_t.items() if k in self.logodds}
        self._occ = {}
        thr = self.p.occupied
        for k, v in self.logodds.items():
            if v >= thr:
                self._occ.setdefault((k[0] // BUCKET, k[1] // BUCKET), set()).add(k)
