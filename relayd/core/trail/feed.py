"""A robot leader's own path, aligned into this relay's odometry frame (pure; the one writer).

A relay that follows a relay reads its leader's GET /path (`LeaderPath` events: the
leader's pose and driven path in *its* odometry frame, on *its* clock). `LeaderFeed`
keeps the newest answer and turns it into a trail in this relay's frame:

- **The frame** (`align.py`): the start poses give the prior (`FeedParams.prior`:
  where the leader's odometry origin lies in ours, from `[control] leader_origin` or
  the fleet config's origins). Each finished scan with a usable bearing is a sighting:
  our pose, the bearing in our frame and where the feed put the leader at that moment.
  While the newest `sightings` agree with the prior (median absolute residual within
  `keep_prior_deg`: the antenna's own bias is a few degrees, and fitting it would
  move a right prior by a metre), the prior stands; when they disagree they refine it
  (Gauss-Newton, align.py, on the sightings that agree with a first fit); an
  alignment whose bearings still disagree (median beyond the bound), or that needs
  too large a correction, is rejected and the feed is not followed while it stands
  (`state` says why).
- **The clocks**: a point's time is the leader's clock. The offset to ours is the
  smallest (receipt time - pose time) of the recent answers (latency only adds), so a
  sighting is matched with where the leader was, not where it is.
- **Fresh**: the leader's pose time must advance; an answer older than `stale_s` (by
  our clock) is stale and the trail falls back to the estimate, then to the bearing.
- **The trail**: the path's points in our frame, the leader's pose as its head, less
  `standoff_m` along it (the head is a robot, not a place to drive to). The part the
  relay has passed is cut by the leader's time of the last point reached, so a path
  that doubles back is not joined across its loop; after a gap (stale, rejected) the
  relay joins again at its nearest later point.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from relayd.core.events import LeaderPath
from relayd.core.trail.align import (
    Alignment,
    AlignParams,
    Frame,
    Sighting,
    align,
    residuals_deg,
)
from relayd.core.trail.polyline import Trail, TrailPoint, prune

#: The feed's states as /status and the trace show them.
FEED_WAITING, FEED_UP, FEED_STALE, FEED_REJECTED = "waiting", "up", "stale", "rejected"


@dataclass(frozen=True, slots=True)
class FeedParams:
    #: The leader's odometry frame in ours (the start poses); None: no leader feed.
    prior: Frame | None = None
    stale_s: float = 2.0
    #: The trail's head stops this far (m, along the path) behind the leader's pose.
    standoff_m: float = 1.5
    #: Sightings kept for the alignment (the newest), at most one per `sight_every_s`.
    sightings: int = 120
    sight_every_s: float = 1.0
    #: Fewer sightings than this cannot reject the prior (one odd bearing is not a verdict).
    min_sightings: int = 10
    #: A bearing less sure than this (deg, the tracking filter's sd) is no sighting.
    max_bearing_sd_deg: float = 15.0
    #: Sightings whose feed position is this far (s, leader clock) beyond its newest pose
    #: are not matched (the feed lags the scan).
    max_extrapolate_s: float = 0.5
    #: Sightings nearer than 2 m are not used: across a metre or two the antenna's offset
    #: from the robot's centre and the leader's size are degrees (a simulator run rejected
    #: a right prior on such bearings while standing 2 m behind its leader).
    align: AlignParams = field(default_factory=lambda: AlignParams(min_range_m=2.0))
    #: The bearings' median absolute residual (deg) under the prior up to which it stands.
    keep_prior_deg: float = 8.0
    #: How many of the path's points ahead the relay may be found at (0.1 m each).
    prune_window: int = 30
    reach_m: float = 0.4


@dataclass(frozen=True, slots=True)
class FeedView:
    state: str
    age_s: float | None
    alignment: str | None
    residual_deg: float | None
    sightings: int

    def to_json(self) -> dict[str, object]:
        return {
            "state": self.state,
            "age_s": self.age_s,
            "alignment": self.alignment,
            "residual_deg": self.residual_deg,
            "sightings": self.sightings,
        }


class LeaderFeed:
    def __init__(self, params: FeedParams) -> None:
        assert params.prior is not None, "a leader feed needs the start poses' prior"
        self.params = params
        self.prior: Frame = params.prior
        self.frame: Frame = params.prior
        self.alignment: Alignment | None = None
        #: The leader's path and pose, its frame and clock: (t_s, x_m, y_m), oldest first.
        self.path: tuple[tuple[float, float, float], ...] = ()
        self.pose: tuple[float, float, float, float] | None = None
        #: Our clock time of the last answer whose pose was newer than the one before.
        self.fresh_t: float | None = None
        self._offsets: tuple[float, ...] = ()
        self.sightings: tuple[Sighting, ...] = ()
        self._last_sight_t: float | None = None
        #: The leader's time of the last path point the relay reached (None: join afresh).
        self._reached_t: float | None = None
        self._joined = False
        #: The path in our frame, less the standoff, and the frame it was mapped with.
        self._mapped: tuple[Frame, list[TrailPoint]] | None = None

    # -- inputs ---------------------------------------------------------------------------

    def on_path(self, ev: LeaderPath) -> None:
        pose = ev.pose
        if pose is None or not all(math.isfinite(v) for v in pose):
            return
        points = tuple(p for p in ev.points if all(math.isfinite(v) for v in p))
        if self.pose is None or pose[0] > self.pose[0]:
            self.fresh_t = ev.t
            # The tightest of the recent answers: latency and the SIP's age only add.
            self._offsets = (*self._offsets, ev.t - pose[0])[-20:]
        self.pose, self.path = pose, points
        self._mapped = None

    def sight(
        self,
        t_s: float,
        own_xy_m: tuple[float, float],
        bearing_world_deg: float,
        bearing_sd_deg: float | None,
    ) -> None:
        """One finished scan's bearing of the leader (our frame) into the alignment."""
        p = self.params
        if not math.isfinite(bearing_world_deg):
            return
        if bearing_sd_deg is not None and not bearing_sd_deg <= p.max_bearing_sd_deg:
            return
        if self._last_sight_t is not None and t_s - self._last_sight_t < p.sight_every_s:
            return
        where = self.leader_at(t_s)
        if where is None:
            return
        self._last_sight_t = t_s
        self.sightings = (*self.sightings, Sighting(own_xy_m, bearing_world_deg, where))[
            -p.sightings :
        ]
        got = self._judge()
        if got.accepted and self.alignment is not None and not self.alignment.accepted:
            self._joined = False  # back from a rejection: join the path afresh
        self.alignment = got
        if got.accepted:
            self.frame = got.frame

    def _judge(self) -> Alignment:
        """The prior while the bearings agree with it, else the refinement, else rejected.

        Judged by the median absolute residual, not the RMS: a leader behind a wall is
        heard along the corridor its signal takes, 20-30 deg off, for as long as it is
        there (measured in the simulator's corners), and such stretches must not move
        the frame or reject it. The antenna's own bias (a few degrees: the lobe fit)
        must not either, so the prior stands while the median is within
        `keep_prior_deg`; beyond it the frame is refitted on the sightings that agree
        with a first fit, and rejected if even that leaves the median beyond the bound.
        """
        p, a = self.params, self.params.align
        prior = self.prior
        use = [
            s
            for s in self.sightings
            if math.dist(prior.apply(s.leader_xy_m), s.own_xy_m) >= a.min_range_m
        ]
        at_prior = _median_abs(residuals_deg(prior, use))
        if len(use) < p.min_sightings or at_prior <= p.keep_prior_deg:
            return Alignment(prior, at_prior, len(use), True, "prior")
        first = align(prior, use, a)
        res = residuals_deg(first.frame, use)
        gate = max(3.0 * _median_abs(res), 2.0 * a.bearing_sd_deg)
        second = align(prior, [s for s, r in zip(use, res, strict=True) if abs(r) <= gate], a)
        median = _median_abs(residuals_deg(second.frame, use))
        if median > a.max_rms_deg or second.why == "bearings_disagree":
            return Alignment(second.frame, median, len(use), False, "bearings_disagree")
        return Alignment(second.frame, median, len(use), second.accepted, second.why)

    # -- reading --------------------------------------------------------------------------

    def offset_s(self) -> float | None:
        return min(self._offsets) if self._offsets else None

    def leader_at(self, t_s: float) -> tuple[float, float] | None:
        """Where the feed puts the leader (its frame) at our clock time t_s; None: unknown."""
        off = self.offset_s()
        if off is None or self.pose is None:
            return None
        tl = t_s - off
        track = [*self.path, self.pose[:3]]
        if tl > track[-1][0] + self.params.max_extrapolate_s or tl < track[0][0]:
            return None
        for a, b in itertools.pairwise(track):
            if a[0] <= tl <= b[0]:
                f = 0.0 if b[0] <= a[0] else (tl - a[0]) / (b[0] - a[0])
                return a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2])
        return track[-1][1], track[-1][2]

    def state(self, now_s: float) -> str:
        if self.fresh_t is None:
            return FEED_WAITING
        if now_s - self.fresh_t > self.params.stale_s:
            return FEED_STALE
        if self.alignment is not None and not self.alignment.accepted:
            return FEED_REJECTED
        return FEED_UP

    def trail(self, now_s: float, own_xy_m: tuple[float, float]) -> Trail | None:
        """The leader's path in our frame, the part behind the relay cut; None: not usable."""
        if self.state(now_s) != FEED_UP or self.pose is None:
            self._joined = False
            return None
        p = self.params
        if self._mapped is None or self._mapped[0] is not self.frame:
            # Once per answer or alignment, not per control step (600 points).
            pts = [TrailPoint(t, *self.frame.apply((x, y))) for t, x, y in self.path]
            pts.append(TrailPoint(self.pose[0], *self.frame.apply(self.pose[1:3])))
            self._mapped = (self.frame, _less_standoff(pts, p.standoff_m))
        pts = self._mapped[1]
        if self._reached_t is not None:
            pts = [q for q in pts if q.t_s >= self._reached_t]
        if not pts:
            return None
        if not self._joined:
            # Join at the nearest point from here on (the start, or back after a gap).
            k = min(range(len(pts)), key=lambda i: math.dist(pts[i].xy, own_xy_m))
            pts = pts[k:]
            self._joined = True
        trail = prune(tuple(pts), own_xy_m, reach_m=p.reach_m, window=p.prune_window)
        self._reached_t = trail[0].t_s
        return trail

    def view(self, now_s: float) -> FeedView:
        a = self.alignment
        return FeedView(
            self.state(now_s),
            None if self.fresh_t is None else round(now_s - self.fresh_t, 2),
            None if a is None else a.why,
            None if a is None or not math.isfinite(a.rms_deg) else round(a.rms_deg, 1),
            len(self.sightings),
        )


def _less_standoff(pts: Sequence[TrailPoint], standoff_m: float) -> list[TrailPoint]:
    """The path without its last `standoff_m` (the new head interpolated on its segment)."""
    out = list(pts)
    left = standoff_m
    while len(out) >= 2 and left > 0.0:
        a, b = out[-2], out[-1]
        seg = math.dist(a.xy, b.xy)
        if seg > left:
            f = (seg - left) / seg
            out[-1] = TrailPoint(b.t_s, a.x_m + f * (b.x_m - a.x_m), a.y_m + f * (b.y_m - a.y_m))
            return out
        left -= seg
        out.pop()
    return out if left <= 0.0 else out[:1]


def _median_abs(values: Sequence[float]) -> float:
    v = sorted(abs(x) for x in values)
    if not v:
        return math.nan
    m = len(v) // 2
    return v[m] if len(v) % 2 else 0.5 * (v[m - 1] + v[m])
