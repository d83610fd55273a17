"""The brain's memory of the leader's trail: its one writer (pure).

`TrailKeeper.scan` takes each finished scan (its time, the relay's odometry pose, the
bearing in the robot frame and its sd, RSSI^l, the sonar floor) and updates the leader
estimate (`estimate`) and the trail (`polyline`) behind it; `steer` prunes the trail
behind the relay and asks `pursuit` where to go. `view` is what /status and the trace
show. An estimate less sure than `max_sigma_m` puts nothing on the trail (its source
is then "bearing": the law steers by the scan bearing as the paper's relays did).

A robot leader's own path (`feed`, relayd/core/trail/feed.py: its GET /path aligned
into our frame) comes first while it is up: the source is then "leader_feed". Stale
or rejected, the estimated trail takes over, then the bearing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from relayd.core.events import LeaderPath
from relayd.core.scan.estimator import SonarReading
from relayd.core.trail.estimate import EstimateParams, LeaderEstimate, observe
from relayd.core.trail.feed import FeedParams, FeedView, LeaderFeed
from relayd.core.trail.polyline import Trail, TrailPoint, add_point, prune, remaining_m
from relayd.core.trail.pursuit import Pursuit, PursuitParams, pursue

#: This relay's own path: a point each 0.1 m (the centimetre a follower wants is in the
#: feed's poses between them), the newest 600 (60 m).
OWN_SPACING_M, OWN_KEEP = 0.1, 600
#: With no estimate, a detour heads this far along the scan bearing (m).
FALLBACK_M = 5.0
#: Where the trail came from, as /status names it.
SOURCE_FEED, SOURCE_ESTIMATE, SOURCE_BEARING = "leader_feed", "estimate", "bearing"


@dataclass(frozen=True, slots=True)
class TrailParams:
    #: "trail": steer along the leader's trail; "bearing": the paper's direct pursuit.
    pursuit: str = "bearing"
    estimate: EstimateParams = field(default_factory=EstimateParams)
    pursue: PursuitParams = field(default_factory=PursuitParams)
    spacing_m: float = 0.4
    keep: int = 400
    reach_m: float = 0.4
    prune_window: int = 8
    #: A position this unsure (1-sigma radius, m) is not laid on the trail.
    max_sigma_m: float = 4.0
    #: Caught up with the head: hold and scan this long (s), then steer by the bearing until
    #: the trail has a new point (a head that no longer moves may be an estimate gone stale).
    hold_s: float = 6.0
    #: A robot leader's own path (its prior None: no feed, the estimate alone).
    feed: FeedParams = field(default_factory=FeedParams)


@dataclass(frozen=True, slots=True)
class TrailView:
    """What /status shows of the trail (odometry frame, metres)."""

    source: str
    leader_xy_m: tuple[float, float] | None
    leader_sigma_m: float | None
    points: tuple[tuple[float, float], ...]
    steer_deg: float | None
    caught_up: bool
    #: The robot leader's feed (None: no leader_url).
    feed: FeedView | None = None

    def to_json(self) -> dict[str, object]:
        """/status's `trail` (the newest MAX_SHOWN points of it)."""
        return {
            "feed": None if self.feed is None else self.feed.to_json(),
            "source": self.source,
            "leader_xy_m": None if self.leader_xy_m is None else list(self.leader_xy_m),
            "leader_sigma_m": self.leader_sigma_m,
            "points_m": [list(p) for p in self.points[-MAX_SHOWN:]],
            "steer_deg": self.steer_deg,
            "caught_up": self.caught_up,
        }


#: /status shows at most this many of the trail's newest points.
MAX_SHOWN = 100


class TrailKeeper:
    def __init__(self, params: TrailParams) -> None:
        self.params = params
        self.estimate: LeaderEstimate | None = None
        self.trail: Trail = ()
        self.last: Pursuit | None = None
        #: This relay's own path (odometry, thinned): what a relay following it follows
        #: (GET /path), and the pose with its time.
        self.own_path: Trail = ()
        self.own: tuple[float, float, float, float] | None = None
        self._held_since: float | None = None
        self._held_head: TrailPoint | None = None
        self.feed = None if params.feed.prior is None else LeaderFeed(params.feed)
        self._source = SOURCE_BEARING
        self._now: float | None = None
        self._fed: Trail | None = None

    def leader_path(self, ev: LeaderPath) -> None:
        """An answer of the leader relay's GET /path (ignored without a configured feed)."""
        if self.feed is not None:
            self.feed.on_path(ev)

    def own_pose(self, t_s: float, pose_mm_deg: tuple[float, float, float]) -> None:
        """This relay's odometry pose of a SIP, onto its own published path."""
        x, y = pose_mm_deg[0] / 1000.0, pose_mm_deg[1] / 1000.0
        self.own = (t_s, x, y, pose_mm_deg[2])
        if self.own_path and math.dist(self.own_path[-1].xy, (x, y)) < OWN_SPACING_M:
            return
        point = TrailPoint(t_s, x, y)
        self.own_path = (*self.own_path, point)[-OWN_KEEP:]

    def path_json(self) -> dict[str, object]:
        """GET /path: the pose and the path, odometry frame (m, deg; times on the daemon's clock)."""
        own = self.own
        return {
            "pose": None
            if own is None
            else {
                "t": own[0],
                "x_m": round(own[1], 3),
                "y_m": round(own[2], 3),
                "theta_deg": own[3],
            },
            "points": [[p.t_s, round(p.x_m, 3), round(p.y_m, 3)] for p in self.own_path],
        }

    def scan(
        self,
        t_s: float,
        pose_mm_deg: tuple[float, float, float] | None,
        bearing_deg: float | None,
        bearing_sd_deg: float | None,
        rssi_dbm: float | None,
        floor_m: float | None,
    ) -> None:
        """One finished scan seen from this pose (robot-frame bearing)."""
        if pose_mm_deg is None or not math.isfinite(t_s):
            return
        if bearing_deg is not None and not math.isfinite(bearing_deg):
            bearing_deg = None
        if rssi_dbm is not None and not math.isfinite(rssi_dbm):
            rssi_dbm = None
        xy = (pose_mm_deg[0] / 1000.0, pose_mm_deg[1] / 1000.0)
        world = None if bearing_deg is None else pose_mm_deg[2] + bearing_deg
        if self.feed is not None and world is not None:
            self.feed.sight(t_s, xy, world, bearing_sd_deg)
        self.estimate = observe(
            self.estimate, t_s, xy, world, bearing_sd_deg, rssi_dbm, floor_m, self.params.estimate
        )
        est = self.estimate
        if est is None or est.sigma_m > self.params.max_sigma_m:
            return
        p = self.params
        point = TrailPoint(t_s, est.x[0], est.x[1], est.sigma_m)
        # An estimate jitters within its sigma: only a move beyond half of it is the leader's.
        spacing = max(p.spacing_m, 0.5 * est.sigma_m)
        self.trail = add_point(self.trail, point, spacing_m=spacing, keep=p.keep)

    def steer(
        self,
        now_s: float,
        pose_mm_deg: tuple[float, float, float] | None,
        front: Sequence[SonarReading],
    ) -> Pursuit | None:
        """Where pursuit steers from this pose (None: no trail, steer by the bearing)."""
        self._now = now_s
        if pose_mm_deg is None:
            self.last = None
            return None
        x, y, th = pose_mm_deg[0] / 1000.0, pose_mm_deg[1] / 1000.0, pose_mm_deg[2]
        p = self.params
        # Pruned even while the feed leads, so a fall-back finds it from where the relay is.
        self.trail = prune(self.trail, (x, y), reach_m=p.reach_m, window=p.prune_window)
        fed = None if self.feed is None else self.feed.trail(now_s, (x, y))
        self._fed = fed
        if fed:
            # The leader's own path: its head is where it is, no estimate to go stale.
            self._held_since = self._held_head = None
            self._source = SOURCE_FEED
            self.last = pursue(fed, (x, y, th), front, p.pursue)
            return self.last
        self._source = SOURCE_ESTIMATE
        got = pursue(self.trail, (x, y, th), front, p.pursue)
        if got is not None and got.caught_up:
            # The last committed point: a head that only jitters on its estimate is no news.
            head = self.trail[-2] if len(self.trail) >= 2 else self.trail[0]
            if self._held_head is None or head.t_s != self._held_head.t_s:
                self._held_since, self._held_head = now_s, head
            if now_s - (self._held_since or now_s) > p.hold_s:
                got = None  # held long enough on a head that does not move: the bearing
        else:
            self._held_since = self._held_head = None
        self.last = got
        return got

    def remaining_m(self, pose_mm_deg: tuple[float, float, float] | None) -> float | None:
        """How far the relay still has to go: along the trail to its head, else to the estimate."""
        if pose_mm_deg is None:
            return None
        xy = (pose_mm_deg[0] / 1000.0, pose_mm_deg[1] / 1000.0)
        if self._source == SOURCE_FEED and self._fed:
            return remaining_m(self._fed, xy)
        if self.trail:
            return remaining_m(self.trail, xy)
        if self.estimate is not None:
            return math.dist(xy, self.estimate.xy_m)
        return None

    @property
    def leader_xy_m(self) -> tuple[float, float] | None:
        """The leader's estimated position (m, odometry frame); None before a scan placed it."""
        return None if self.estimate is None else self.estimate.xy_m

    def goal_xy(
        self, pose_mm_deg: tuple[float, float, float] | None, bearing_deg: float | None
    ) -> tuple[float, float] | None:
        """Where a detour round the sonar map heads (relayd/core/plan): nowhere while a robot
        leader's own driven path leads (it is free where the leader went), else the leader's
        estimate while it is sure enough, else a point FALLBACK_M along the scan bearing."""
        if pose_mm_deg is None:
            return None
        last = self.last
        if self.params.pursuit == "trail" and self._source == SOURCE_FEED and last is not None:
            return None  # the leader relay's own driven path: free where it went, no detour
        est = self.estimate
        if est is not None and est.sigma_m <= self.params.max_sigma_m:
            return est.xy_m
        if bearing_deg is None or not math.isfinite(bearing_deg):
            return None
        a = math.radians(pose_mm_deg[2] + bearing_deg)
        x, y = pose_mm_deg[0] / 1000.0, pose_mm_deg[1] / 1000.0
        return (x + FALLBACK_M * math.cos(a), y + FALLBACK_M * math.sin(a))

    def view(self) -> TrailView:
        est = self.estimate
        steering = self.params.pursuit == "trail" and self.last is not None
        src = self._source if steering else SOURCE_BEARING
        last = self.last
        feed = None if self.feed is None else self.feed.view(self._now or 0.0)
        return TrailView(
            src,
            None if est is None else (round(est.x[0], 3), round(est.x[1], 3)),
            None if est is None else round(est.sigma_m, 3),
            tuple((round(p.x_m, 3), round(p.y_m, 3)) for p in self.trail),
            None if last is None or last.steer_deg is None else round(last.steer_deg, 1),
            last is not None and last.caught_up,
            feed,
        )
