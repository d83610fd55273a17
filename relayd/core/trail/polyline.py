"""The leader's trail: the positions it passed through, thinned, with times (pure).

A trail is a tuple of `TrailPoint`s, oldest first, in the relay's odometry frame (m).
The first point stays where the trail began; the last is the head: it follows the newest estimate until it is `spacing_m`
from the point before it, when it is committed and the next estimate starts a new head, so a
leader that stops adds nothing and one that walks adds a point every `spacing_m`.
Points the relay has reached are dropped from the tail (`prune`); the search for the
nearest point looks only a few points ahead, so a trail that doubles back (a leader
that turned round) is not cut short across its loop.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class TrailPoint:
    t_s: float
    x_m: float
    y_m: float
    #: The estimate's 1-sigma radius there (0 for a point from the leader's own odometry).
    sigma_m: float = 0.0

    @property
    def xy(self) -> tuple[float, float]:
        return self.x_m, self.y_m


Trail = tuple[TrailPoint, ...]


def add_point(trail: Trail, point: TrailPoint, *, spacing_m: float, keep: int) -> Trail:
    """The trail with this newest position as its head (see the module docstring)."""
    if len(trail) >= 2 and math.dist(trail[-2].xy, trail[-1].xy) < spacing_m:
        out = (*trail[:-1], point)  # the head has not yet got spacing_m away: it moves on
    else:
        out = (*trail, point)
    return out[-keep:] if len(out) > keep else out


def prune(trail: Trail, relay_xy_m: tuple[float, float], *, reach_m: float, window: int) -> Trail:
    """Drop the points behind the relay: up to the nearest of the next `window` points when it
    is within reach_m, or when the relay is past it along the segment after it."""
    if len(trail) < 2:
        return trail
    n = min(window, len(trail) - 1)  # never drop the head
    best, best_d = -1, math.inf
    for i in range(n):
        d = math.dist(trail[i].xy, relay_xy_m)
        if d < best_d:
            best, best_d = i, d
    cut = best if best_d <= reach_m else 0
    # Past a point: the relay's projection on the segment after it lies beyond its start.
    while cut < len(trail) - 1 and _beyond(trail[cut], trail[cut + 1], relay_xy_m):
        cut += 1
    return trail[cut:]


def _beyond(a: TrailPoint, b: TrailPoint, p: tuple[float, float]) -> bool:
    """Is p past b along a->b (its projection beyond b)? Then a is behind the relay."""
    ax, ay = b.x_m - a.x_m, b.y_m - a.y_m
    seg2 = ax * ax + ay * ay
    if seg2 <= 1e-12:
        return True  # a repeated point is of no use
    return ((p[0] - a.x_m) * ax + (p[1] - a.y_m) * ay) / seg2 >= 1.0


def length_m(trail: Trail) -> float:
    return sum(math.dist(a.xy, b.xy) for a, b in itertools.pairwise(trail))


def point_along(
    trail: Trail, relay_xy_m: tuple[float, float], distance_m: float
) -> tuple[float, float]:
    """The point distance_m along the trail from the relay's projection onto its first
    segment (the relay itself joins the trail there); the head if the trail is shorter."""
    if len(trail) == 1:
        return trail[0].xy
    a, b = trail[0], trail[1]
    ax, ay = b.x_m - a.x_m, b.y_m - a.y_m
    seg2 = ax * ax + ay * ay
    u = (
        0.0
        if seg2 <= 1e-12
        else ((relay_xy_m[0] - a.x_m) * ax + (relay_xy_m[1] - a.y_m) * ay) / seg2
    )
    u = min(max(u, 0.0), 1.0)
    start = (a.x_m + u * ax, a.y_m + u * ay)
    # The relay may be off the trail: the way onto it counts toward the lookahead.
    left = distance_m - math.dist(relay_xy_m, start)
    if left <= 0.0:
        return start
    pts = [start, *(p.xy for p in trail[1:])]
    for p, q in itertools.pairwise(pts):
        seg = math.dist(p, q)
        if seg >= left and seg > 0.0:
            f = left / seg
            return p[0] + f * (q[0] - p[0]), p[1] + f * (q[1] - p[1])
        left -= seg
    return pts[-1]


def remaining_m(trail: Trail, relay_xy_m: tuple[float, float]) -> float:
    """How far along the trail the head still is: the way onto it plus what lies after."""
    if not trail:
        return 0.0
    if len(trail) == 1:
        return math.dist(relay_xy_m, trail[0].xy)
    return math.dist(relay_xy_m, trail[1].xy) + length_m(trail[1:])
