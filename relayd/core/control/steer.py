"""Which way the law steers, and how fast along a detour (pure).

The paper's law steers at the scan bearing. The trail pursuit puts the trail's direction
in its place (back onto the trail, not through a wall), and a detour's path round the
sonar map (relayd/core/plan) replaces either while the straight way is blocked. Along
a detour, near echoes beside the path (a door's jambs) slow the robot to a crawl; only
an echo that may lie in its own path scales its speed to zero.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from relayd.core.avoid.ring import by_heading, in_path_below_m, wall_fit
from relayd.core.avoid.state import AvoidMode, AvoidState
from relayd.core.control.params import ControlParams
from relayd.core.scan.estimator import SONAR_MAX_RANGE_M, SonarReading
from relayd.core.trail.blocked import waiting

if TYPE_CHECKING:
    from relayd.core.control.inputs import ControlInputs, ControlMemory


def speed_scale(d_min_m: float, threshold_o_m: float, stop_distance_m: float) -> float:
    """1 at threshold_o (and beyond), falling linearly to 0 at stop_distance (and below)."""
    span = threshold_o_m - stop_distance_m
    if span <= 0:
        return 1.0 if d_min_m >= threshold_o_m else 0.0
    return min(max((d_min_m - stop_distance_m) / span, 0.0), 1.0)


#: A blocked escape along a detour is tried again after this long (s).
DETOUR_RETRY_S = 10.0


def retry_detour(avoid: AvoidState, t_s: float | None) -> bool:
    """Has the escape stood "blocked" DETOUR_RETRY_S, so that a detour may try again?"""
    return (
        t_s is not None and avoid.mode is AvoidMode.BLOCKED and t_s - avoid.mode_t >= DETOUR_RETRY_S
    )


#: A detour that has not got DETOUR_PROGRESS_MM on in DETOUR_STALL_S has stalled: the
#: escape (and its own watchdog) takes over from it.
DETOUR_PROGRESS_MM, DETOUR_STALL_S = 300.0, 10.0


def detour_watch(
    anchor: tuple[float, float, float] | None, inputs: ControlInputs
) -> tuple[tuple[float, float, float] | None, bool]:
    """(the new anchor (x mm, y mm, t s), stalled): None in, a fresh watch from here."""
    odom, t = inputs.odom, inputs.t_s
    if odom is None or t is None:
        return None, False
    if anchor is None or math.hypot(odom[0] - anchor[0], odom[1] - anchor[1]) > DETOUR_PROGRESS_MM:
        return (odom[0], odom[1], t), False
    return anchor, t - anchor[2] > DETOUR_STALL_S


def away_from_near_side(steer_deg: float, front: tuple[SonarReading, ...], stop_m: float) -> float:
    """No turn toward a side whose 50 or 90 deg sonar reads below stop_m (a jamb beside the
    robot: turning into it would swing the body's corner onto it), and only a gentle one
    (TIGHT_STEER_DEG) while either side is within PASSAGE_SIDE_M more: a sharp turn in a
    gap swings the robot's tail onto what it is passing."""
    r = by_heading(front)

    def side_m(side: int) -> float:
        return min(r.get(side * 90.0, SONAR_MAX_RANGE_M), r.get(side * 50.0, SONAR_MAX_RANGE_M))

    side = 1 if steer_deg > 0 else -1
    if side_m(side) < stop_m:
        return 0.0
    if min(side_m(1), side_m(-1)) < stop_m + PASSAGE_SIDE_M:
        return max(-TIGHT_STEER_DEG, min(TIGHT_STEER_DEG, steer_deg))
    return steer_deg


#: The push off a side wall (deg) were its sonar to read 0; the transducer sits 0.12 m
#: inside the body's side, so at touching it reads about that and the push is less (20 deg
#: with the shipped control.side_keep_m of 0.35 m).
KEEP_PUSH_DEG = 30.0


def keep_off_sides(
    steer_deg: float, prev_deg: float | None, front: tuple[SonarReading, ...], keep_m: float
) -> tuple[float, float | None]:
    """(steer, previous steer for the D term): the steer pushed away from a wall beside the
    robot nearer than keep_m (its 90 deg sonar), in proportion to how much nearer
    (KEEP_PUSH_DEG x (keep_m - range) / keep_m), both sides summed (between two, toward the
    middle); the previous steer moved by the same push, so the D term sees the bearing's
    own change. The paper's law drives at the leader's bearing, and a wall met at a
    glancing angle echoes into the side sonar alone (the forward ones see it specularly:
    not at all), so nothing else turns the robot off it before it scrapes."""
    if keep_m <= 0.0:
        return steer_deg, prev_deg
    r = by_heading(front)
    push = 0.0
    for side in (1, -1):
        d = r.get(side * 90.0, SONAR_MAX_RANGE_M)
        if d < keep_m:
            push -= side * KEEP_PUSH_DEG * (keep_m - d) / keep_m
    return steer_deg + push, None if prev_deg is None else prev_deg + push


#: The slide along a wall acts on a leader at most this far off the nose (deg): one
#: behind is the turn round's, and sliding on would run the robot away along the wall.
SLIDE_MAX_DEG = 100.0


def slide_along_wall(steer_deg: float, front: tuple[SonarReading, ...], reach_m: float) -> float:
    """The steer no further into a wall on its side than the wall's own direction: the
    leader's signal comes through walls, and a relay that steers at it into one meets the
    paper's slow-down, turns off, steers back in and crawls. Along the wall instead it
    drives on until the wall ends or opens (a door), and the bearing has the way again.
    The wall is the line through that side's two nearest 90/50/30 deg echoes within
    reach_m (relayd.core.avoid.ring.wall_fit; one echo alone is taken as parallel to the
    heading), and only while the 90 deg sonar hears it abeam; 0: off. The echoes sit on
    their beams' axes, which reads a parallel wall 7-14 deg turned off it (the nearest
    echo comes from the beam's edge): as measured, the slide eases the robot off the wall
    by about that much (docs/CONTROL.md 7.4)."""
    if reach_m <= 0.0 or steer_deg == 0.0 or abs(steer_deg) > SLIDE_MAX_DEG:
        return steer_deg
    side = 1 if steer_deg > 0 else -1
    r = by_heading(front)
    if r.get(side * 90.0, SONAR_MAX_RANGE_M) > reach_m:
        # Nothing abeam on that side: a door or a side corridor there, or the wall still
        # ahead, where the paper's obstacle rule has it; the bearing has the way.
        return steer_deg
    fit = wall_fit(r, side, reach_m)
    if fit is None:
        return steer_deg
    _, along_deg = fit
    return min(steer_deg, along_deg) if side > 0 else max(steer_deg, along_deg)


def off_walls(
    steer_deg: float,
    prev_deg: float | None,
    front: tuple[SonarReading, ...],
    params: ControlParams,
    detouring: bool,
) -> tuple[float, float | None]:
    """The plain pursuit's steer and its previous value, slid along a wall it points into
    (control.wall_slide_m) and pushed off one beside it (control.side_keep_m); a detour's
    path is the map's, and neither acts on it."""
    if detouring:
        return steer_deg, prev_deg
    slid = slide_along_wall(steer_deg, front, params.wall_slide_m)
    if slid != steer_deg:
        prev_deg = None  # the steer is the wall's, not the bearing's: no D term on it
    return keep_off_sides(slid, prev_deg, front, params.side_keep_m)


#: Within this much beyond the stop distance of a side echo, a detour steers gently ...
PASSAGE_SIDE_M = 0.15
#: ... at most this far off the nose (deg).
TIGHT_STEER_DEG = 10.0


def in_path_m(r: dict[float, float]) -> float:
    """The nearest echo of the front ring (by heading) that may lie in the forward path."""
    return min((d for h, d in r.items() if d < in_path_below_m(h)), default=SONAR_MAX_RANGE_M)


#: Over this much beyond the stop distance (m) the beside floor fades to the paper's scale.
BESIDE_RAMP_M = 0.1


def situation_speed(
    d_min_m: float, front: tuple[SonarReading, ...], params: ControlParams
) -> float:
    """The share of its speed the paper's situation 1 leaves the robot: by the nearest
    forward echo, linearly to 0 at the stop distance. An echo that cannot lie in the
    forward path (in_path_below_m) slows it no lower than beside_speed_floor (fading to
    the paper's scale within BESIDE_RAMP_M of the stop distance): in a 1.5 m
    corridor the 50 deg sonars read 0.4-0.7 m off its walls, and the paper's law slowed
    a relay a little off centre to a stop there, for the escape's watchdog to take it as
    stuck and back it off 1.2 m (generated corridors 40)."""
    stop = params.stop_distance_m
    paper = speed_scale(d_min_m, params.threshold_o_m, stop)
    if params.beside_speed_floor <= 0.0:
        return paper
    ahead = speed_scale(in_path_m(by_heading(front)), params.threshold_o_m, stop)
    # The floor fades out over the last BESIDE_RAMP_M to the stop distance: at the floor's
    # speed the robot closed on a box corner beside it to 0.096 m before the escape took
    # over, under the 0.1 m the escape's property test asks (0.126 m with the fade).
    floor = params.beside_speed_floor * min(max((d_min_m - stop) / BESIDE_RAMP_M, 0.0), 1.0)
    return min(ahead, max(floor, paper))


def detour_speed(v_mm_s: float, front: tuple[SonarReading, ...], params: ControlParams) -> float:
    """The paper's speed along a detour: scaled by the nearest echo that may lie in the
    robot's forward path, and no faster than the door passage's crawl (avoidance.door_speed_mm_s)
    past echoes beside it."""
    r = by_heading(front)
    v_mm_s *= speed_scale(in_path_m(r), params.threshold_o_m, params.stop_distance_m)
    if min(r.values(), default=SONAR_MAX_RANGE_M) < params.threshold_o_m:
        v_mm_s = min(v_mm_s, params.avoid.door_speed_mm_s)
    return v_mm_s


def trail_hold(inputs: ControlInputs, params: ControlParams, memory: ControlMemory) -> str | None:
    """The trail pursuit's own stops, by reason: a "trail_blocked" wait, or caught up with
    the trail's head ("trail_head"); None: neither."""
    if params.pursuit != "trail":
        return None
    if inputs.t_s is not None and waiting(memory.trail_block, inputs.t_s):
        hold_reason = "trail_blocked"
    elif inputs.trail_caught_up:
        hold_reason = "trail_head"
    else:
        return None
    return hold_reason


def steering(
    inputs: ControlInputs, params: ControlParams, bearing: float, prev: float | None
) -> tuple[float, float | None, bool]:
    """(steer, its previous value for the D term, detouring): the trail's direction replaces
    the scan bearing in trail pursuit (back onto the trail, not through a wall); a detour's
    path round the sonar map replaces either (relayd/core/plan)."""
    if params.pursuit == "trail":
        steer = inputs.trail_steer_deg
        if steer is not None and math.isfinite(steer):
            bearing, prev = steer, None
    detour = inputs.detour_steer_deg
    if detour is not None and math.isfinite(detour):
        return detour, None, True
    return bearing, prev, False
