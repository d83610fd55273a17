"""Breadcrumbs: the relay's own trail, and how to drive back along it in reverse (pure).

A crumb is a pose the relay drove through (odometry x, y) with the RSSI^l and RSSI^b it
had there. `relayd.core.recovery.machine` keeps the trail and decides when to use it; this module
holds the geometry: laying crumbs at a spacing, choosing the crumb to go back to, and
the wheel speeds that reverse toward a crumb with the rear sonars guarding the way.

Reversing: the crumb's angle off the rear axis (ccw +) times a gain is the wheel-speed
difference (a ccw turn swings the rear ccw); more than TURN_IN_PLACE_DEG off, the robot
turns in place. The rear sonars 9..14 act as the front ones do going forward
(docs/CONTROL.md section 3.1): an echo closer than threshold_o slows the robot linearly
and the rear sonar centroid (open space attracts) steers it; closer than stop_distance
it does not move at all: it never backs into an obstacle. No I/O, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from relayd.core.geometry import wrap_deg

#: Rear sonars that guard reversing: headings -130, -150, -170, 170, 150, 130 (P3-AT 9..14).
REAR_SONARS: tuple[int, ...] = (9, 10, 11, 12, 13, 14)
#: Their headings relative to the robot's rear (ccw +), sonar 9 first.
REAR_RELATIVE_DEG: tuple[float, ...] = (50.0, 30.0, 10.0, -10.0, -30.0, -50.0)
#: Turn in place (no reverse motion) while the crumb behind is more than this off the rear axis.
TURN_IN_PLACE_DEG = 50.0
#: A sonar at or beyond this range (mm) has no echo.
NO_ECHO_MM = 5000


@dataclass(frozen=True, slots=True)
class TrailPoint:
    """A point the relay drove through (odometry mm) and what it heard there: the one trail
    type of recovery's breadcrumbs and the retreat's spots."""

    x_mm: float
    y_mm: float
    rssi_l_dbm: float | None = None
    rssi_b_dbm: float | None = None
    #: The retreat's verdict of a rear poll taken here: the hop met its target (None: no poll).
    met: bool | None = None


def add_crumb(
    trail: tuple[TrailPoint, ...],
    x_mm: float,
    y_mm: float,
    rssi_l: float | None,
    rssi_b: float | None,
    *,
    spacing_m: float,
    keep: int,
) -> tuple[TrailPoint, ...]:
    """The trail with a crumb here if the relay moved crumb_spacing_m from the newest one."""
    if trail:
        last = trail[-1]
        if math.hypot(x_mm - last.x_mm, y_mm - last.y_mm) < spacing_m * 1000.0:
            return trail
    trail = (*trail, TrailPoint(x_mm, y_mm, rssi_l, rssi_b))
    return trail[-keep:] if len(trail) > keep else trail


def leader_target(trail: tuple[TrailPoint, ...], threshold_l_dbm: float) -> int | None:
    """The newest crumb where the leader was heard at or above threshold_l; else the best one."""
    best: int | None = None
    for i in range(len(trail) - 1, -1, -1):
        r = trail[i].rssi_l_dbm
        if r is None:
            continue
        if r >= threshold_l_dbm:
            return i
        if best is None or r > (trail[best].rssi_l_dbm or -math.inf):
            best = i
    return best


def _rear_clearance_m(sonar_mm: tuple[int | None, ...]) -> list[float | None]:
    out: list[float | None] = []
    for k in REAR_SONARS:
        r = sonar_mm[k] if k < len(sonar_mm) else None
        out.append(None if r is None or r >= NO_ECHO_MM or r <= 0 else r / 1000.0)
    return out


def _rear_avoid_deg(ranges: list[float | None], gamma_o_m: float) -> float:
    """Sonar centroid of the rear sonars (relative to the rear, ccw +): open space attracts."""
    d = [5.0 if r is None else r for r in ranges]
    top = max(d)
    w = [10.0 ** ((x - top) / gamma_o_m) for x in d]
    return float(sum(wi * a for wi, a in zip(w, REAR_RELATIVE_DEG, strict=True)) / sum(w))


def reverse_toward(
    pose: tuple[float, float, float],
    target: TrailPoint,
    speed_mm_s: float,
    sonar_mm: tuple[int | None, ...],
    *,
    threshold_o_m: float,
    stop_distance_m: float,
    gamma_o_m: float,
    turn_gain_mm_s_deg: float,
) -> tuple[float, float, str]:
    """(left, right, reason) reversing toward a crumb, the rear sonars guarding the way."""
    x, y, th = pose
    want = math.degrees(math.atan2(target.y_mm - y, target.x_mm - x))
    alpha = wrap_deg(want - (th + 180.0))  # target off the rear axis, ccw +
    ranges = _rear_clearance_m(sonar_mm)
    echoes = [r for r in ranges if r is not None]
    d_min = min(echoes) if echoes else None
    reason = "retrace"
    v = speed_mm_s
    if d_min is not None and d_min < threshold_o_m:
        span = threshold_o_m - stop_distance_m
        scale = 0.0 if span <= 0 else min(max((d_min - stop_distance_m) / span, 0.0), 1.0)
        if scale <= 0.0:
            return 0.0, 0.0, "rear_blocked"  # never back into it; wait (the time limit runs)
        v *= scale
        alpha = _rear_avoid_deg(ranges, gamma_o_m)
        reason = "rear_obstacle"
    if abs(alpha) > TURN_IN_PLACE_DEG:
        v = 0.0
    turn = max(-speed_mm_s, min(speed_mm_s, turn_gain_mm_s_deg * alpha))
    # Reverse: both wheels negative; +turn rotates ccw, which swings the rear ccw.
    return -v - turn, -v + turn, reason
