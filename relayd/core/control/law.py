"""How should the wheels turn? The paper's control law, pure (docs/CONTROL.md sections 3-7).

`control_step(inputs, params, memory)` gives the wheels, drive state, reason and new memory:
the first rule of section 6's order decides; a follow-mode command is rounded by the
actuator, bounded by v_max and passes the sonar guard; only the link rule moves its latch.
"""

from __future__ import annotations

import math
from dataclasses import replace

from relayd.core.avoid.escape import avoid_step
from relayd.core.avoid.ring import guard
from relayd.core.avoid.state import AvoidMode, AvoidState, Sense, episode_only
from relayd.core.control.inputs import ControlInputs as ControlInputs
from relayd.core.control.inputs import ControlMemory as ControlMemory
from relayd.core.control.inputs import ControlOutput as ControlOutput
from relayd.core.control.inputs import not_driving, stopped
from relayd.core.control.modes import clamp, fail_safe_or_mode
from relayd.core.control.params import ControlParams as ControlParams
from relayd.core.control.rangecue import far_by_sonar, release_speed_mm_s
from relayd.core.control.search import SearchState, search_step, search_wheels
from relayd.core.control.steer import (
    SLIDE_MAX_DEG,
    away_from_near_side,
    detour_speed,
    detour_watch,
    off_walls,
    retry_detour,
    situation_speed,
    slide_along_wall,
    speed_scale,
    steering,
    trail_hold,
)
from relayd.core.geometry import wrap_deg
from relayd.core.scan.estimator import (
    SonarReading,
    avoidance_bearing,
    classify_situation,
    nearest_front_m,
)
from relayd.core.trail.blocked import blocked_step
from relayd.core.vocab import DriveState


def within_v_max(out: ControlOutput, params: ControlParams) -> ControlOutput:
    """`out` with no wheel beyond v_max, whichever stage commanded it (recovery and the
    retreat add their turn to their speed: at a first drive's low v_max that once passed
    it): the turn kept, the translation shrunk, as the law does; unchanged within it."""
    if max(abs(out.left_mm_s), abs(out.right_mm_s)) <= params.v_max_mm_s + 1e-9:
        return out
    left, right = params.actuator.express_wheels(out.left_mm_s, out.right_mm_s, params.v_max_mm_s)
    return replace(out, left_mm_s=left, right_mm_s=right)


def background_speed(rssi_leader_dbm: float, w1: float, w2: float, v_max_mm_s: float) -> float:
    """v = -w1 * RSSI^l - w2, clamped to [0, v_max]: faster the fainter the leader."""
    return clamp(-w1 * rssi_leader_dbm - w2, 0.0, v_max_mm_s)


def wheel_law(
    v_mm_s: float,
    bearing_deg: float,
    prev_bearing_deg: float | None,
    kp: float,
    kd: float,
    v_max_mm_s: float,
) -> tuple[float, float]:
    """(V_L, V_R) from the PD law on the bearing; positive bearing turns left."""
    derivative = 0.0 if prev_bearing_deg is None else bearing_deg - prev_bearing_deg
    turn = kp * bearing_deg + kd * derivative
    return (
        clamp(v_mm_s - turn, -v_max_mm_s, v_max_mm_s),
        clamp(v_mm_s + turn, -v_max_mm_s, v_max_mm_s),
    )


def link_rule(
    rssi_leader_dbm: float | None,
    rssi_behind_dbm: float | None,
    params: ControlParams,
    was_driving: bool,
    rear_required: bool,
) -> tuple[bool, str]:
    """(may drive, reason): the stop rule (docs/CONTROL.md section 5) with a hysteresis band around both thresholds."""
    if rssi_leader_dbm is None or math.isnan(rssi_leader_dbm):
        return False, "no_scan_yet"
    if rear_required and (rssi_behind_dbm is None or math.isnan(rssi_behind_dbm)):
        return False, "rear_link_stale"
    # While stopped, both thresholds move by the band towards "keep standing".
    margin = 0.0 if was_driving else params.hysteresis_db
    if rssi_leader_dbm >= params.threshold_l_dbm - margin:
        return False, "leader_near"
    # rear_required with no rear reading returned "rear_link_stale" above.
    if (
        rear_required
        and rssi_behind_dbm is not None
        and rssi_behind_dbm <= params.threshold_b_dbm + margin
    ):
        return False, "rear_weak"
    return True, "driving"


def _lost(
    inputs: ControlInputs, params: ControlParams, situation: int, memory: ControlMemory
) -> ControlOutput:
    """Leader lost: go on round what the escape is going round, or stand, or turn toward
    where it was last seen beyond the servo's reach."""
    t = inputs.t_s
    if memory.lost_t is None and t is not None and math.isfinite(t):
        memory = replace(memory, lost_t=t)
    if _lost_window_open(inputs, params, memory):
        # Only the rear half of the link rule can hold a relay that has no leader: its
        # latch moves here as it does while following.
        rear_ok, _ = link_rule(
            -math.inf, inputs.rssi_behind_dbm, params, memory.link_drive, params.rear_link_required
        )
        memory = replace(memory, link_drive=rear_ok)
        going_on = None
        if rear_ok:
            going_on = _round_while_lost(inputs, params, situation, memory) or (
                _search_along_wall(inputs, params, situation, memory)
            )
        if going_on is not None:
            return going_on
    heading = inputs.odom[2] if inputs.odom is not None else None
    search, rvel = search_step(
        memory.search, inputs.search_bearing_deg, heading, inputs.t_s, params.search
    )
    memory = replace(memory, search=search)
    left, right = search_wheels(
        rvel,
        params.actuator,
        inputs.front_sonar,
        inputs.rear_sonar,
        params.stop_distance_m,
        params.v_max_mm_s,
    )
    reason = "leader_lost" if left == 0.0 and right == 0.0 else "leader_search"
    held = _lost_memory(memory, inputs.t_s, params)
    return ControlOutput(left, right, DriveState.LEADER_LOST, reason, situation, held)


def _lost_memory(memory: ControlMemory, t_s: float | None, params: ControlParams) -> ControlMemory:
    """The memory of a lost step that does not escape: the escape's episode outlives it
    (AvoidParams.keep_episode_when_lost), its manoeuvre does not."""
    return replace(not_driving(memory), avoid=episode_only(memory.avoid, t_s, params.avoid))


def _lost_window_open(inputs: ControlInputs, params: ControlParams, memory: ControlMemory) -> bool:
    """A lost relay may drive on that soon after the loss (AvoidParams.lost_manoeuvre_s),
    by a clock that is finite and has not gone back."""
    t, lost_t, limit_s = inputs.t_s, memory.lost_t, params.avoid.lost_manoeuvre_s
    if limit_s <= 0.0 or t is None or lost_t is None or not math.isfinite(t):
        return False
    return 0.0 <= t - lost_t <= limit_s


def _round_while_lost(
    inputs: ControlInputs, params: ControlParams, situation: int, memory: ControlMemory
) -> ControlOutput | None:
    """The escape's manoeuvre through a short loss: going round a box turns the antenna
    off the leader; the way round goes on toward where the scans last put it. None: no."""
    av, odom = memory.avoid, inputs.odom
    if av.mode in (AvoidMode.FOLLOW, AvoidMode.BLOCKED) or odom is None:
        return None
    seen = inputs.search_bearing_deg
    bearing = seen if seen is not None and math.isfinite(seen) else wrap_deg(av.goal_deg - odom[2])
    _, out = _escape(inputs, params, memory, bearing, situation)
    return None if out is None or out.state is not DriveState.AVOIDING else out


def _search_along_wall(
    inputs: ControlInputs, params: ControlParams, situation: int, memory: ControlMemory
) -> ControlOutput | None:
    """Lost beyond the servo's reach on the side of a wall beside (the slide's, 7.4): it
    was heard through that wall, and the way to it is where the wall opens. On along the
    wall at the escape's wall speed, not a search turn into it. None: no such wall."""
    seen = inputs.search_bearing_deg
    if (
        not params.search.enabled
        or seen is None
        or not math.isfinite(seen)
        or not params.search.min_bearing_deg <= abs(seen) <= SLIDE_MAX_DEG
    ):
        # Behind the robot (beyond the slide's 100 deg) is the turn round's: on along the
        # wall would run it away from the leader.
        return None
    toward = math.copysign(SLIDE_MAX_DEG, seen)
    along = slide_along_wall(toward, inputs.front_sonar, params.wall_slide_m)
    if along == toward:
        return None
    v = params.avoid.wall_speed_mm_s
    if situation == 1 and (d_min := nearest_front_m(inputs.front_sonar)) is not None:
        v *= speed_scale(d_min, params.threshold_o_m, params.stop_distance_m)
    left, right = wheel_law(v, along, None, params.kp, params.kd, params.v_max_mm_s)
    vel, rvel = _on_the_wire(left, right, inputs.front_sonar, params)
    if vel <= 0:
        return None
    left, right = params.actuator.wheels(vel, rvel)
    held = _lost_memory(memory, inputs.t_s, params)
    return ControlOutput(left, right, DriveState.LEADER_LOST, "leader_search", situation, held)


def control_step(
    inputs: ControlInputs, params: ControlParams, memory: ControlMemory
) -> ControlOutput:
    """One control decision; see the module docstring for the order of rules."""
    situation = classify_situation(inputs.front_sonar, params.threshold_o_m, params.detect_range_m)
    # Hold, manual and the fail-safes end a search episode: its heading and time bookkeeping
    # mean nothing after them (the operator may have moved the robot); a relay still lost
    # afterwards searches afresh, on evidence still recent (docs/CONTROL.md 6.1).
    first = fail_safe_or_mode(inputs, params, situation, memory)
    if first is not None:
        return first
    if inputs.leader_lost:
        return _lost(inputs, params, situation, memory)
    if memory.search != SearchState() or memory.lost_t is not None:
        # Found: the next loss searches afresh.
        memory = replace(memory, search=SearchState(), lost_t=None)
    bearing, rssi_l = inputs.bearing_deg, inputs.rssi_leader_dbm
    if bearing is None or rssi_l is None or not (math.isfinite(bearing) and math.isfinite(rssi_l)):
        return stopped(DriveState.STOPPED, "no_scan_yet", situation, memory)
    prev = inputs.prev_bearing_deg
    if prev is not None and not math.isfinite(prev):
        prev = None  # a broken B' only loses the D term for one scan

    drive, reason = link_rule(
        rssi_l, inputs.rssi_behind_dbm, params, memory.link_drive, params.rear_link_required
    )
    released = False
    if reason == "leader_near" and far_by_sonar(
        inputs.leader_floor_m,
        params.leader_gap_max_m,
        memory.sonar_release,
        rssi_l,
        params.threshold_l_dbm,
    ):
        # The sonars put the leader beyond the gap limit: only the rear half of the rule
        # (the rule run without the leader's term) may still hold the robot.
        released, reason = link_rule(
            -math.inf, inputs.rssi_behind_dbm, params, memory.link_drive, params.rear_link_required
        )
    memory = replace(memory, link_drive=drive or released, sonar_release=released)
    if not (drive or released):
        return stopped(DriveState.STOPPED, reason, situation, memory)

    # Trail pursuit: the stop rule above stands; the trail's direction replaces the scan
    # bearing for the wheel law and the escape (back onto the trail, not through a wall).
    held = trail_hold(inputs, params, memory)
    if held is not None:
        return stopped(DriveState.STOPPED, held, situation, memory)
    bearing, prev, detouring = steering(inputs, params, bearing, prev)
    v = (
        release_speed_mm_s(params.threshold_l_dbm, params.w1, params.w2, params.v_max_mm_s)
        if released
        else background_speed(rssi_l, params.w1, params.w2, params.v_max_mm_s)
    )
    # Situation 1 means a forward sonar echoed inside the detection range: d_min is set.
    d_min = nearest_front_m(inputs.front_sonar) if situation == 1 else None
    if d_min is not None and detouring:
        # Near echoes along a planned path (a door's jambs): slow by what lies in the
        # robot's own path, crawl past the rest, keep to the path.
        v = detour_speed(v, inputs.front_sonar, params)
        bearing = away_from_near_side(bearing, inputs.front_sonar, params.stop_distance_m)
        left, right = wheel_law(v, bearing, None, params.kp, params.kd, params.v_max_mm_s)
        state, reason = DriveState.DRIVING, "detour"
        memory = replace(memory, prev_steer_deg=None)
    elif d_min is not None:
        steer = avoidance_bearing(inputs.front_sonar, params.gamma_o_m)
        v *= situation_speed(d_min, inputs.front_sonar, params)
        left, right = wheel_law(
            v, steer, memory.prev_steer_deg, params.kp, params.kd, params.v_max_mm_s
        )
        state, reason, memory = (
            DriveState.AVOIDING,
            "obstacle",
            replace(memory, prev_steer_deg=steer),
        )
    else:
        kept, prev = off_walls(bearing, prev, inputs.front_sonar, params, detouring)
        left, right = wheel_law(v, kept, prev, params.kp, params.kd, params.v_max_mm_s)
        state, memory = DriveState.DRIVING, replace(memory, prev_steer_deg=None)
        reason = "detour" if detouring else ("leader_far_sonar" if released else "driving")

    vel, rvel = _on_the_wire(left, right, inputs.front_sonar, params)
    # Along a planned detour the escape stands by while the robot makes way: a jamb
    # beside it is what the plan passes between, not a dead end.
    if detouring and retry_detour(memory.avoid, inputs.t_s):
        # A blocked escape waits for the leader's bearing to clear, which a way round
        # never gives; the map has a path: after the wait, the detour tries it again.
        memory = replace(memory, avoid=AvoidState())
    anchor, stalled = detour_watch(memory.detour_anchor, inputs) if detouring else (None, False)
    if anchor != memory.detour_anchor:
        memory = replace(memory, detour_anchor=anchor)
    passing = detouring and vel > 0 and memory.avoid.mode is AvoidMode.FOLLOW and not stalled
    if params.escape and not passing:
        memory, escaped = _escape(inputs, params, memory, bearing, situation)
        if escaped is not None:
            return escaped
    left, right = params.actuator.wheels(vel, rvel)
    return ControlOutput(left, right, state, reason, situation, memory)


def _on_the_wire(
    left_mm_s: float, right_mm_s: float, front: tuple[SonarReading, ...], params: ControlParams
) -> tuple[int, int]:
    """(VEL, RVEL): the law's wheels as the wire will carry them, within v_max, and never
    into a near echo (the guard)."""
    act = params.actuator
    vel, rvel = act.within(*act.express(*act.vel_rvel(left_mm_s, right_mm_s)), params.v_max_mm_s)
    return guard(vel, rvel, front, params.stop_distance_m)


def _escape(
    inputs: ControlInputs,
    params: ControlParams,
    memory: ControlMemory,
    bearing: float,
    situation: int,
) -> tuple[ControlMemory, ControlOutput | None]:
    """The escape's step (section 7): its command, when it has one, replaces the paper's."""
    if inputs.t_s is None or inputs.odom is None or not math.isfinite(inputs.t_s):
        return memory, None
    act = params.actuator
    sense = Sense(inputs.t_s, inputs.odom, inputs.front_sonar, bearing, inputs.rear_sonar)
    aparams = replace(
        params.avoid, stop_distance_m=params.stop_distance_m, threshold_o_m=params.threshold_o_m
    )
    avoid, cmd = avoid_step(memory.avoid, sense, aparams, act)
    memory = replace(memory, avoid=avoid)
    if params.pursuit == "trail":
        moving = not cmd.follow and (cmd.vel_mm_s != 0 or cmd.rvel_deg_s != 0)
        block, stop = blocked_step(
            memory.trail_block, inputs.t_s, moving, inputs.trail_remaining_m, params.trail_blocked
        )
        memory = replace(memory, trail_block=block)
        if stop:  # _stopped clears the escape: it starts afresh after the wait
            return memory, stopped(DriveState.STOPPED, "trail_blocked", situation, memory)
    if cmd.follow:
        return memory, None
    # The escape's turn rates are fixed; a v_max below them still bounds every wheel.
    left, right = act.wheels(*act.within(cmd.vel_mm_s, cmd.rvel_deg_s, params.v_max_mm_s))
    moving = cmd.vel_mm_s != 0 or cmd.rvel_deg_s != 0
    state = DriveState.AVOIDING if moving else DriveState.STOPPED
    # The escape's command (its "blocked" stop too) ends a sonar release: it must be
    # earned again at the full limit once the paper's law drives again.
    out = replace(memory, prev_steer_deg=None, sonar_release=False)
    return memory, ControlOutput(left, right, state, cmd.reason, situation, out)
