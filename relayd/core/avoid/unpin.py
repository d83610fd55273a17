"""A turn in place the guard refuses is not held for good ([avoidance] unpin; pure).

The escape turns in place to get round what it meets, and the guard refuses a turn while
anything lies inside the circle the corners sweep. Held there, in a corridor's corner or
against a wall along the side, nothing would ever change. These are the commands that
creep on instead, on an arc away from the nearer side, within what the guard allows and
what the near side's rear sonar sees of the rear corner's swing (docs/AVOIDANCE.md).
"""

from __future__ import annotations

import math

from relayd.core.avoid.ring import TURN_MARGIN_M, jammed_beside, min_at
from relayd.core.avoid.state import AvoidCommand, StepView, drive_cmd
from relayd.core.geometry import HALF_LENGTH_M, HALF_WIDTH_M, SONAR_POSES
from relayd.core.scan.estimator import SONAR_MAX_RANGE_M

#: The rear ring's sonar looking out of each side from the rear corner (+1 left, -1 right).
REAR_SIDE_SONAR: dict[float, int] = {1.0: 15, -1.0: 8}
#: Clearance (m) kept beside the rear corner's swing while unpinning.
UNPIN_MARGIN_M = 0.05


def creep_beside(v: StepView, held: AvoidCommand) -> AvoidCommand | None:
    """A refused turn whose jam is a wall beside the robot: the unpin's creep, not a
    back-off. Backing off runs along that wall and gains no room, and a long reverse at a
    few degrees to it closes on it unseen (generated corridors 116: ALIGN and its 0.3 m
    back-off took turns for 2.4 m until a rear corner touched the wall). None: not
    jammed beside, or the creep is not allowed either (the caller's rules go on)."""
    if not v.p.unpin or not jammed_beside(v.s.sonar, v.s.rear, TURN_MARGIN_M):
        return None
    cmd = unpin_cmd(v, held)
    return cmd if cmd.vel_mm_s > 0 else None


def unpin_cmd(v: StepView, held: AvoidCommand) -> AvoidCommand:
    """A turn in place the guard refuses (an echo inside the circle the corners sweep)
    with no room behind to back off. Held there, nothing would ever change (generated
    corridors 2: a corridor's corner along the right and behind, the way ahead open,
    "blocked" for the rest of the run). So it creeps on, along an arc away from the
    nearer side, as the guard allows, until the corners have room to turn. The guard
    checks a forward command against the forward path only: the arc's swing of the near
    side's rear corner is checked here, against that side's rear sonar (unread: no
    creep). With nothing allowed, it holds (`held`)."""
    s, p, r = v.s, v.p, v.r
    away = 1.0 if min_at(r, (-90.0, -50.0)) < min_at(r, (90.0, 50.0)) else -1.0
    rvel = away * p.turn_rate_deg_s / 2.0
    index = REAR_SIDE_SONAR[-away]
    read = [x.range_m for x in s.rear if x.index == index]
    if not read:
        return held
    # The transducer sits inside the body's side: what is beyond the side is less.
    inset_m = HALF_WIDTH_M - abs(SONAR_POSES[index].y_mm) / 1000.0
    beside_m = (read[0] if read[0] is not None else SONAR_MAX_RANGE_M) - inset_m
    if beside_m < rear_swing_m(p.backoff_speed_mm_s, rvel) + UNPIN_MARGIN_M:
        return held
    creep = drive_cmd(v.act, s, p, p.backoff_speed_mm_s, rvel)
    return creep if creep.vel_mm_s > 0 else held


def rear_swing_m(vel_mm_s: float, rvel_deg_s: float) -> float:
    """How far a rear corner swings outward, beyond the body's side, on an arc at (vel,
    rvel): the corner's distance from the arc's centre less the side's."""
    w = math.radians(abs(rvel_deg_s))
    if w == 0.0:
        return 0.0
    radius_m = vel_mm_s / 1000.0 / w
    return math.hypot(HALF_LENGTH_M, radius_m + HALF_WIDTH_M) - (radius_m + HALF_WIDTH_M)
