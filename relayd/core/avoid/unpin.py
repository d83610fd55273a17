"""A turn in place the guard refuses is not held for good ([avoidance] unpin; pure).

The escape turns in place to get round what it meets, and the guard refuses a turn while
anything lies inside the circle the corners sweep. Held there, in a corridor's corner or
against a wall along the side, nothing would ever change. These are the commands that
creep on instead, on an arc away from the nearer side, within what the guard allows and
what the near side's rear sonar sees of the rear corner's swing (docs/AVOIDANCE.md).
"""

from __future__ import annotations

import math

from relayd.core.avoid.ring import (
    AHEAD_DEG,
    REAR_SIDE_SONAR,
    TURN_MARGIN_M,
    echo_m,
    min_at,
    wall_along_side,
)
from relayd.core.avoid.state import AvoidCommand, StepView, drive_cmd
from relayd.core.geometry import HALF_LENGTH_M, HALF_WIDTH_M, SONAR_POSES

#: Clearance (m) kept beside the rear corner's swing while unpinning.
UNPIN_MARGIN_M = 0.05


def creep_beside(v: StepView, held: AvoidCommand, wall: int | None = None) -> AvoidCommand | None:
    """A refused turn whose jam is a wall along one side: the unpin's creep away from that
    wall, not a back-off. Backing off runs along the wall and gains no room, and a long
    reverse at a few degrees to it closes on it unseen (generated corridors 116: ALIGN
    and its 0.3 m back-off took turns for 2.4 m until a rear corner touched the wall).
    None: no such wall, or the creep is not allowed either (the caller's rules go on).
    `wall`: ring.wall_along_side's answer, when the caller has it already."""
    if not v.p.unpin:
        return None
    if wall is None:
        wall = wall_along_side(v.s.sonar, v.s.rear, TURN_MARGIN_M)
    if wall == 0:
        return None
    cmd = unpin_cmd(v, held, away=-wall)
    return cmd if cmd.vel_mm_s > 0 else None


def unpin_cmd(v: StepView, held: AvoidCommand, away: int = 0) -> AvoidCommand:
    """A turn in place the guard refuses (an echo inside the circle the corners sweep)
    with no room behind to back off. Held there, nothing would ever change (generated
    corridors 2: a corridor's corner along the right and behind, the way ahead open,
    "blocked" for the rest of the run). So it creeps on, along an arc away from the
    nearer side (or `away`, +1 left, -1 right), as the guard allows, until the corners
    have room to turn. The guard checks a forward command against the forward path only,
    so the arc's two outer corners are checked here: the rear one swings out beyond the
    near side (against that side's rear sonar; unread: no creep), the front one moves
    out toward the far side (whose 50 and 90 deg sonars must see the stop distance).
    With nothing allowed, it holds (`held`)."""
    s, p, r = v.s, v.p, v.r
    nearer = 1 if min_at(r, (-90.0, -50.0)) < min_at(r, (90.0, 50.0)) else -1
    turn = away or nearer
    if min_at(r, (turn * 90.0, turn * 50.0)) < p.stop_distance_m:
        return held
    rvel = turn * p.turn_rate_deg_s / 2.0
    index = REAR_SIDE_SONAR[-turn]
    reading = next((x for x in s.rear if x.index == index), None)
    if reading is None:
        return held
    # The transducer sits inside the body's side: what is beyond the side is less.
    inset_m = HALF_WIDTH_M - abs(SONAR_POSES[index].y_mm) / 1000.0
    beside_m = echo_m(reading) - inset_m
    if beside_m < rear_swing_m(p.backoff_speed_mm_s, rvel) + UNPIN_MARGIN_M:
        return held
    creep = drive_cmd(v.act, s, p, p.backoff_speed_mm_s, rvel)
    return creep if creep.vel_mm_s > 0 else held


def straight_on(v: StepView) -> AvoidCommand | None:
    """A turn in place refused, no creep and no room behind, the way ahead open (nothing
    within threshold_o of the +-10 and +-30 deg sonars): on straight ahead at the
    back-off speed, which swings no corner out and whose whole path the guard checks,
    until the corners have room to turn. None: not open ahead, or the guard says no."""
    p = v.p
    if not p.unpin or min_at(v.r, AHEAD_DEG) <= p.threshold_o_m:
        return None
    cmd = drive_cmd(v.act, v.s, p, p.backoff_speed_mm_s, 0.0)
    return cmd if cmd.vel_mm_s > 0 else None


def rear_swing_m(vel_mm_s: float, rvel_deg_s: float) -> float:
    """How far a rear corner swings outward, beyond the body's side, on an arc at (vel,
    rvel): the corner's distance from the arc's centre less the side's."""
    w = math.radians(abs(rvel_deg_s))
    if w == 0.0:
        return 0.0
    radius_m = vel_mm_s / 1000.0 / w
    return math.hypot(HALF_LENGTH_M, radius_m + HALF_WIDTH_M) - (radius_m + HALF_WIDTH_M)
