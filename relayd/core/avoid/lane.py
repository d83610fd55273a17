"""The escape's lane change: in a passage, run beside the free side's boundary past the obstacle.

A handler's helpers for relayd.core.avoid.escape (LANE): a passage has no room to turn
in place and follow the obstacle's face, so the robot arcs past it at the lane's
distance and hands back to the paper's law (docs/AVOIDANCE.md).
"""

from __future__ import annotations

import math
from dataclasses import replace

from relayd.core.avoid.ring import (
    LATERAL_M,
    REAR_M,
    REAR_SIDE_SONAR,
    boundary_echo_m,
    echo_m,
    forward_min_m,
    lane_clear,
    min_at,
    wall_fit,
)
from relayd.core.avoid.state import (
    AvoidCommand,
    AvoidMode,
    AvoidParams,
    AvoidState,
    Sense,
    drive_cmd,
    enter,
)
from relayd.core.control.actuator import Actuator
from relayd.core.geometry import HALF_WIDTH_M, wrap_deg
from relayd.core.scan.estimator import SONAR_MAX_RANGE_M


def maybe_lane(
    st: AvoidState, s: Sense, r: dict[float, float], p: AvoidParams, t: float
) -> AvoidState:
    """In a passage (a boundary abeam on the free side), change lanes instead of turning:
    there is no room to turn in place and follow the obstacle's face."""
    free = r.get(st.side * 90.0, SONAR_MAX_RANGE_M)
    fit = wall_fit(r, st.side, p.fit_range_m, edge=True)
    if free > p.lane_detect_m or fit is None:
        return st
    shift = fit[0] - HALF_WIDTH_M - p.lane_margin_m
    if shift < p.lane_min_shift_m:
        return st
    # The lane must be open ahead: the free side's 30/50 degree sonars may see only the
    # side boundary (their nearest echo off it, at the beam edge), nothing nearer.
    for h in (30.0, 50.0):
        expected = boundary_echo_m(fit, st.side, st.side * h)
        if r.get(st.side * h, SONAR_MAX_RANGE_M) < expected - 0.15:
            return st
    return enter(st, AvoidMode.LANE, t, lane_ref=s.pose, lane_beside=False, lane_near_m=None)


def lane_step(
    st: AvoidState, s: Sense, r: dict[float, float], p: AvoidParams, act: Actuator, t: float
) -> tuple[AvoidState, AvoidCommand | None]:
    """Run beside the free side's boundary at the lane's distance (the middle of a narrow
    gap once the obstacle is abeam) until the obstacle is behind, then drift back and
    hand over to the paper's law; None hands over to TURN (the lane is shut)."""
    if st.lane_ref is None:  # no lane to keep: hand over to TURN, as a shut lane does
        return st, None
    x0, y0, h0 = st.lane_ref
    along = (
        (s.pose[0] - x0) * math.cos(math.radians(h0))
        + (s.pose[1] - y0) * math.sin(math.radians(h0))
    ) / 1000.0
    w = -st.side  # the obstacle's side
    # Past the obstacle once the sonars on its side, the rear one abeam included (the
    # robot's back half is still beside it when the front ring clears), see open space.
    rear_abeam = [echo_m(x) for x in s.rear if x.index == REAR_SIDE_SONAR[w]]
    abeam_m = min([r.get(w * 90.0, SONAR_MAX_RANGE_M), *rear_abeam])
    near_m = abeam_m if st.lane_near_m is None else min(st.lane_near_m, abeam_m)
    st = replace(st, lane_near_m=near_m)
    clear_m = p.leave_clear_m
    if p.lane_pass_margin_m > 0.0:
        clear_m = min(clear_m, near_m + p.lane_pass_margin_m)
    passed = (
        along > 0.5
        and min_at(r, tuple(w * h for h in (90.0, 50.0, 30.0))) > clear_m
        and min(rear_abeam, default=SONAR_MAX_RANGE_M) > clear_m
    )
    # Out of the gap and clear of its sides: the paper's law takes over, turning gently
    # onto the leader as it drives.
    leave = passed and forward_min_m(s.sonar) >= p.threshold_o_m
    if p.leave_by_lane and not passed:
        # In a corridor the obstacle side's far wall may never be leave_clear_m away: past
        # it once nothing is abeam on that side within the robot's own width, front or
        # back, and the lane to the leader is free (ring.lane_clear).
        beside = min([r.get(w * 90.0, SONAR_MAX_RANGE_M), *rear_abeam]) <= 2.0 * HALF_WIDTH_M
        if beside and not st.lane_beside:
            st = replace(st, lane_beside=True)
        leave = (
            st.lane_beside
            and not beside
            and lane_clear(r, s.bearing_deg, p.leave_clear_m, HALF_WIDTH_M + p.leave_lane_margin_m)
        )
    if leave:
        return enter(
            st,
            AvoidMode.FOLLOW,
            t,
            lane_ref=None,
            lane_beside=False,
            lane_near_m=None,
            anchor=s.pose[:2],
            anchor_t=t,
        ), AvoidCommand(True)
    if max(r.get(10.0, SONAR_MAX_RANGE_M), r.get(-10.0, SONAR_MAX_RANGE_M)) < p.front_clear_m:
        # Both forward sonars close: something across the lane (a diagonal approach to
        # the side boundary shows in one of them only). Go round it instead.
        return enter(st, AvoidMode.TURN, t, lane_ref=None, lane_near_m=None), None
    fit = wall_fit(r, st.side, p.fit_range_m, edge=True)
    if fit is not None:
        # The free side's boundary is in reach: run parallel to it at the lane's distance
        # (or down the middle between it and the obstacle once that is abeam).
        wall_lat, wall_angle = fit
        want = HALF_WIDTH_M + p.lane_margin_m
        # An echo at the edge of the abeam beam is no nearer than r cos 15 sideways.
        obstacle_lat = LATERAL_M[90.0] + r.get(w * 90.0, SONAR_MAX_RANGE_M) * math.cos(
            math.radians(15.0)
        )
        if passed:
            # Past it: drift back toward the middle of the passage, then hand back.
            want = min(
                (wall_lat + LATERAL_M[90.0] + r.get(w * 90.0, SONAR_MAX_RANGE_M)) / 2.0,
                wall_lat + 0.1,
            )
        elif obstacle_lat < want:
            # Nearer the obstacle than the lane asks: the gap is narrow, keep to its middle.
            # (Only this way round: an echo off the obstacle's far corner, at the edge of
            # the abeam beam, must not pull the robot toward it.)
            want = (wall_lat + obstacle_lat) / 2.0
        toward = max(
            -p.lane_max_deg, min(p.lane_max_deg, p.lane_gain_deg_per_m * (wall_lat - want))
        )
        # Heading away from that boundary swings the tail toward it (the centre is 0.31 m
        # ahead of the rear corners): only as far as keeps the tail corner at the margin.
        spare = wall_lat - HALF_WIDTH_M - (p.lane_margin_m - 0.02)
        toward = max(toward, -math.degrees(math.asin(max(0.0, min(1.0, spare / REAR_M)))))
        err = wrap_deg(st.side * toward + wall_angle)
    else:
        # The boundary that made this a passage is gone: no lane to keep, go round instead.
        return enter(st, AvoidMode.TURN, t, lane_ref=None, lane_near_m=None), None
    rvel = max(-p.turn_rate_deg_s, min(p.turn_rate_deg_s, 2.0 * err))
    # Keep rolling while turning: between close boundaries there is no room to turn in
    # place, only to arc (the guard still stops the wheels before anything in the path).
    vel = p.lane_speed_mm_s * max(0.4, math.cos(math.radians(min(90.0, 3.0 * abs(err)))))
    cmd = drive_cmd(act, s, p, vel, rvel)
    if cmd.vel_mm_s == 0 and cmd.rvel_deg_s == 0 and forward_min_m(s.sonar) < p.front_clear_m:
        # The lane is shut: go round.
        return enter(st, AvoidMode.TURN, t, lane_ref=None, lane_near_m=None), None
    return st, cmd
