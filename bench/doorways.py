"""Door-like gaps in an ARIA map's wall lines: where they are and how wide.

A door in a `.map` made by ARIA's tools is a gap between two wall lines that would
otherwise run on: a line ends in free space (no other line within JOIN_M of its end) and
the first line met going on from that end, within ALIGN_DEG of the wall's own direction
and with no line across the way, is 0.5-1.6 m away. For each such gap the script prints the two wall ends, the width
between them (line to line), the clear width after the map's scan points (the widest
stretch of the gap with no `DATA` point within POINT_BAND_M of it: furniture and door
frames are often only points), and the gap's middle and direction. Passing a gap takes a
robot's width plus a margin each side.

    python bench/doorways.py AMROffice.map [--box X0 Y0 X1 Y1] [--min 0.5] [--max 1.6]
"""

from __future__ import annotations

import argparse
import itertools
import math
from pathlib import Path

from relayd.sim.ariamap import MapLine, load_map

#: Two line ends closer than this are joined (a corner, not a gap).
JOIN_M = 0.08
#: A scan point this close to the gap's segment narrows it.
POINT_BAND_M = 0.15
#: The gap runs within this angle of the wall it continues (a door in a straight wall).
ALIGN_DEG = 25.0


def _closest(px: float, py: float, ln: MapLine) -> tuple[float, float, float]:
    """(distance, x, y) of the point of `ln` nearest (px, py)."""
    ex, ey = ln.x2 - ln.x1, ln.y2 - ln.y1
    n2 = ex * ex + ey * ey
    u = 0.0 if n2 == 0 else max(0.0, min(1.0, ((px - ln.x1) * ex + (py - ln.y1) * ey) / n2))
    qx, qy = ln.x1 + u * ex, ln.y1 + u * ey
    return math.hypot(px - qx, py - qy), qx, qy


def _crosses(a: tuple[float, float], b: tuple[float, float], ln: MapLine) -> bool:
    """Segment a-b properly crosses `ln` (a wall across the gap: not a door)."""

    def side(p: tuple[float, float], q: tuple[float, float], r: tuple[float, float]) -> float:
        return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])

    c, d = (ln.x1, ln.y1), (ln.x2, ln.y2)
    return side(a, b, c) * side(a, b, d) < 0 and side(c, d, a) * side(c, d, b) < 0


def _free_ends(lines: tuple[MapLine, ...]) -> list[tuple[MapLine, float, float, float, float]]:
    """Each line end with no other line within JOIN_M: (line, x, y, unit dx, unit dy) with
    the direction pointing out of the line, past its end."""
    out = []
    for ln in lines:
        length = math.hypot(ln.x2 - ln.x1, ln.y2 - ln.y1)
        if length < 0.1:
            continue
        ux, uy = (ln.x2 - ln.x1) / length, (ln.y2 - ln.y1) / length
        for x, y, dx, dy in ((ln.x1, ln.y1, -ux, -uy), (ln.x2, ln.y2, ux, uy)):
            if all(o is ln or _closest(x, y, o)[0] > JOIN_M for o in lines):
                out.append((ln, x, y, dx, dy))
    return out


def clear_width_m(
    a: tuple[float, float], b: tuple[float, float], points: list[tuple[float, float]]
) -> float:
    """The widest stretch of segment a-b with no scan point within POINT_BAND_M of it."""
    length = math.dist(a, b)
    ux, uy = (b[0] - a[0]) / length, (b[1] - a[1]) / length
    cuts = [0.0, length]
    for px, py in points:
        along = (px - a[0]) * ux + (py - a[1]) * uy
        across = -(px - a[0]) * uy + (py - a[1]) * ux
        if -POINT_BAND_M < along < length + POINT_BAND_M and abs(across) < POINT_BAND_M:
            cuts.append(min(length, max(0.0, along)))
    cuts.sort()
    return max(q - p for p, q in itertools.pairwise(cuts))


def doorways(
    path: str | Path, min_m: float = 0.5, max_m: float = 1.6,
    box: tuple[float, float, float, float] | None = None,
) -> list[dict[str, float]]:  # fmt: skip
    """The map's door-like gaps, widest first (see the module docstring)."""
    amap = load_map(path)
    lines = amap.lines
    if box is not None:
        x0, y0, x1, y1 = box
        lines = tuple(
            ln for ln in lines
            if x0 - 2 < min(ln.x1, ln.x2) and max(ln.x1, ln.x2) < x1 + 2
            and y0 - 2 < min(ln.y1, ln.y2) and max(ln.y1, ln.y2) < y1 + 2
        )  # fmt: skip
    ends = _free_ends(lines)
    found: list[dict[str, float]] = []
    for own, x, y, dx, dy in ends:
        if box is not None and not (box[0] <= x <= box[2] and box[1] <= y <= box[3]):
            continue
        # The first wall met going on from this end, along the wall (a door in it) and
        # with no other wall across the way.
        best: tuple[float, float, float, MapLine] | None = None
        for other in lines:
            if other is own:
                continue
            d, qx, qy = _closest(x, y, other)
            if not min_m <= d <= max_m or (best is not None and d >= best[0]):
                continue
            if ((qx - x) * dx + (qy - y) * dy) / d < math.cos(math.radians(ALIGN_DEG)):
                continue
            if any(_crosses((x, y), (qx, qy), o) for o in lines if o is not own and o is not other):
                continue
            best = (d, qx, qy, other)
        if best is None:
            continue
        d, qx, qy, other = best
        mx, my = (x + qx) / 2, (y + qy) / 2
        # The same gap seen from its other end.
        if any(math.hypot(mx - f["mid_x"], my - f["mid_y"]) < 0.05 for f in found):
            continue
        near = [p for p in amap.points if abs(p[0] - mx) < d and abs(p[1] - my) < d]
        found.append({
            "width_m": d, "clear_m": clear_width_m((x, y), (qx, qy), near),
            "mid_x": mx, "mid_y": my, "ax": x, "ay": y, "bx": qx, "by": qy,
            "line_a": own.lineno, "line_b": other.lineno,
        })  # fmt: skip
    found.sort(key=lambda f: -f["clear_m"])
    return found


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map")
    ap.add_argument("--box", type=float, nargs=4, metavar=("X0", "Y0", "X1", "Y1"))
    ap.add_argument("--min", type=float, default=0.5, help="narrowest gap listed (m)")
    ap.add_argument("--max", type=float, default=1.6, help="widest gap listed (m)")
    args = ap.parse_args()
    rows = doorways(args.map, args.min, args.max, tuple(args.box) if args.box else None)
    print("| width m | clear m | middle (x, y) | from (x, y) | to (x, y) | map lines |")
    print("|---|---|---|---|---|---|")
    for f in rows:
        print(
            f"| {f['width_m']:.2f} | {f['clear_m']:.2f} | ({f['mid_x']:.2f}, {f['mid_y']:.2f}) "
            f"| ({f['ax']:.2f}, {f['ay']:.2f}) | ({f['bx']:.2f}, {f['by']:.2f}) "
            f"| {f['line_a']}, {f['line_b']} |"
        )


if __name__ == "__main__":
    main()
