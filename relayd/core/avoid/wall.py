"""The escape's boundary following (WALL) and outer corners (CORNER): the Bug family's part.

The handler relayd.core.avoid.escape runs last in a step: it follows the obstacle's
boundary on side w = -side, turns into an opening abeam toward the leader, rounds an outer
corner, and leaves toward the leader once its direction is open and the robot is further
along the leader's line than where it hit (Bug2; docs/AVOIDANCE.md).
"""

from __future__ import annotations

import math
from dataclasses import replace

from relayd.core.avoid.ring import LATERAL_M, lane_clear, leader_clear, min_at, wall_fit
from relayd.core.avoid.state import (
    AvoidCommand,
    AvoidMode,
    AvoidState,
    StepView,
    Verdict,
    drive_cmd,
    enter,
    turn_cmd,
)
from relayd.core.geometry import HALF_WIDTH_M, wrap_deg
from relayd.core.scan.estimator import SONAR_MAX_RANGE_M
from relayd.core.vocab import Reason


def proj_m(pose: tuple[float, float, float], goal_deg: float) -> float:
    """How far along the leader's line (heading goal_deg) a pose lies, in metres."""
    g = math.radians(goal_deg)
    return (pose[0] * math.cos(g) + pose[1] * math.sin(g)) / 1000.0


def on_wall(st: AvoidState, v: StepView) -> Verdict:
    """Boundary following, the boundary on side w = -side; also ends every hand-over."""
    s, p, t, r, act = v.s, v.p, v.t, v.r, v.act
    w = -st.side
    progress = proj_m(s.pose, st.goal_deg) - st.hit_proj_m
    door = abs(s.bearing_deg) >= 60.0 and s.bearing_deg * w > 0
    if door and r.get(w * 90.0, SONAR_MAX_RANGE_M) > p.leave_clear_m:
        # An opening abeam toward the leader: turn into it from its middle, not its edge.
        st = replace(st, opening_at=st.opening_at or s.pose[:2])
        door = math.dist(st.opening_at or s.pose[:2], s.pose[:2]) >= p.door_run_m * 1000.0
        if not door:
            return st, drive_cmd(act, s, p, p.wall_speed_mm_s, 0.0)
    else:
        st = replace(st, opening_at=None)
    if progress > (p.door_progress_m if door else p.leave_progress_m) and way_open(v, w):
        st = enter(st, AvoidMode.ALIGN, t)
        if abs(s.bearing_deg) <= p.align_tol_deg:
            st = enter(st, AvoidMode.FOLLOW, t, anchor=s.pose[:2], anchor_t=t)
            return st, AvoidCommand(True)
        return st, turn_cmd(
            act, s, p, math.copysign(p.turn_rate_deg_s, s.bearing_deg), Reason.REJOINING
        )
    if min_at(r, (10.0, -10.0, 30.0 * w)) < p.front_clear_m or v.d_min_m < p.stop_distance_m:
        if st.lost_at is not None:
            # Blocked while rounding an outer corner: the way on is round it, toward the wall.
            return corner(st, v, w)
        st = enter(st, AvoidMode.TURN, t)
        return st, turn_cmd(act, s, p, st.side * p.turn_rate_deg_s, Reason.AVOIDING)
    fit = wall_fit(r, w, p.fit_range_m)
    if fit is None and not st.had_wall:
        # Turned away from it and it is not beside us yet: drive on, past it, until it is.
        return st, drive_cmd(act, s, p, p.wall_speed_mm_s, 0.0)
    if fit is None:
        lost = st.lost_at or s.pose[:2]
        st = replace(st, lost_at=lost)
        if math.dist(lost, s.pose[:2]) >= p.corner_run_m * 1000.0:
            return corner(st, v, w)
        return st, drive_cmd(act, s, p, p.wall_speed_mm_s, 0.0)
    st = replace(st, lost_at=None, had_wall=True)
    lateral, angle = fit
    target = HALF_WIDTH_M + p.wall_gap_m
    other = min(
        (
            LATERAL_M[h] + r.get(-w * h, SONAR_MAX_RANGE_M) * math.sin(math.radians(h))
            for h in (90.0, 50.0)
        ),
        default=SONAR_MAX_RANGE_M,
    )
    if lateral + other < 2.0 * target:
        target = (lateral + other) / 2.0  # a narrow gap: keep to its middle
    rvel = p.wall_angle_gain * angle + w * p.wall_gain_deg_s_per_m * (lateral - target)
    rvel = max(-p.turn_rate_deg_s, min(p.turn_rate_deg_s, rvel))
    return st, drive_cmd(act, s, p, p.wall_speed_mm_s, rvel)


def way_open(v: StepView, w: int = 0) -> bool:
    """The escape may leave for the leader: its way is open (AvoidParams.leave_by_lane)."""
    p, r, bearing = v.p, v.r, v.s.bearing_deg
    if p.leave_by_lane and abs(bearing) < 60.0:
        return lane_clear(r, bearing, p.leave_clear_m, HALF_WIDTH_M + p.leave_lane_margin_m)
    return leader_clear(r, bearing, p.leave_clear_m, w)


def corner(st: AvoidState, v: StepView, w: int) -> Verdict:
    """Round an outer corner: turn 90 degrees toward the boundary's side w."""
    st = enter(
        st,
        AvoidMode.CORNER,
        v.t,
        lost_at=None,
        corner_heading_deg=wrap_deg(v.s.pose[2] + w * 90.0),
    )
    return st, turn_cmd(v.act, v.s, v.p, w * v.p.turn_rate_deg_s, Reason.AVOIDING)
