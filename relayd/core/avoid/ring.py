"""What the P3-AT's sonar ring says about moving: geometry of the escape and its guard.

Pure helpers for relayd/core/avoid/escape.py: the front ring by heading, the freer side, whether
an echo may lie in the forward path, room to turn in place (the corners sweep a 0.40 m
circle), the rear ring for backing off, a boundary fitted to one side's sonars, and
`guard`, the last check on every escape command. Ranges in metres; headings in degrees
in the robot frame, counter-clockwise positive; poses from drivers/arcos/sonar.py.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from relayd.core.geometry import (
    HALF_LENGTH_M,
    HALF_WIDTH_M,
    SONAR_HEADINGS_DEG,
    SONAR_POSES,
    wrap_deg,
)
from relayd.core.scan.estimator import SONAR_MAX_RANGE_M, SonarReading

#: Lateral offset (m) of each front-ring transducer from the centreline, by heading.
LATERAL_M: dict[float, float] = {p.heading_deg: abs(p.y_mm) / 1000.0 for p in SONAR_POSES[:8]}
#: Position (m, x forward, y left) of each front-ring transducer, by heading.
POSE_M: dict[float, tuple[float, float]] = {
    p.heading_deg: (p.x_mm / 1000.0, p.y_mm / 1000.0) for p in SONAR_POSES[:8]
}
#: Side echoes within this (m) are fitted as a boundary alongside (lane_clear).
SIDE_FIT_M = 1.5
#: From the centre of rotation back to the rear corners.
REAR_M = HALF_LENGTH_M
#: Clearance kept between the swept circle of a turn in place and any echo.
TURN_MARGIN_M = 0.085


#: The rear sonars that look backwards (headings +-130, +-150, +-170).
REAR_BACK: tuple[int, ...] = (9, 10, 11, 12, 13, 14)
#: The whole rear ring (8 and 15 look sideways from the rear corners).
REAR_RING: tuple[int, ...] = tuple(range(8, 16))
#: The P3-AT's corners are this far from its centre: what a turn in place sweeps.
SWEEP_RADIUS_M = math.hypot(REAR_M, HALF_WIDTH_M)


def rear_readings(ranges_mm: Sequence[int | None]) -> tuple[SonarReading, ...]:
    """The rear ring (8..15) in metres, in index order; a sonar never read is left out."""
    out = []
    for index in REAR_RING:
        mm = ranges_mm[index] if index < len(ranges_mm) else None
        if mm is None or mm < 0:
            continue
        out.append(
            SonarReading(
                SONAR_HEADINGS_DEG[index], None if mm >= 5000 else mm / 1000.0, index=index
            )
        )
    return tuple(out)


def rear_min_m(rear: Sequence[SonarReading]) -> float:
    """Nearest echo behind; 0 when the rear ring is unknown (so the robot never backs blind)."""
    back = [r for r in rear if r.index in REAR_BACK]
    if len(back) < len(REAR_BACK):
        return 0.0
    return min(echo_m(r) for r in back)


def _echo_centre_m(index: int, range_m: float) -> float:
    """Distance from the robot centre of an echo of sonar `index` at `range_m`: the
    nearest the echo may be, anywhere across the +-15 degree beam (a jamb's end, a
    corner) rather than on the axis."""
    pose = SONAR_POSES[index]
    x, y = pose.x_mm / 1000.0, pose.y_mm / 1000.0
    return min(
        math.hypot(x + range_m * math.cos(a), y + range_m * math.sin(a))
        for a in (math.radians(pose.heading_deg + d) for d in (-15.0, 0.0, 15.0))
    )


def turn_room(sonar: Sequence[SonarReading], rear: Sequence[SonarReading], margin_m: float) -> bool:
    """Room to turn in place: no echo of the front ring, nor of the rear ring when known,
    within the corners' sweep plus margin_m of the centre."""
    limit = SWEEP_RADIUS_M + margin_m
    for reading in (*sonar, *rear):
        idx = reading.index
        if idx is None or reading.range_m is None or reading.range_m >= SONAR_MAX_RANGE_M:
            continue
        if _echo_centre_m(idx, reading.range_m) < limit:
            return False
    return True


#: The sonars looking straight out of each side (+1 left, -1 right): the front ring's
#: 0 and 7, the rear ring's 15 and 8 at the rear corners.
SIDE_SONARS: dict[int, tuple[int, int]] = {1: (0, 15), -1: (7, 8)}
#: The rear corner's sonar looking out of each side.
REAR_SIDE_SONAR: dict[int, int] = {side: rear for side, (_, rear) in SIDE_SONARS.items()}
#: The forward sonars that see the way ahead, not beside it (a corridor's walls echo in
#: the 50 and 90 deg sonars).
AHEAD_DEG = (-30.0, -10.0, 10.0, 30.0)
#: How much further than the sweep (m) the rear corner's side sonar may see the same wall.
WALL_ALONG_SLACK_M = 0.15


def wall_along_side(
    sonar: Sequence[SonarReading], rear: Sequence[SonarReading], margin_m: float
) -> int:
    """The side (+1 left, -1 right; 0: neither) where a wall along the robot keeps a turn
    in place from having room: that side's front sonar echoes inside the corners' sweep
    plus margin_m, and its rear corner's sonar sees the same wall (a jamb ends before the
    rear corner). Backing off along a wall gains no room; backing out of a door does.
    Walls along both sides: 0 (no side to creep away from)."""
    ranges = {r.index: r.range_m for r in (*sonar, *rear) if r.index is not None}
    limit = SWEEP_RADIUS_M + margin_m

    def near(index: int, within_m: float) -> bool:
        range_m = ranges.get(index)
        return (
            range_m is not None
            and range_m < SONAR_MAX_RANGE_M
            and _echo_centre_m(index, range_m) < within_m
        )

    sides = [
        side
        for side, (front, back) in SIDE_SONARS.items()
        if near(front, limit) and near(back, limit + WALL_ALONG_SLACK_M)
    ]
    return sides[0] if len(sides) == 1 else 0


def echo_m(reading: SonarReading) -> float:
    r = reading.range_m
    return SONAR_MAX_RANGE_M if r is None or r >= SONAR_MAX_RANGE_M else r


def by_heading(sonar: Sequence[SonarReading]) -> dict[float, float]:
    out: dict[float, float] = {}
    for s in sonar:
        h = wrap_deg(s.heading_deg)
        if abs(h) <= 90.0:
            out[h] = min(out.get(h, SONAR_MAX_RANGE_M), echo_m(s))
    return out


def min_at(r: dict[float, float], headings: Sequence[float]) -> float:
    return min((r[h] for h in headings if h in r), default=SONAR_MAX_RANGE_M)


def forward_min_m(sonar: Sequence[SonarReading]) -> float:
    """d_min over the forward sonars (|heading| < 90)."""
    r = by_heading(sonar)
    return min((d for h, d in r.items() if abs(h) < 90.0), default=SONAR_MAX_RANGE_M)


def side_clearance_m(sonar: Sequence[SonarReading], side: int) -> float:
    """How open one side is: the sum of its three sonars' ranges (left +1, right -1)."""
    r = by_heading(sonar)
    return sum(r.get(side * h, SONAR_MAX_RANGE_M) for h in (90.0, 50.0, 30.0))


def choose_side(sonar: Sequence[SonarReading], bearing_deg: float, tie_m: float) -> int:
    """The freer side; a tie (within tie_m) goes to the leader's side, bearing 0 to the left."""
    diff = side_clearance_m(sonar, 1) - side_clearance_m(sonar, -1)
    if abs(diff) > tie_m:
        return 1 if diff > 0 else -1
    return -1 if bearing_deg < 0 else 1


def in_path_below_m(heading_deg: float) -> float:
    """The range below which an echo of the front-ring sonar at this heading may lie in the
    robot's forward path (its +-15 degree arc crosses the footprint's corridor)."""
    edge = abs(heading_deg) - 15.0
    if edge <= 0.0:
        return math.inf
    return (HALF_WIDTH_M - LATERAL_M.get(heading_deg, 0.0)) / math.sin(math.radians(edge))


def path_blocked(sonar: Sequence[SonarReading], stop_m: float) -> bool:
    """A forward-ring echo nearer than stop_m that may lie in the forward path."""
    return any(d < min(stop_m, in_path_below_m(h)) for h, d in by_heading(sonar).items())


def guard(
    vel: int,
    rvel: int,
    sonar: Sequence[SonarReading],
    stop_m: float,
    rear: Sequence[SonarReading] | None = None,
) -> tuple[int, int]:
    """The last line. No forward motion toward an echo nearer than stop_m in the forward
    path; no reversing unless the rear sonars show stop_m behind; no turn in place toward
    a side whose 50/90 degree sonars read below stop_m, nor with any echo inside the
    circle the corners sweep (0.40 m) plus TURN_MARGIN_M."""
    if vel > 0 and path_blocked(sonar, stop_m):
        vel = 0
    if vel < 0 and (rear is None or rear_min_m(rear) < stop_m):
        vel = 0
    if rvel != 0 and vel == 0:
        side = 1 if rvel > 0 else -1
        if min_at(by_heading(sonar), (side * 90.0, side * 50.0)) < stop_m or not turn_room(
            sonar, rear or (), TURN_MARGIN_M
        ):
            rvel = 0
    return vel, rvel


def leader_clear(
    r: dict[float, float], bearing_deg: float, clear_m: float, wall_side: int = 0
) -> bool:
    """The sonars looking within 25 degrees of the leader all see beyond clear_m; when the
    leader is on the side of the boundary being followed, that side must be open too
    (the boundary has ended), or the robot would turn back into what it is rounding."""
    if abs(bearing_deg) > 100.0:
        return False
    near = [d for h, d in r.items() if abs(h - bearing_deg) <= 25.0]
    if not near or min(near) <= clear_m:
        return False
    if wall_side != 0 and bearing_deg * wall_side > 0:
        if abs(bearing_deg) >= 60.0:
            # The leader abeam, beyond an opening (a door) the abeam sonar sees through.
            return r.get(wall_side * 90.0, SONAR_MAX_RANGE_M) > clear_m
        return min_at(r, tuple(wall_side * h for h in (90.0, 50.0, 30.0))) > clear_m
    return True


def lane_clear(
    r: dict[float, float], bearing_deg: float, clear_m: float, half_width_m: float
) -> bool:
    """No echo in the lane the robot would drive toward the leader: `clear_m` long ahead of
    the centre along the bearing, `half_width_m` each side of its axis. Unlike
    leader_clear, a wall running along the way (a 2 m corridor's side, 0.65 m off) is
    beside the lane, not in it.

    A sonar reports the nearest echo anywhere in its 30 degree cone. An echo that a
    boundary fitted on its side explains (what the sonar would read off that line and
    nothing else, as `boundary_echo_m` works it out) is that line, and the line is what
    is tested against the lane. Any other echo is taken at every angle across its beam,
    except where a neighbour whose cone covers that angle saw further."""
    if abs(bearing_deg) > 100.0:
        return False
    b = math.radians(bearing_deg)
    ux, uy = math.cos(b), math.sin(b)
    explained: set[float] = set()
    for w in (1, -1):
        mine = [w * h for h in (90.0, 50.0, 30.0) if r.get(w * h, SONAR_MAX_RANGE_M) <= SIDE_FIT_M]
        for h in mine:
            # Explained by the boundary the side's *other* echoes show: a lone echo (a box
            # corner) is never its own wall.
            others = {k: v for k, v in r.items() if k != h}
            fit = wall_fit(others, w, SIDE_FIT_M, edge=True)
            if fit is not None and abs(r[h] - boundary_echo_m(fit, w, h)) < 0.1:
                explained.add(h)
        fit = wall_fit(r, w, SIDE_FIT_M, edge=True)
        if fit is None or not explained.intersection(mine):
            continue
        lat, angle = fit
        a = math.radians(angle)
        nx, ny = -w * math.sin(a), w * math.cos(a)  # unit normal toward the boundary
        spread = half_width_m * abs(-uy * nx + ux * ny)
        steps = max(1, math.ceil(clear_m / 0.05))
        if any((nx * ux + ny * uy) * clear_m * k / steps + spread >= lat for k in range(steps + 1)):
            return False
    for h, d in r.items():
        if d >= SONAR_MAX_RANGE_M or h in explained:
            continue
        x0, y0 = POSE_M.get(h, (0.0, 0.0))
        for k in (-15.0, -7.5, 0.0, 7.5, 15.0):
            a = h + k
            if any(abs(a - h2) <= 15.0 and d2 > d + 0.1 for h2, d2 in r.items() if h2 != h):
                continue  # a neighbour saw through there
            x = x0 + d * math.cos(math.radians(a))
            y = y0 + d * math.sin(math.radians(a))
            along, across = x * ux + y * uy, -x * uy + y * ux
            if 0.0 < along <= clear_m and abs(across) < half_width_m:
                return False
    return True


def wall_fit(
    r: dict[float, float], w: int, fit_range_m: float, edge: bool = False
) -> tuple[float, float] | None:
    """(distance from the robot centre to the boundary on side w, its angle to the heading
    in degrees, ccw +) from the two nearest echoes of that side's 90/50/30 sonars; None
    when that side sees nothing within fit_range_m."""
    pts = []
    for h in (90.0, 50.0, 30.0):
        d = r.get(w * h)
        if d is None or d > fit_range_m:
            continue
        pose = POSE_M[w * h]
        # edge: the first echo from a long boundary alongside comes from the beam's edge
        # nearest the perpendicular, not from its axis (the corners of an obstacle being
        # rounded are better placed on the axis).
        a = math.radians(w * (min(h + 15.0, 90.0) if edge else h))
        pts.append((d, pose[0] + d * math.cos(a), pose[1] + d * math.sin(a)))
    if not pts:
        return None
    pts.sort()
    if len(pts) == 1:
        return abs(pts[0][2]), 0.0
    (_, px, py), (_, qx, qy) = pts[0], pts[1]
    ux, uy = qx - px, qy - py
    if ux < 0:
        ux, uy = -ux, -uy
    norm = math.hypot(ux, uy)
    if norm < 1e-6:
        return abs(py), 0.0
    ux, uy = ux / norm, uy / norm
    return abs(px * uy - py * ux), math.degrees(math.atan2(uy, ux))


def boundary_echo_m(
    fit: tuple[float, float], side: int, heading_deg: float, half_beam_deg: float = 15.0
) -> float:
    """The range a front-ring sonar would read off a fitted boundary (distance from the
    centre, angle to the heading) on `side` and nothing else: its beam direction nearest
    the boundary's normal, from the transducer to the line; the maximum if it cannot."""
    lat, angle = fit
    a = math.radians(angle)
    nx, ny = -side * math.sin(a), side * math.cos(a)  # unit normal toward the boundary
    px, py = POSE_M[heading_deg]
    gap = lat - (nx * px + ny * py)
    normal_deg = math.degrees(math.atan2(ny, nx))
    off = max(-half_beam_deg, min(half_beam_deg, wrap_deg(normal_deg - heading_deg)))
    cos_hit = math.cos(math.radians(wrap_deg(normal_deg - (heading_deg + off))))
    if gap <= 0.0 or cos_hit <= 1e-6:
        return SONAR_MAX_RANGE_M
    return min(SONAR_MAX_RANGE_M, gap / cos_hit)
