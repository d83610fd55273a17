"""Going round what is in the way: when to plan, and where the plan steers (pure).

The relay drives at its target (the scan bearing's leader estimate, or the trail's
lookahead point) as long as the straight way there is clear on the sonar map. When the
map shows something on that line (a wall the leader's signal comes through, the arm of
a U), the navigator plans a path round it on the map (relayd/core/plan/astar.py) and
steers at a point `lookahead_m` along that path, replanning every `replan_s`, when the
target moves by `retarget_m` or when the path runs into a newly seen obstacle. A
detour, once taken, is kept for `hold_s` after the direct way clears, so the relay does
not swing back at the wall it has just left behind a corner.

The last metres before the target are not checked (`goal_free_m`): the leader itself
echoes there, a robot leader most of all. Time comes with each call; nothing is read.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from relayd.core.geometry import wrap_deg
from relayd.core.plan.astar import Path, PlanParams, plan
from relayd.core.plan.grid import GridParams, SonarGrid


@dataclass(frozen=True, slots=True)
class NavParams:
    #: Off: the navigator never steers (the laws as they were).
    enabled: bool = True
    grid: GridParams = field(default_factory=GridParams)
    plan: PlanParams = field(default_factory=PlanParams)
    #: How far along the straight way (m) the map is checked, and how close to the
    #: line an occupied cell must be to block it (the robot's half width and a margin).
    check_m: float = 4.0
    clear_m: float = 0.35
    goal_free_m: float = 1.2
    lookahead_m: float = 0.8
    replan_s: float = 1.5
    #: ... and never sooner than this after the last plan, found or not.
    min_replan_s: float = 0.5
    retarget_m: float = 1.0
    hold_s: float = 3.0
    #: Echoes this close to the leader's estimate are the leader's own (m): a person or a
    #: robot walks on, and the doorway it walked through must not read as closed.
    leader_free_m: float = 1.0
    #: The map keeps this much round the relay (m).
    keep_m: float = 30.0
    forget_every_s: float = 30.0


@dataclass(frozen=True, slots=True)
class NavView:
    """The detour in force: its steering (robot frame) and the path (odometry frame, m)."""

    steer_deg: float
    path: Path


class Navigator:
    """The one writer of the sonar map and the detour plan."""

    def __init__(self, params: NavParams | None = None) -> None:
        self.p = params or NavParams()
        self.grid = SonarGrid(self.p.grid)
        self.path: Path | None = None
        self._plan_t: float | None = None
        self._plan_goal: tuple[float, float] | None = None
        self._clear_since: float | None = None
        self._forgot_t: float | None = None
        self.last: NavView | None = None
        self.plans = 0

    def sonar(
        self,
        t_s: float,
        pose_mm_deg: tuple[float, float, float],
        readings: Sequence[tuple[int, int]],
        leader_xy: tuple[float, float] | None = None,
    ) -> None:
        """One SIP's new sonar readings (index, range mm) onto the map; echoes within
        leader_free_m of where the leader is estimated are its own, not mapped."""
        if not self.p.enabled:
            return
        self.grid.update(t_s, pose_mm_deg, readings, leader_xy, self.p.leader_free_m)
        if self._forgot_t is None:
            self._forgot_t = t_s
        elif t_s - self._forgot_t > self.p.forget_every_s:
            self._forgot_t = t_s
            self.grid.forget(pose_mm_deg[0] / 1000.0, pose_mm_deg[1] / 1000.0, self.p.keep_m)

    def clear_line(self, a: tuple[float, float], b: tuple[float, float]) -> bool:
        """Is the straight way from a toward b free on the map (up to check_m, and short of
        b by goal_free_m)?"""
        p = self.p
        d = math.dist(a, b)
        span = min(p.check_m, d - p.goal_free_m)
        if span <= 0:
            return True
        end = (a[0] + span * (b[0] - a[0]) / d, a[1] + span * (b[1] - a[1]) / d)
        return self.grid.segment_clear(a, end, p.clear_m)

    def steer(
        self,
        t_s: float,
        pose_mm_deg: tuple[float, float, float] | None,
        goal_xy: tuple[float, float] | None,
    ) -> NavView | None:
        """The detour's steering from this odometry pose toward goal_xy (m); None: go straight."""
        p = self.p
        if not p.enabled or goal_xy is None or pose_mm_deg is None:
            self._drop()
            return None
        here = (pose_mm_deg[0] / 1000.0, pose_mm_deg[1] / 1000.0)
        if self.clear_line(here, goal_xy):
            if self.path is None:
                return None
            if self._clear_since is None:
                self._clear_since = t_s
            if t_s - self._clear_since >= p.hold_s:
                self._drop()
                return None
        else:
            self._clear_since = None
        if self._replan_due(t_s, here, goal_xy):
            self.path = plan(self.grid, here, goal_xy, p.plan)
            self._plan_t, self._plan_goal = t_s, goal_xy
            self.plans += 1
        if self.path is None:
            self.last = None
            return None
        tx, ty = _along(self.path, here, p.lookahead_m)
        steer = wrap_deg(math.degrees(math.atan2(ty - here[1], tx - here[0])) - pose_mm_deg[2])
        self.last = NavView(steer, self.path)
        return self.last

    def _replan_due(self, t_s: float, here: tuple[float, float], goal: tuple[float, float]) -> bool:
        p = self.p
        if self._plan_t is None or self._plan_goal is None:
            return True
        since = t_s - self._plan_t
        if since < p.min_replan_s:
            return False  # a plan, found or not, stands at least this long: A* is not free
        if since >= p.replan_s or self.path is None:
            return True
        if math.dist(goal, self._plan_goal) > p.retarget_m:
            return True
        # The path ahead runs into something seen since: replan.
        return not self._ahead_clear(here)

    def _ahead_clear(self, here: tuple[float, float]) -> bool:
        """The path's next check_m from the relay's place on it keeps clear of the map."""
        assert self.path is not None
        inflate = self.p.plan.inflate_m * 0.8
        # From inflate_m on: where the robot stands, a wall beside it is no news.
        pts = _ahead(self.path, here, self.p.check_m)
        skip = _ahead(self.path, here, self.p.plan.inflate_m)
        rest = [skip[-1], *pts[len(skip) - 1 :][1:]] if len(pts) >= len(skip) else pts
        return all(self.grid.segment_clear(a, b, inflate) for a, b in itertools.pairwise(rest))

    def path_json(self) -> list[list[float]] | None:
        """/status's `trail.detour_m`: the detour's path in force (m), or None."""
        if self.last is None:
            return None
        return [[round(x, 3), round(y, 3)] for x, y in self.last.path]

    def _drop(self) -> None:
        self.path = self.last = None
        self._plan_t = self._plan_goal = self._clear_since = None


def _ahead(path: Path, here: tuple[float, float], ahead_m: float) -> list[tuple[float, float]]:
    """The path from its point nearest `here` (its projection) to ahead_m along it, as points."""
    i, cur = _nearest(path, here)
    out = [cur]
    left = ahead_m
    for j in range(i + 1, len(path)):
        seg = math.dist(cur, path[j])
        if seg >= left:
            f = left / seg
            out.append((cur[0] + f * (path[j][0] - cur[0]), cur[1] + f * (path[j][1] - cur[1])))
            return out
        left -= seg
        cur = path[j]
        out.append(cur)
    return out


def _along(path: Path, here: tuple[float, float], ahead_m: float) -> tuple[float, float]:
    """The point ahead_m along the path from its point nearest `here` (its projection)."""
    return _ahead(path, here, ahead_m)[-1]


def _nearest(path: Path, here: tuple[float, float]) -> tuple[int, tuple[float, float]]:
    """(index of the segment's start, the point) of the path nearest `here`."""
    best_i, best_d, best_pt = 0, math.inf, path[0]
    for i in range(len(path) - 1):
        pt = _project(here, path[i], path[i + 1])
        d = math.dist(here, pt)
        if d < best_d:
            best_i, best_d, best_pt = i, d, pt
    return best_i, best_pt


def _project(
    p: tuple[float, float], a: tuple[float, float], b: tuple[float, float]
) -> tuple[float, float]:
    ax, ay = b[0] - a[0], b[1] - a[1]
    n = ax * ax + ay * ay
    if n < 1e-12:
        return a
    f = max(0.0, min(1.0, ((p[0] - a[0]) * ax + (p[1] - a[1]) * ay) / n))
    return (a[0] + f * ax, a[1] + f * ay)
