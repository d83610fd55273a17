"""A scripted walker of the simulated world: the leader, and a command center carried along.

`LeaderScript` turns a scenario's waypoints (x, y, pause at it), a walking speed that may
change with the clock (`speed_profile`) and a start delay into `pose(t)`: where the
walker is at clock time t, its heading, whether it is moving and whether it has
arrived. Pure in time (no world, no state between calls), so the world, the paper's
validation runs (relayd.sweep.validation) and the tests can ask it for any t, in any
order.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

from relayd.sim.geometry import Point


@dataclass(frozen=True, slots=True)
class LeaderPose:
    x_m: float
    y_m: float
    heading_deg: float
    moving: bool
    done: bool


class LeaderScript:
    """A leader walking waypoints, pausing where told, at a speed that may change with time
    (`speed_profile`: (clock s, m/s) pairs in time order). Pure in time."""

    def __init__(
        self,
        waypoints: list[tuple[float, float, float]],
        speed_m_s: float,
        start_s: float = 0.0,
        speed_profile: list[tuple[float, float]] | None = None,
    ) -> None:
        if not waypoints:
            raise ValueError("a leader script needs at least one waypoint")
        if speed_m_s <= 0 or any(v <= 0 for _, v in speed_profile or ()):
            raise ValueError("leader speed must be > 0")
        self.speed_m_s = speed_m_s
        # Speed breakpoints: (from clock s, speed) with the base speed from 0.
        self._speeds: list[tuple[float, float]] = [(0.0, speed_m_s), *sorted(speed_profile or ())]
        # Legs: (t_start, t_end, from, to, heading); a pause is a leg with from == to.
        self._legs: list[tuple[float, float, Point, Point, float]] = []
        t = start_s
        x0, y0, pause0 = waypoints[0]
        heading = 0.0
        if len(waypoints) > 1:
            heading = math.degrees(math.atan2(waypoints[1][1] - y0, waypoints[1][0] - x0))
        if start_s > 0:
            self._legs.append((0.0, start_s, (x0, y0), (x0, y0), heading))
        if pause0 > 0:
            self._legs.append((t, t + pause0, (x0, y0), (x0, y0), heading))
            t += pause0
        for (xa, ya, _), (xb, yb, pause) in itertools.pairwise(waypoints):
            d = math.hypot(xb - xa, yb - ya)
            if d > 0:
                heading = math.degrees(math.atan2(yb - ya, xb - xa))
                t_end = self._time_to_cover(t, d)
                self._legs.append((t, t_end, (xa, ya), (xb, yb), heading))
                t = t_end
            if pause > 0:
                self._legs.append((t, t + pause, (xb, yb), (xb, yb), heading))
                t += pause
        self.end_s = t
        self._start = (x0, y0, heading)
        self._final = (waypoints[-1][0], waypoints[-1][1], heading)

    def _distance(self, t0: float, t1: float) -> float:
        """Metres walked between clock t0 and t1 at the profile's speeds."""
        total = 0.0
        for k, (ts, v) in enumerate(self._speeds):
            te = self._speeds[k + 1][0] if k + 1 < len(self._speeds) else math.inf
            lo, hi = max(t0, ts), min(t1, te)
            if hi > lo:
                total += v * (hi - lo)
        return total

    def _time_to_cover(self, t0: float, d: float) -> float:
        t, left = t0, d
        for k, (ts, v) in enumerate(self._speeds):
            te = self._speeds[k + 1][0] if k + 1 < len(self._speeds) else math.inf
            if te <= t:
                continue
            seg = v * (te - max(t, ts))
            if seg >= left:
                return max(t, ts) + left / v
            left -= seg
            t = te
        return t  # unreachable: the last speed holds for ever

    @property
    def goal(self) -> Point:
        return self._final[0], self._final[1]

    def pose(self, t: float) -> LeaderPose:
        if t >= self.end_s:
            x, y, h = self._final
            return LeaderPose(x, y, h, False, True)
        for t0, t1, a, b, h in self._legs:
            if t0 <= t < t1:
                if a == b:
                    return LeaderPose(a[0], a[1], h, False, False)
                f = min(1.0, self._distance(t0, t) / math.hypot(b[0] - a[0], b[1] - a[1]))
                return LeaderPose(
                    a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), h, True, False
                )
        x, y, h = self._start
        return LeaderPose(x, y, h, False, False)
