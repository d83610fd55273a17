"""Pure pursuit along the leader's trail: which way to steer, or hold at its head (pure).

The target is the point `lookahead` metres along the trail from where the relay joins
it; the steering angle is that point's bearing in the robot frame, which the paper's
PD wheel law then follows in place of the scan bearing (so its speed law, its clamps to
v_max and the stop rule before it are unchanged). The lookahead shrinks in tight
places: it is the nearest front echo times `lookahead_per_clear`, within
[lookahead_min_m, lookahead_max_m], so in a doorway the target is the door, not the
room beyond its jamb. Within `catch_up_m` of the head the relay has caught up with
where the leader was last placed: it holds there and scans (`caught_up`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from relayd.core.geometry import wrap_deg
from relayd.core.scan.estimator import SONAR_MAX_RANGE_M, SonarReading
from relayd.core.trail.polyline import Trail, point_along, remaining_m


@dataclass(frozen=True, slots=True)
class PursuitParams:
    lookahead_min_m: float = 0.6
    lookahead_max_m: float = 2.0
    lookahead_per_clear: float = 1.0
    catch_up_m: float = 0.5


@dataclass(frozen=True, slots=True)
class Pursuit:
    #: The target's bearing in the robot frame (deg, ccw +); None when caught up.
    steer_deg: float | None
    lookahead_m: float
    target_xy_m: tuple[float, float] | None
    caught_up: bool


def lookahead_m(front: Sequence[SonarReading], prm: PursuitParams) -> float:
    echoes = [r.range_m for r in front if r.range_m is not None and abs(r.heading_deg) <= 90.0]
    clear = min(echoes, default=SONAR_MAX_RANGE_M)
    return min(prm.lookahead_max_m, max(prm.lookahead_min_m, prm.lookahead_per_clear * clear))


def pursue(
    trail: Trail,
    pose_m_deg: tuple[float, float, float],
    front: Sequence[SonarReading],
    prm: PursuitParams,
) -> Pursuit | None:
    """The steering onto the trail from this pose; None without a trail."""
    if not trail:
        return None
    xy = (pose_m_deg[0], pose_m_deg[1])
    look = lookahead_m(front, prm)
    if remaining_m(trail, xy) <= prm.catch_up_m:
        return Pursuit(None, look, trail[-1].xy, True)
    tx, ty = point_along(trail, xy, look)
    if math.dist((tx, ty), xy) < 1e-6:
        return Pursuit(None, look, (tx, ty), True)
    steer = wrap_deg(math.degrees(math.atan2(ty - xy[1], tx - xy[0])) - pose_m_deg[2])
    return Pursuit(steer, look, (tx, ty), False)
