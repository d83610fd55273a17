"""2-D geometry of the simulated world: segments, boxes, ray casting, footprint collision.

Pure and allocation-light: the world calls these for every sonar ray and every motion
step of every robot, so everything is plain floats and tuples (no numpy). Units are
metres and degrees (counter-clockwise positive, x east, y north); the simulator converts
to the robot's millimetres at the boundary.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from relayd.core.geometry import wrap_deg

Point = tuple[float, float]
Polygon = tuple[Point, ...]

_EPS = 1e-12
#: Slack of a bounding-box pre-test: far above the exact tests' 1e-12 tolerance and their
#: rounding, far below anything a world is drawn to (so it never decides a result).
_BOX_SLACK = 1e-9
#: cone_range skips a disc whose nearest point (centre distance - radius) lies farther
#: than the best echo so far by this much per metre: every candidate it could give (its
#: centre, or where an edge ray meets it) is at least that far up to float rounding, and
#: the rounding of an edge ray's square root is ~3e-8 per metre of distance at worst,
#: so a skipped disc could never have won (the same ranges, bit for bit).
_DISC_SLACK = 1e-6


@dataclass(frozen=True, slots=True)
class Segment:
    """A straight wall piece from (x1, y1) to (x2, y2) made of `material`."""

    x1: float
    y1: float
    x2: float
    y2: float
    material: str = "brick"

    @property
    def length_m(self) -> float:
        return math.hypot(self.x2 - self.x1, self.y2 - self.y1)

    def bbox(self) -> tuple[float, float, float, float]:
        return (
            min(self.x1, self.x2),
            min(self.y1, self.y2),
            max(self.x1, self.x2),
            max(self.y1, self.y2),
        )


@dataclass(frozen=True, slots=True)
class Box:
    """An axis-aligned rectangular obstacle (a crate, a parked car, a pillar)."""

    x_min: float
    y_min: float
    x_max: float
    y_max: float
    material: str = "box"

    def __post_init__(self) -> None:
        if not (self.x_min < self.x_max and self.y_min < self.y_max):
            raise ValueError(f"box needs x_min < x_max and y_min < y_max, got {self!r}")

    def corners(self) -> Polygon:
        return (
            (self.x_min, self.y_min),
            (self.x_max, self.y_min),
            (self.x_max, self.y_max),
            (self.x_min, self.y_max),
        )

    def segments(self) -> tuple[Segment, ...]:
        return polygon_segments(self.corners(), self.material)


def polygon_segments(poly: Sequence[Point], material: str = "body") -> tuple[Segment, ...]:
    """The closed outline of a polygon as segments."""
    n = len(poly)
    return tuple(
        Segment(poly[i][0], poly[i][1], poly[(i + 1) % n][0], poly[(i + 1) % n][1], material)
        for i in range(n)
    )


def ray_segment_distance(
    ox: float, oy: float, dx: float, dy: float, x1: float, y1: float, x2: float, y2: float
) -> float | None:
    """Distance along the unit ray (ox, oy) + t (dx, dy), t >= 0, to the segment, or None."""
    ex, ey = x2 - x1, y2 - y1
    denom = dx * ey - dy * ex
    if abs(denom) < _EPS:
        return None  # parallel (a grazing ray along a wall does not echo)
    wx, wy = x1 - ox, y1 - oy
    t = (wx * ey - wy * ex) / denom
    if t < 0.0:
        return None
    u = (wx * dy - wy * dx) / denom
    if u < 0.0 or u > 1.0:
        return None
    return t


def ray_circle_distance(
    ox: float, oy: float, dx: float, dy: float, cx: float, cy: float, r: float
) -> float | None:
    """Distance along the unit ray to the first intersection with a circle, or None."""
    fx, fy = ox - cx, oy - cy
    b = fx * dx + fy * dy
    c = fx * fx + fy * fy - r * r
    disc = b * b - c
    if disc < 0.0:
        return None
    sq = math.sqrt(disc)
    t = -b - sq
    if t >= 0.0:
        return t
    t = -b + sq
    return 0.0 if t >= 0.0 else None  # origin inside the circle: touching


def cast_ray(
    ox: float,
    oy: float,
    heading_deg: float,
    max_range_m: float,
    segments: Iterable[Segment],
    circles: Iterable[tuple[float, float, float]] = (),
) -> float | None:
    """Nearest hit of a ray against segments and circles (cx, cy, r) within max_range_m."""
    a = math.radians(heading_deg)
    dx, dy = math.cos(a), math.sin(a)
    best = max_range_m
    hit = False
    for s in segments:
        t = ray_segment_distance(ox, oy, dx, dy, s.x1, s.y1, s.x2, s.y2)
        if t is not None and t <= best:
            best, hit = t, True
    for cx, cy, r in circles:
        t = ray_circle_distance(ox, oy, dx, dy, cx, cy, r)
        if t is not None and t <= best:
            best, hit = t, True
    return best if hit else None


def _orient(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


def segments_intersect(p1: Point, p2: Point, q1: Point, q2: Point) -> bool:
    """True if the closed segments p1-p2 and q1-q2 share a point (touching counts)."""
    d1 = _orient(q1[0], q1[1], q2[0], q2[1], p1[0], p1[1])
    d2 = _orient(q1[0], q1[1], q2[0], q2[1], p2[0], p2[1])
    d3 = _orient(p1[0], p1[1], p2[0], p2[1], q1[0], q1[1])
    d4 = _orient(p1[0], p1[1], p2[0], p2[1], q2[0], q2[1])
    if ((d1 > 0) != (d2 > 0) and d1 != 0 and d2 != 0) and (
        (d3 > 0) != (d4 > 0) and d3 != 0 and d4 != 0
    ):
        return True

    def on_seg(a: Point, b: Point, c: Point, d: float) -> bool:
        return (
            abs(d) < 1e-12
            and min(a[0], b[0]) - 1e-12 <= c[0] <= max(a[0], b[0]) + 1e-12
            and min(a[1], b[1]) - 1e-12 <= c[1] <= max(a[1], b[1]) + 1e-12
        )

    return (
        on_seg(q1, q2, p1, d1)
        or on_seg(q1, q2, p2, d2)
        or on_seg(p1, p2, q1, d3)
        or on_seg(p1, p2, q2, d4)
    )


def crossings(p: Point, q: Point, segments: Iterable[Segment]) -> list[Segment]:
    """The walls the straight path p -> q crosses (each counted once)."""
    # Walls whose bounding box misses the path's (by more than any rounding of the exact
    # test, which touches within 1e-12) cannot share a point with it: skipped unexamined.
    x0, x1 = min(p[0], q[0]) - _BOX_SLACK, max(p[0], q[0]) + _BOX_SLACK
    y0, y1 = min(p[1], q[1]) - _BOX_SLACK, max(p[1], q[1]) + _BOX_SLACK
    out = []
    for s in segments:
        sx1, sy1, sx2, sy2 = s.x1, s.y1, s.x2, s.y2
        if (
            (sx1 < x0 and sx2 < x0)
            or (sx1 > x1 and sx2 > x1)
            or (sy1 < y0 and sy2 < y0)
            or (sy1 > y1 and sy2 > y1)
        ):
            continue
        if segments_intersect(p, q, (sx1, sy1), (sx2, sy2)):
            out.append(s)
    return out


def footprint(x_m: float, y_m: float, theta_deg: float, length_m: float, width_m: float) -> Polygon:
    """The rectangle a robot covers, centred on its pose, long axis along its heading."""
    a = math.radians(theta_deg)
    c, s = math.cos(a), math.sin(a)
    hl, hw = length_m / 2.0, width_m / 2.0
    return tuple(
        (x_m + c * lx - s * ly, y_m + s * lx + c * ly)
        for lx, ly in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))
    )


def point_in_polygon(pt: Point, poly: Sequence[Point]) -> bool:
    """Even-odd rule; points on the boundary may go either way (edges are tested separately)."""
    x, y = pt
    inside = False
    n = len(poly)
    j = n - 1
    for i in range(n):
        xi, yi = poly[i]
        xj, yj = poly[j]
        if (yi > y) != (yj > y) and x < (xj - xi) * (y - yi) / (yj - yi) + xi:
            inside = not inside
        j = i
    return inside


def polygon_hits_segment(poly: Sequence[Point], s: Segment) -> bool:
    """True if a convex polygon touches or contains any part of the segment."""
    a, b = (s.x1, s.y1), (s.x2, s.y2)
    n = len(poly)
    for i in range(n):
        if segments_intersect(poly[i], poly[(i + 1) % n], a, b):
            return True
    return point_in_polygon(a, poly)


def polygons_overlap(p: Sequence[Point], q: Sequence[Point]) -> bool:
    """True if two simple polygons touch, cross or one contains the other."""
    n, m = len(p), len(q)
    for i in range(n):
        for j in range(m):
            if segments_intersect(p[i], p[(i + 1) % n], q[j], q[(j + 1) % m]):
                return True
    return point_in_polygon(p[0], q) or point_in_polygon(q[0], p)


def polygon_hits_circle(poly: Sequence[Point], cx: float, cy: float, r: float) -> bool:
    """True if a polygon and a disc overlap."""
    if point_in_polygon((cx, cy), poly):
        return True
    n = len(poly)
    return any(point_segment_distance((cx, cy), poly[i], poly[(i + 1) % n]) <= r for i in range(n))


def point_segment_distance(p: Point, a: Point, b: Point) -> float:
    ex, ey = b[0] - a[0], b[1] - a[1]
    L2 = ex * ex + ey * ey
    if L2 < _EPS:
        return math.hypot(p[0] - a[0], p[1] - a[1])
    t = max(0.0, min(1.0, ((p[0] - a[0]) * ex + (p[1] - a[1]) * ey) / L2))
    return math.hypot(p[0] - a[0] - t * ex, p[1] - a[1] - t * ey)


def _clip_to_half_plane(p: Point, q: Point, nx: float, ny: float) -> tuple[Point, Point] | None:
    """The part of segment p-q where n . x >= 0, or None."""
    dp, dq = nx * p[0] + ny * p[1], nx * q[0] + ny * q[1]
    if dp < 0.0 and dq < 0.0:
        return None
    if dp >= 0.0 and dq >= 0.0:
        return p, q
    f = dp / (dp - dq)
    m = (p[0] + f * (q[0] - p[0]), p[1] + f * (q[1] - p[1]))
    return (p, m) if dp >= 0.0 else (m, q)


# Complexity: a hot geometric kernel kept in one piece for speed (bench/simspeed.py).
def cone_range(  # noqa: C901
    ox: float,
    oy: float,
    heading_deg: float,
    half_width_deg: float,
    max_range_m: float,
    segments: Iterable[Segment],
    circles: Iterable[tuple[float, float, float]] = (),
) -> float | None:
    """Distance from (ox, oy) to the nearest point of any segment or disc inside the cone
    heading +- half_width (< 90 deg), or None when nothing lies within max_range_m.

    This is what a sonar's first echo measures: the nearest surface anywhere in its beam,
    not along a few sampled rays, so it is exact and symmetric under mirroring.
    """
    h = math.radians(heading_deg)
    w = math.radians(half_width_deg)
    # Inward normals of the cone's two edges (left edge at h + w, right edge at h - w).
    nlx, nly = math.sin(h + w), -math.cos(h + w)
    nrx, nry = -math.sin(h - w), math.cos(h - w)
    best = max_range_m
    hit = False
    hypot = math.hypot
    for s in segments:
        # Each segment clipped to both edges' half-planes, then its distance from the apex:
        # _clip_to_half_plane twice and point_segment_distance, written out because a
        # sonar ring runs this 80 times a second per robot (the same operations in the same
        # order, so the same floats; tests/sim/test_shortcuts.py checks it against them).
        px, py, qx, qy = s.x1 - ox, s.y1 - oy, s.x2 - ox, s.y2 - oy
        dp, dq = nlx * px + nly * py, nlx * qx + nly * qy
        if dp < 0.0 and dq < 0.0:
            continue
        if not (dp >= 0.0 and dq >= 0.0):
            f = dp / (dp - dq)
            if dp >= 0.0:
                qx, qy = px + f * (qx - px), py + f * (qy - py)
            else:
                px, py = px + f * (qx - px), py + f * (qy - py)
        dp, dq = nrx * px + nry * py, nrx * qx + nry * qy
        if dp < 0.0 and dq < 0.0:
            continue
        if not (dp >= 0.0 and dq >= 0.0):
            f = dp / (dp - dq)
            if dp >= 0.0:
                qx, qy = px + f * (qx - px), py + f * (qy - py)
            else:
                px, py = px + f * (qx - px), py + f * (qy - py)
        ex, ey = qx - px, qy - py
        l2 = ex * ex + ey * ey
        if l2 < _EPS:
            d = hypot(0.0 - px, 0.0 - py)
        else:
            u = max(0.0, min(1.0, ((0.0 - px) * ex + (0.0 - py) * ey) / l2))
            d = hypot(0.0 - px - u * ex, 0.0 - py - u * ey)
        if d <= best:
            best, hit = d, True
    cos_w = math.cos(w)
    dx, dy = math.cos(h), math.sin(h)
    # The two edge rays, for every disc (the same cos and sin each time, worked out once).
    lx, ly = math.cos(h + w), math.sin(h + w)
    rx_, ry_ = math.cos(h - w), math.sin(h - w)
    sqrt = math.sqrt
    for cx, cy, r in circles:
        # A disc's candidates in ray_circle_distance's order (its centre if inside the cone,
        # then where the left and the right edge ray meet it), that function written out
        # with the ray starting at the apex: a specular ring's corners are ~10 points per
        # cone (the same operations in the same order, so the same floats).
        rx, ry = cx - ox, cy - oy
        dist = hypot(rx, ry)
        if dist <= r:
            return 0.0
        if dist - r > best + _DISC_SLACK * (1.0 + dist):
            continue  # all its candidates lie beyond the nearest echo so far (_DISC_SLACK)
        if (rx * dx + ry * dy) >= dist * cos_w:  # the centre is inside the cone
            d = dist - r
            if d <= best:
                best, hit = d, True
        fx, fy = 0.0 - rx, 0.0 - ry
        c = fx * fx + fy * fy - r * r
        for ex, ey in ((lx, ly), (rx_, ry_)):
            b = fx * ex + fy * ey
            disc = b * b - c
            if disc < 0.0:
                continue
            sq = sqrt(disc)
            t = -b - sq
            if t < 0.0:
                t = -b + sq
                if t < 0.0:
                    continue
                t = 0.0  # the apex inside the disc: touching
            if t <= best:
                best, hit = t, True
    return best if hit else None


__all__ = ["wrap_deg"]  # re-exported: the simulator's callers name it here
