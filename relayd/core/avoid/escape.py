"""Getting past obstacles without deadlock: a pure, bounded escape state machine.

The paper's situation 1 cannot get a robot past an obstacle symmetric about its path
(the centroid is 0, the speed scale 0). `avoid_step` notices that and runs an escape:
one handler per mode (HANDLERS: FOLLOW, BACKOFF, ALIGN, LANE, TURN, WALL, CORNER,
BLOCKED, DOOR) over the escape's memory, with the hand-overs within one step as a table
(HANDS_OVER). It promises: each escape is bounded (time, distance, turning, stray from
where it took over; then BLOCKED with wheels at zero, and a fresh escape only after a
wait that doubles with each block of a run, blocked_retry_s to blocked_retry_max_s), and
its commands are guarded by the sonars. The state diagram and each rule:
docs/AVOIDANCE.md. The vocabulary and the guarded commands are in
relayd/core/avoid/state.py; the lane and the boundary following in lane.py and wall.py,
the creep past a refused turn in unpin.py. Pure: time, pose, sonars and bearing come in
a `Sense`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

from relayd.core.avoid.door import at_door, door_step
from relayd.core.avoid.lane import lane_step, maybe_lane
from relayd.core.avoid.ring import (
    AHEAD_DEG,
    TURN_MARGIN_M,
    by_heading,
    choose_side,
    guard,
    min_at,
    rear_min_m,
    wall_along_side,
)
from relayd.core.avoid.state import (
    AvoidCommand,
    AvoidMode,
    AvoidParams,
    AvoidState,
    Sense,
    StepView,
    Verdict,
    enter,
    turn_cmd,
)
from relayd.core.avoid.unpin import creep_beside, straight_on, unpin_cmd
from relayd.core.avoid.wall import on_wall, proj_m, way_open
from relayd.core.control.actuator import Actuator
from relayd.core.geometry import wrap_deg
from relayd.core.scan.estimator import SONAR_MAX_RANGE_M
from relayd.core.vocab import Reason


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
    new, cmd = _step(st, s, p, act)
    if new.mode is not st.mode:
        new = replace(new, mode_heading_deg=s.pose[2], had_wall=False)
    return new, cmd


def _step(
    st: AvoidState, s: Sense, p: AvoidParams, act: Actuator
) -> tuple[AvoidState, AvoidCommand]:
    st = _bookkeep(st, s)
    r = by_heading(s.sonar)
    d_min = min((d for h, d in r.items() if abs(h) < 90.0), default=SONAR_MAX_RANGE_M)
    v = StepView(s, p, act, r, d_min, s.t_s)
    if (
        st.escape_t is not None
        and st.mode is not AvoidMode.BLOCKED
        and (
            v.t - st.escape_t > p.max_escape_s
            or st.path_m > p.max_escape_m
            or st.turned_deg > p.max_turn_deg
            or _strayed(st, s, p)
        )
    ):
        return enter(st, AvoidMode.BLOCKED, v.t), AvoidCommand(False, reason=Reason.BLOCKED)
    handler = st.mode
    while True:
        st, out = HANDLERS[handler](st, v)
        if isinstance(out, AvoidCommand):
            return st, out
        if out not in HANDS_OVER[handler]:
            # Not a transition of the table: a bug, and the brain's fail-safe stops the wheels.
            raise RuntimeError(f"escape: {handler} may not hand over to {out}")
        handler = out


def _on_blocked(st: AvoidState, v: StepView) -> Verdict:
    s, p = v.s, v.p
    if abs(s.bearing_deg) < 30.0 and way_open(v) and v.d_min_m > p.threshold_o_m:
        st = enter(
            AvoidState(), AvoidMode.FOLLOW, v.t, anchor=s.pose[:2], anchor_t=v.t, last_pose=s.pose
        )
        return st, AvoidCommand(True)
    wait = _retry_wait(st, p)
    if wait > 0.0 and v.t - st.mode_t >= wait:
        # The wait is over: a fresh escape from here, toward where the scans put the
        # leader now (which a dead end's limits never look at again); the next block
        # waits twice as long.
        fresh = AvoidState(retry_wait_s=wait)
        st = enter(fresh, AvoidMode.FOLLOW, v.t, anchor=s.pose[:2], anchor_t=v.t, last_pose=s.pose)
        return st, AvoidCommand(True)
    return st, AvoidCommand(False, reason=Reason.BLOCKED)


def _retry_wait(st: AvoidState, p: AvoidParams) -> float:
    """How long this block waits before a fresh escape (s); 0: it waits for the leader."""
    if p.blocked_retry_s <= 0.0:
        return 0.0
    return min(p.blocked_retry_max_s, max(p.blocked_retry_s, 2.0 * st.retry_wait_s))


def _on_follow(st: AvoidState, v: StepView) -> Verdict:
    s, p, t, d_min = v.s, v.p, v.t, v.d_min_m
    if st.anchor is None or math.dist(st.anchor, s.pose[:2]) > p.progress_m * 1000.0:
        st = replace(st, anchor=s.pose[:2], anchor_t=t)
    if st.escape_t is not None or st.retry_wait_s > 0.0:
        # An episode ends once the robot has run free for a while (and so does a run of
        # retried blocks, the fresh escape after the last one having no episode yet).
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
                retry_wait_s=0.0,
            )
    stuck = t - st.anchor_t > p.no_progress_s
    if not stuck and at_door(v):
        # A gap the robot fits through, the leader beyond it: through it, not round it
        # (side echoes nearer than the stop distance included). Stuck in it: the escape.
        return enter(st, AvoidMode.DOOR, t), AvoidMode.DOOR
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
            hit_proj_m=proj_m(s.pose, s.pose[2] + s.bearing_deg),
        )
        if abs(s.bearing_deg) >= p.align_first_deg or (
            p.align_open_deg > 0.0 and abs(s.bearing_deg) >= p.align_open_deg and way_open(v)
        ):
            # The leader is off to a side or behind (round a corner the robot overran):
            # what blocks the way ahead is not between them, and going round it would
            # take the robot away. Turn onto the leader first; the side is chosen only
            # if something blocks that way too.
            return enter(st, AvoidMode.ALIGN, t), AvoidMode.ALIGN
    if st.side == 0:
        st = replace(st, side=choose_side(s.sonar, s.bearing_deg, p.tie_m))
    st = enter(st, AvoidMode.TURN, t)
    if (
        d_min < p.backoff_below_m
        and rear_min_m(s.rear) > p.stop_distance_m + 0.1
        and not (p.beside_turn and min_at(v.r, AHEAD_DEG) >= p.backoff_to_m)
    ):
        st = enter(
            st,
            AvoidMode.BACKOFF,
            t,
            backoff_from=s.pose[:2],
            backoff_len_m=p.backoff_max_m,
            unjam=False,
        )
    else:
        st = maybe_lane(st, s, v.r, p, t)
    return st, st.mode


def _on_backoff(st: AvoidState, v: StepView) -> Verdict:
    s, p, t = v.s, v.p, v.t
    if st.backoff_from is None:  # entered without its origin: back off from here
        st = replace(st, backoff_from=s.pose[:2])
    backed = math.dist(st.backoff_from or s.pose[:2], s.pose[:2]) / 1000.0
    # A back-off after the hit stops once the obstacle is far enough ahead; one to
    # unjam a turn runs its whole length, because what stops the turn is beside the
    # robot (a door's jambs), and the way ahead may be wide open.
    if (
        (st.unjam or v.d_min_m < p.backoff_to_m)
        and backed < st.backoff_len_m
        and rear_min_m(s.rear) > p.stop_distance_m + 0.1
    ):
        reason = Reason.REJOINING if st.after_backoff is AvoidMode.ALIGN else Reason.AVOIDING
        return st, _back_off(v, reason)
    after = st.after_backoff
    st = enter(st, after, t, backoff_from=None, after_backoff=AvoidMode.TURN)
    if after is AvoidMode.TURN:
        # Only an escape's first move may become a lane change: after an ALIGN's
        # back-off the way is onto the leader, not along the latched side.
        st = maybe_lane(st, s, v.r, p, t)
    return st, st.mode


def _on_lane(st: AvoidState, v: StepView) -> Verdict:
    if st.lane_ref is None:
        # No lane to keep (a state _maybe_lane never makes): the wall-following rules decide.
        return st, AvoidMode.WALL
    st, cmd = lane_step(st, v.s, v.r, v.p, v.act, v.t)
    return st, (cmd if cmd is not None else st.mode)


def _on_align(st: AvoidState, v: StepView) -> Verdict:
    s, p, t = v.s, v.p, v.t
    if abs(s.bearing_deg) <= p.align_tol_deg:
        st = enter(st, AvoidMode.FOLLOW, t, anchor=s.pose[:2], anchor_t=t)
        return st, AvoidCommand(True)
    cmd = turn_cmd(v.act, s, p, math.copysign(p.turn_rate_deg_s, s.bearing_deg), Reason.REJOINING)
    if cmd.rvel_deg_s != 0:
        return st, cmd
    wall = wall_along_side(s.sonar, s.rear, TURN_MARGIN_M) if p.unpin else 0
    if wall * s.bearing_deg > 0:
        # The leader beyond the wall along the side that jams the turn onto it: creeping
        # off the wall turns away from the leader, and round in circles (generated
        # corridors 78: 187 deg in 21 s); on along the wall instead, where it opens.
        return enter(st, AvoidMode.WALL, t, lost_at=None, side=-wall), AvoidMode.WALL
    if (crept := creep_beside(v, cmd, wall)) is not None:
        return st, crept
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
        return st, _back_off(v, Reason.REJOINING)
    if (ahead := straight_on(v)) is not None:
        # Rounding would hand straight back here, the leader's direction being open, and
        # hold: generated corridors 63 stood so for 87 s.
        return st, ahead
    # Too close to turn: keep rounding (on the freer side, if none is latched yet).
    side = st.side or choose_side(s.sonar, s.bearing_deg, p.tie_m)
    return enter(st, AvoidMode.WALL, t, lost_at=None, side=side), AvoidMode.WALL


def _on_turn(st: AvoidState, v: StepView) -> Verdict:
    s, p, t, r = v.s, v.p, v.t, v.r
    front = min_at(r, AHEAD_DEG)
    turned = abs(wrap_deg(s.pose[2] - st.mode_heading_deg))
    if (
        front > p.front_clear_m
        and min_at(r, (50.0 * -st.side,)) > p.stop_distance_m
        and (front > p.turn_clear_m or turned >= p.turn_max_deg)
    ):
        return enter(st, AvoidMode.WALL, t, lost_at=None), AvoidMode.WALL
    cmd = turn_cmd(v.act, s, p, st.side * p.turn_rate_deg_s, Reason.AVOIDING)
    if cmd.rvel_deg_s == 0 and (crept := creep_beside(v, cmd)) is not None:
        return st, crept
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
        return st, _back_off(v, Reason.AVOIDING)
    if cmd.rvel_deg_s == 0 and p.unpin:
        return st, unpin_cmd(v, cmd)
    return st, cmd


def _on_corner(st: AvoidState, v: StepView) -> Verdict:
    s, p = v.s, v.p
    # A corner without its target heading is over (follow the wall again).
    if (
        st.corner_heading_deg is None
        or abs(wrap_deg(s.pose[2] - st.corner_heading_deg)) < 5.0
        or v.d_min_m < p.stop_distance_m
    ):
        st = enter(st, AvoidMode.WALL, v.t, lost_at=None, corner_heading_deg=None)
        return st, AvoidMode.WALL
    return st, turn_cmd(v.act, s, p, -st.side * p.turn_rate_deg_s, Reason.AVOIDING)


def _back_off(v: StepView, reason: Reason) -> AvoidCommand:
    """Reverse at the back-off speed, as the guard allows it."""
    vel, _ = guard(
        -v.act.express(v.p.backoff_speed_mm_s, 0.0)[0], 0, v.s.sonar, v.p.stop_distance_m, v.s.rear
    )
    return AvoidCommand(False, vel, 0, reason)


Handler = Callable[[AvoidState, StepView], Verdict]

#: One handler per mode (h11's _state.py): what the escape does in each.
HANDLERS: dict[AvoidMode, Handler] = {
    AvoidMode.BLOCKED: _on_blocked,
    AvoidMode.FOLLOW: _on_follow,
    AvoidMode.BACKOFF: _on_backoff,
    AvoidMode.LANE: _on_lane,
    AvoidMode.ALIGN: _on_align,
    AvoidMode.TURN: _on_turn,
    AvoidMode.CORNER: _on_corner,
    AvoidMode.WALL: on_wall,
    AvoidMode.DOOR: door_step,
}

#: The hand-overs within one step: a handler that does not decide names the mode whose
#: handler does. Every hand-over goes further down this order (FOLLOW, BACKOFF, LANE,
#: ALIGN, TURN, CORNER, WALL), so a step ends after at most seven handlers; a pair not in
#: the table raises. A handler's mode changes that end the step (FOLLOW, BLOCKED, TURN,
#: BACKOFF, CORNER entered with a command) are the state diagram in docs/AVOIDANCE.md.
HANDS_OVER: dict[AvoidMode, frozenset[AvoidMode]] = {
    AvoidMode.BLOCKED: frozenset(),
    AvoidMode.FOLLOW: frozenset(
        {AvoidMode.ALIGN, AvoidMode.TURN, AvoidMode.BACKOFF, AvoidMode.LANE, AvoidMode.DOOR}
    ),
    AvoidMode.BACKOFF: frozenset({AvoidMode.TURN, AvoidMode.ALIGN, AvoidMode.LANE}),
    AvoidMode.LANE: frozenset({AvoidMode.TURN, AvoidMode.WALL}),
    AvoidMode.ALIGN: frozenset({AvoidMode.WALL}),
    AvoidMode.TURN: frozenset({AvoidMode.WALL}),
    AvoidMode.CORNER: frozenset({AvoidMode.WALL}),
    AvoidMode.WALL: frozenset(),
    AvoidMode.DOOR: frozenset(),
}
