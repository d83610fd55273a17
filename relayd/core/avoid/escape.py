"""Getting past obstacles without deadlock: a pure, bounded escape state machine.

The paper's situation 1 (steer by the sonar centroid, slow down towards the stop
distance) cannot get a robot past an obstacle that is symmetric about its path: the
centroid is 0, the speed scale is 0, and the robot stands still for good. This module
is the layer that notices that and does something the robot can really execute. It is
pure: the time, the odometry pose, the sonars and the leader's bearing come in a
`Sense`, the memory in an `AvoidState`, and `avoid_step` returns both the new state and
the command; nothing here reads a clock. docs/AVOIDANCE.md has the state diagram.

- FOLLOW: the paper's law drives; a watchdog says "blocked" when a forward sonar reads
  below the stop distance, or the robot has not moved `progress_m` in `no_progress_s`
  while the link rule says its leader is beyond.
- An escape begins. A leader `align_first_deg` (60) or more off the nose is not beyond
  what blocks the way (it is round a corner the robot overran, or behind it): ALIGN
  first, turning onto it; only what then blocks the way to it is gone round. Otherwise
  the side is latched for the whole episode (the freer side; a tie
  goes to the leader's side, bearing 0 to the left). BACKOFF first when the robot is
  closer than `backoff_below_m` and the rear sonars show room. In a passage (a boundary
  abeam on the free side) LANE: run beside that boundary, or down the middle of a
  narrow gap, past the obstacle. Otherwise TURN in place toward the free side until the
  front is open, then WALL: boundary following (Bug family) with the obstacle on the
  other side; an inner corner goes back to TURN, a lost boundary runs `corner_run_m`
  on and turns 90 degrees toward it (CORNER). Leave (tangent-bug style) when the
  leader's direction is open and the robot is further along the leader's line than
  where it hit (Bug2; a door abeam may be level with the hit point): ALIGN (turn in
  place onto the leader's bearing), then FOLLOW.
- BLOCKED: the escape exceeded `max_escape_s`, `max_escape_m` or `max_turn_deg`, or
  took the robot more than `max_stray_m` from where it took over from the paper's law:
  wheels zero, reason `blocked`, until the leader's direction is open ahead again.

The escape's vocabulary (modes, settings, memory, one step's view and verdict) and
the guarded turn and drive commands are in relayd/core/avoid/state.py.
"""

from __future__ import annotations

import math
from dataclasses import replace

from relayd.core.avoid.ring import (
    LATERAL_M,
    REAR_M,
    boundary_echo_m,
    by_heading,
    choose_side,
    echo_m,
    forward_min_m,
    guard,
    leader_clear,
    min_at,
    rear_min_m,
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
    turn_cmd,
)
from relayd.core.control.actuator import Actuator
from relayd.core.geometry import HALF_WIDTH_M, wrap_deg
from relayd.core.scan.estimator import SONAR_MAX_RANGE_M


def _proj_m(pose: tuple[float, float, float], goal_deg: float) -> float:
    g = math.radians(goal_deg)
    return (pose[0] * math.cos(g) + pose[1] * math.sin(g)) / 1000.0


def _strayed(st: AvoidState, s: Sense, p: AvoidParams) -> bool:
    """The escape (not the paper's law) has taken the robot beyond max_stray_m of where it
    took over: a relay in a building is then going round the building, away from its
    leader and its link behind, not round an obstacle."""
    return (
        st.mode is not AvoidMode.FOLLOW
        and st.hit_at is not None
        and math.dist(st.hit_at, s.pose[:2]) > p.max_stray_m * 1000.0
    )


def _bookkeep(st: AvoidState, s: Sense) -> AvoidState:
    """Path and turn accumulated since the last step, for the escape limits."""
    if st.last_pose is None:
        return replace(st, last_pose=s.pose)
    x0, y0, th0 = st.last_pose
    step_m = math.hypot(s.pose[0] - x0, s.pose[1] - y0) / 1000.0
    dth = abs(wrap_deg(s.pose[2] - th0))
    if st.escape_t is not None:
        st = replace(st, path_m=st.path_m + step_m, turned_deg=st.turned_deg + dth)
    return replace(st, last_pose=s.pose)


def avoid_step(
    st: AvoidState, s: Sense, p: AvoidParams, act: Actuator
) -> tuple[AvoidState, AvoidCommand]:
    """One decision while the link rule says drive; see the module docstring."""
    new, cmd = _avoid_step(st, s, p, act)
    if new.mode is not st.mode:
        new = replace(new, mode_heading_deg=s.pose[2], had_wall=False)
    return new, cmd


# Complexity: the escape's modes fall through one function; the state table (issue 24) replaces it.
def _avoid_step(  # noqa: C901
    st: AvoidState, s: Sense, p: AvoidParams, act: Actuator
) -> tuple[AvoidState, AvoidCommand]:
    st = _bookkeep(st, s)
    r = by_heading(s.sonar)
    d_min = min((d for h, d in r.items() if abs(h) < 90.0), default=SONAR_MAX_RANGE_M)
    t = s.t_s

    if (
        st.escape_t is not None
        and st.mode is not AvoidMode.BLOCKED
        and (
            t - st.escape_t > p.max_escape_s
            or st.path_m > p.max_escape_m
            or st.turned_deg > p.max_turn_deg
            or _strayed(st, s, p)
        )
    ):
        return enter(st, AvoidMode.BLOCKED, t), AvoidCommand(False, reason="blocked")

    if st.mode is AvoidMode.BLOCKED:
        if (
            abs(s.bearing_deg) < 30.0
            and leader_clear(r, s.bearing_deg, p.leave_clear_m)
            and d_min > p.threshold_o_m
        ):
            st = enter(
                AvoidState(), AvoidMode.FOLLOW, t, anchor=s.pose[:2], anchor_t=t, last_pose=s.pose
            )
            return st, AvoidCommand(True)
        return st, AvoidCommand(False, reason="blocked")

    if st.mode is AvoidMode.FOLLOW:
        if st.anchor is None or math.dist(st.anchor, s.pose[:2]) > p.progress_m * 1000.0:
            st = replace(st, anchor=s.pose[:2], anchor_t=t)
        if st.escape_t is not None:
            # An episode ends once the robot has run free for a while.
            since = st.clear_since_t if d_min > p.threshold_o_m else None
            if d_min > p.threshold_o_m and since is None:
                since = t
            st = replace(st, clear_since_t=since)
            if since is not None and t - since > p.episode_clear_s:
                st = replace(
                    st,
                    escape_t=None,
                    side=0,
                    path_m=0.0,
                    turned_deg=0.0,
                    clear_since_t=None,
                    hit_at=None,
                )
        stuck = t - st.anchor_t > p.no_progress_s
        if d_min >= p.stop_distance_m and not stuck:
            return st, AvoidCommand(True)
        st = replace(st, hit_at=s.pose[:2], clear_since_t=None)
        if st.escape_t is None:
            st = replace(
                st,
                escape_t=t,
                path_m=0.0,
                turned_deg=0.0,
                side=0,
                goal_deg=s.pose[2] + s.bearing_deg,
                hit_proj_m=_proj_m(s.pose, s.pose[2] + s.bearing_deg),
            )
            if abs(s.bearing_deg) >= p.align_first_deg:
                # The leader is off to a side or behind (round a corner the robot overran):
                # what blocks the way ahead is not between them, and going round it would
                # take the robot away. Turn onto the leader first; the side is chosen only
                # if something blocks that way too.
                st = enter(st, AvoidMode.ALIGN, t)
        if st.mode is AvoidMode.FOLLOW:
            if st.side == 0:
                st = replace(st, side=choose_side(s.sonar, s.bearing_deg, p.tie_m))
            st = enter(st, AvoidMode.TURN, t)
            if d_min < p.backoff_below_m and rear_min_m(s.rear) > p.stop_distance_m + 0.1:
                st = enter(
                    st,
                    AvoidMode.BACKOFF,
                    t,
                    backoff_from=s.pose[:2],
                    backoff_len_m=p.backoff_max_m,
                    unjam=False,
                )
            else:
                st = _maybe_lane(st, s, r, p, t)

    if st.mode is AvoidMode.BACKOFF:
        if st.backoff_from is None:  # entered without its origin: back off from here
            st = replace(st, backoff_from=s.pose[:2])
        backed = math.dist(st.backoff_from or s.pose[:2], s.pose[:2]) / 1000.0
        # A back-off after the hit stops once the obstacle is far enough ahead; one to
        # unjam a turn runs its whole length, because what stops the turn is beside the
        # robot (a door's jambs), and the way ahead may be wide open.
        if (
            (st.unjam or d_min < p.backoff_to_m)
            and backed < st.backoff_len_m
            and rear_min_m(s.rear) > p.stop_distance_m + 0.1
        ):
            vel, _ = guard(
                -act.express(p.backoff_speed_mm_s, 0.0)[0], 0, s.sonar, p.stop_distance_m, s.rear
            )
            reason = "rejoining" if st.after_backoff is AvoidMode.ALIGN else "avoiding"
            return st, AvoidCommand(False, vel, 0, reason)
        after = st.after_backoff
        st = enter(st, after, t, backoff_from=None, after_backoff=AvoidMode.TURN)
        if after is AvoidMode.TURN:
            # Only an escape's first move may become a lane change: after an ALIGN's
            # back-off the way is onto the leader, not along the latched side.
            st = _maybe_lane(st, s, r, p, t)

    if st.mode is AvoidMode.LANE:
        st, cmd = _lane(st, s, r, p, act, t)
        if cmd is not None:
            return st, cmd

    if st.mode is AvoidMode.ALIGN:
        if abs(s.bearing_deg) <= p.align_tol_deg:
            st = enter(st, AvoidMode.FOLLOW, t, anchor=s.pose[:2], anchor_t=t)
            return st, AvoidCommand(True)
        cmd = turn_cmd(act, s, p, math.copysign(p.turn_rate_deg_s, s.bearing_deg), "rejoining")
        if cmd.rvel_deg_s != 0:
            return st, cmd
        if rear_min_m(s.rear) > p.stop_distance_m + 0.1:
            # No room to turn here (in a doorway): back off a little and turn there.
            st = enter(
                st,
                AvoidMode.BACKOFF,
                t,
                backoff_from=s.pose[:2],
                backoff_len_m=p.unjam_m,
                unjam=True,
                after_backoff=AvoidMode.ALIGN,
            )
            vel, _ = guard(
                -act.express(p.backoff_speed_mm_s, 0.0)[0], 0, s.sonar, p.stop_distance_m, s.rear
            )
            return st, AvoidCommand(False, vel, 0, "rejoining")
        # Too close to turn: keep rounding (on the freer side, if none is latched yet).
        side = st.side or choose_side(s.sonar, s.bearing_deg, p.tie_m)
        st = enter(st, AvoidMode.WALL, t, lost_at=None, side=side)

    if st.mode is AvoidMode.TURN:
        front = min_at(r, (10.0, -10.0, 30.0, -30.0))
        turned = abs(wrap_deg(s.pose[2] - st.mode_heading_deg))
        if (
            front > p.front_clear_m
            and min_at(r, (50.0 * -st.side,)) > p.stop_distance_m
            and (front > p.turn_clear_m or turned >= p.turn_max_deg)
        ):
            st = enter(st, AvoidMode.WALL, t, lost_at=None)
        else:
            cmd = turn_cmd(act, s, p, st.side * p.turn_rate_deg_s, "avoiding")
            if cmd.rvel_deg_s == 0 and rear_min_m(s.rear) > p.stop_distance_m + 0.1:
                # No room to turn here (a corner, a passage): back off a little and retry.
                st = enter(
                    st,
                    AvoidMode.BACKOFF,
                    t,
                    backoff_from=s.pose[:2],
                    backoff_len_m=p.unjam_m,
                    unjam=True,
                )
                vel, _ = guard(
                    -act.express(p.backoff_speed_mm_s, 0.0)[0],
                    0,
                    s.sonar,
                    p.stop_distance_m,
                    s.rear,
                )
                return st, AvoidCommand(False, vel, 0, "avoiding")
            return st, cmd

    if st.mode is AvoidMode.CORNER:
        # A corner without its target heading is over (follow the wall again).
        if (
            st.corner_heading_deg is None
            or abs(wrap_deg(s.pose[2] - st.corner_heading_deg)) < 5.0
            or d_min < p.stop_distance_m
        ):
            st = enter(st, AvoidMode.WALL, t, lost_at=None, corner_heading_deg=None)
        else:
            return st, turn_cmd(act, s, p, -st.side * p.turn_rate_deg_s, "avoiding")

    # WALL: the boundary is on side w = -side.
    w = -st.side
    progress = _proj_m(s.pose, st.goal_deg) - st.hit_proj_m
    door = abs(s.bearing_deg) >= 60.0 and s.bearing_deg * w > 0
    if door and r.get(w * 90.0, SONAR_MAX_RANGE_M) > p.leave_clear_m:
        # An opening abeam toward the leader: turn into it from its middle, not its edge.
        st = replace(st, opening_at=st.opening_at or s.pose[:2])
        door = math.dist(st.opening_at or s.pose[:2], s.pose[:2]) >= p.door_run_m * 1000.0
        if not door:
            return st, drive_cmd(act, s, p, p.wall_speed_mm_s, 0.0)
    else:
        st = replace(st, opening_at=None)
    if progress > (p.door_progress_m if door else p.leave_progress_m) and leader_clear(
        r, s.bearing_deg, p.leave_clear_m, w
    ):
        st = enter(st, AvoidMode.ALIGN, t)
        if abs(s.bearing_deg) <= p.align_tol_deg:
            st = enter(st, AvoidMode.FOLLOW, t, anchor=s.pose[:2], anchor_t=t)
            return st, AvoidCommand(True)
        return st, turn_cmd(act, s, p, math.copysign(p.turn_rate_deg_s, s.bearing_deg), "rejoining")
    if min_at(r, (10.0, -10.0, 30.0 * w)) < p.front_clear_m or d_min < p.stop_distance_m:
        if st.lost_at is not None:
            # Blocked while rounding an outer corner: the way on is round it, toward the wall.
            st = enter(
                st,
                AvoidMode.CORNER,
                t,
                lost_at=None,
                corner_heading_deg=wrap_deg(s.pose[2] + w * 90.0),
            )
            return st, turn_cmd(act, s, p, w * p.turn_rate_deg_s, "avoiding")
        st = enter(st, AvoidMode.TURN, t)
        return st, turn_cmd(act, s, p, st.side * p.turn_rate_deg_s, "avoiding")
    fit = wall_fit(r, w, p.fit_range_m)
    if fit is None and not st.had_wall:
        # Turned away from it and it is not beside us yet: drive on, past it, until it is.
        return st, drive_cmd(act, s, p, p.wall_speed_mm_s, 0.0)
    if fit is None:
        lost = st.lost_at or s.pose[:2]
        st = replace(st, lost_at=lost)
        if math.dist(lost, s.pose[:2]) >= p.corner_run_m * 1000.0:
            st = enter(
                st,
                AvoidMode.CORNER,
                t,
                lost_at=None,
                corner_heading_deg=wrap_deg(s.pose[2] + w * 90.0),
            )
            return st, turn_cmd(act, s, p, w * p.turn_rate_deg_s, "avoiding")
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


def _maybe_lane(
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
    return enter(st, AvoidMode.LANE, t, lane_ref=s.pose)


def _lane(
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
    rear_abeam = [echo_m(x) for x in s.rear if x.index == (15 if w > 0 else 8)]
    passed = (
        along > 0.5
        and min_at(r, tuple(w * h for h in (90.0, 50.0, 30.0))) > p.leave_clear_m
        and min(rear_abeam, default=SONAR_MAX_RANGE_M) > p.leave_clear_m
    )
    if passed and forward_min_m(s.sonar) >= p.threshold_o_m:
        # Out of the gap and clear of its sides: the paper's law takes over, turning
        # gently onto the leader as it drives.
        return enter(
            st, AvoidMode.FOLLOW, t, lane_ref=None, anchor=s.pose[:2], anchor_t=t
        ), AvoidCommand(True)
    if max(r.get(10.0, SONAR_MAX_RANGE_M), r.get(-10.0, SONAR_MAX_RANGE_M)) < p.front_clear_m:
        # Both forward sonars close: something across the lane (a diagonal approach to
        # the side boundary shows in one of them only). Go round it instead.
        return enter(st, AvoidMode.TURN, t, lane_ref=None), None
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
        return enter(st, AvoidMode.TURN, t, lane_ref=None), None
    rvel = max(-p.turn_rate_deg_s, min(p.turn_rate_deg_s, 2.0 * err))
    # Keep rolling while turning: between close boundaries there is no room to turn in
    # place, only to arc (the guard still stops the wheels before anything in the path).
    vel = p.lane_speed_mm_s * max(0.4, math.cos(math.radians(min(90.0, 3.0 * abs(err)))))
    cmd = drive_cmd(act, s, p, vel, rvel)
    if cmd.vel_mm_s == 0 and cmd.rvel_deg_s == 0 and forward_min_m(s.sonar) < p.front_clear_m:
        return enter(st, AvoidMode.TURN, t, lane_ref=None), None  # the lane is shut: go round
    return st, cmd
