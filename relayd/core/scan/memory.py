"""The brain's memory of its scans: the sweep in progress, what the finished ones said, the next sweep.

`relayd.core.brain.Brain` hands its scan events here (`ready`, `sample`, `done`, and
`servo_up` when the scan servo answers again) and asks
back what the scans say: the bearing to steer by (`bearing_now`: the tracking filter's
prediction, else the last scan's in the current frame), whether the leader is lost
(`lost`), whether scans stopped completing (`stale`), and where to sweep next (`plan`).
Each finished scan becomes an estimate (`relayd.core.scan.estimator`) that the bearing model
(`relayd.core.scan.leader`) takes in, and counts toward leader-lost. `ScanMemory` is the only
writer of this memory, as the brain is of the rest of what the robot knows; the
robot's heading and whether it follows come in as arguments.

Pure: times come in the events and arguments; no clock, no I/O.
"""

from __future__ import annotations

from collections.abc import Sequence

from relayd.core.events import Action, ScanDone, ScanPlan, ScanResult, ScanSampleEvent, ServoTarget
from relayd.core.scan.estimator import (
    LOST_AFTER_SCANS,
    EstimatorParams,
    ScanSample,
    estimate_scan,
    front_readings,
    update_lost_count,
)
from relayd.core.scan.leader import BearingModel, LeaderParams, TrackingModel, make_model
from relayd.core.scan.plan import ScanParams, full_window, in_current_frame, next_window, sweep_plan
from relayd.core.vocab import ScanRecord


class ScanMemory:
    """The bearing memory of the scans and the sweep in progress. Call in event order."""

    def __init__(self, scan: ScanParams, estimator: EstimatorParams, leader: LeaderParams) -> None:
        self._params = scan
        self._estimator = estimator
        self._ascending = True
        self._scan: list[ScanSample] = []
        self._scan_t: list[float] = []
        self._model = make_model(leader)
        #: The scanner asked for a plan while the servo was not answering: plan when it is.
        self._wanted = False
        self._last_scan_t: float | None = None
        self._count = 0
        self._lost_count = 0
        self._bearing_deg: float | None = None
        self._bearing_heading_deg: float | None = None
        self._prev_bearing_deg: float | None = None
        self._prev_heading_deg: float | None = None
        self._rssi_leader_dbm: float | None = None

    # -- read-only views (the bearing memory is written by `remember` alone) -------------

    @property
    def bearing_deg(self) -> float | None:
        """The last scan's bearing (robot frame at `bearing_heading_deg`)."""
        return self._bearing_deg

    @property
    def bearing_heading_deg(self) -> float | None:
        return self._bearing_heading_deg

    @property
    def prev_bearing_deg(self) -> float | None:
        """The scan before the last one's bearing (robot frame at `prev_heading_deg`)."""
        return self._prev_bearing_deg

    @property
    def prev_heading_deg(self) -> float | None:
        return self._prev_heading_deg

    @property
    def rssi_leader_dbm(self) -> float | None:
        return self._rssi_leader_dbm

    @property
    def model(self) -> BearingModel:
        """The bearing estimator behind the bearing memory (`relayd.core.scan.leader`)."""
        return self._model

    def pattern_learned(self) -> dict[str, object] | None:
        """How far the online pattern learner has come (/status; None: not learning)."""
        m = self._model
        status = m.learned_status() if isinstance(m, TrackingModel) else None
        return None if status is None else status.to_json()

    @property
    def count(self) -> int:
        """Scans that gave an estimate (the recovery's breadcrumbs count them)."""
        return self._count

    @property
    def lost_count(self) -> int:
        return self._lost_count

    @property
    def last_scan_t(self) -> float | None:
        return self._last_scan_t

    @property
    def leader_lost(self) -> bool:
        return self._lost_count >= LOST_AFTER_SCANS

    def remember(
        self, bearing_deg: float, heading_deg: float | None, rssi_leader_dbm: float
    ) -> None:
        """A finished scan's bearing into the bearing memory: the last one becomes the one before.

        The one writer of the bearing memory: `done` calls it with each scan's estimate. It is
        also the set-up seam for a brain that starts with bearings in memory (a test of the
        control shell without a scanner): a caller puts bearings in the way a scan does,
        through this method, instead of writing fields, and touches nothing else a scan does
        (no scan time, no leader-lost count, no tracking filter, no trail).
        """
        self._prev_bearing_deg, self._prev_heading_deg = (
            self._bearing_deg,
            self._bearing_heading_deg,
        )
        self._bearing_deg, self._bearing_heading_deg = bearing_deg, heading_deg
        self._rssi_leader_dbm = rssi_leader_dbm

    # -- the sweep in progress ------------------------------------------------------------

    def ready(
        self, now: float, heading_deg: float | None, following: bool, servo_ok: bool
    ) -> list[Action]:
        """The scanner is ready for a sweep: what the last one left unfinished is dropped, and
        the next one is planned now, or when the servo answers (`servo_up`)."""
        self._scan, self._scan_t = [], []
        if not servo_ok:
            self._wanted = True
            return []
        return [self.plan(now, heading_deg, following)]

    def servo_up(self, now: float, heading_deg: float | None, following: bool) -> list[Action]:
        """The scan servo answers again: the sweep the scanner was waiting for, if it was."""
        if not self._wanted:
            return []
        self._wanted = False
        return [self.plan(now, heading_deg, following)]

    def sample(self, ev: ScanSampleEvent, heading_deg: float | None) -> None:
        self._scan.append(ScanSample(ev.angle_deg, ev.rssi_dbm, self._sample_heading(heading_deg)))
        self._scan_t.append(ev.t)

    def _sample_heading(self, heading_deg: float | None) -> float:
        if heading_deg is not None:
            return heading_deg
        return self._scan[-1].heading_deg if self._scan else 0.0

    def done(
        self, ev: ScanDone, heading_deg: float | None, sonar: Sequence[int | None]
    ) -> list[Action]:
        """The sweep is over: its estimate, the bearing memory, and the data antenna's new aim."""
        samples, self._scan = self._scan, []
        times, self._scan_t = self._scan_t, []
        actions: list[Action] = []
        if len(samples) >= 3:
            heading_end = heading_deg
            try:
                est = estimate_scan(
                    samples,
                    heading_end if heading_end is not None else samples[-1].heading_deg,
                    front_readings(sonar),
                    self._estimator,
                )
            except ValueError:
                est = None  # bad sonar data: this scan is lost, the next one is planned
            if est is not None:
                est = self._model.scan_done(
                    ev.t,
                    heading_end if heading_end is not None else samples[-1].heading_deg,
                    est,
                    times,
                )
            if est is not None:
                period_s = ev.t - ev.started_t
                self.remember(est.bearing_deg, heading_end, est.rssi_leader_dbm)
                self._lost_count = update_lost_count(
                    self._lost_count, est.rssi_leader_dbm, self._params.lost_rssi_dbm
                )
                self._last_scan_t = ev.t
                self._count += 1
                record = ScanRecord(
                    t=ev.t,
                    angles_deg=tuple(round(a, 2) for a in est.angles_deg),
                    rssi_dbm=tuple(round(r, 2) for r in est.rssi_dbm),
                    bearing_deg=round(est.bearing_deg, 3),
                    rssi_leader_dbm=est.rssi_leader_dbm,
                    situation=est.situation,
                    period_s=period_s,
                )
                actions.append(ScanResult(record, est))
                # Point the data-link antenna at the leader.
                actions.append(ServoTarget(self._params.link_channel, est.bearing_deg))
        return actions

    # -- what the scans say -------------------------------------------------------------

    def lost(self, now: float, heading_deg: float | None, following: bool) -> bool:
        """Leader lost: RSSI^l too low for 3 scans, or the tracking filter lost it."""
        # A filter that lost its leader because no scan completes says so as "scan_stale".
        return self.leader_lost or (
            self._model.lost(now, heading_deg) and not self.stale(now, following)
        )

    def stale(self, now: float, following: bool) -> bool:
        """No completed scan for `scan_timeout_s` while following, once a bearing exists."""
        limit = self._params.scan_timeout_s
        return (
            limit is not None
            and following
            and self._last_scan_t is not None
            and now - self._last_scan_t > limit
        )

    def bearing_now(self, now: float, heading_deg: float | None) -> float | None:
        """The bearing to steer by: the filter's prediction, else the last scan's in the current frame."""
        predicted = self._model.bearing_now(now, heading_deg)
        if predicted is not None:
            return predicted
        return in_current_frame(self._bearing_deg, self._bearing_heading_deg, heading_deg)

    def prev_bearing_now(self, heading_deg: float | None) -> float | None:
        """The scan before the last one's bearing, in the current frame (the controller's D term)."""
        return in_current_frame(self._prev_bearing_deg, self._prev_heading_deg, heading_deg)

    def plan(self, now: float, heading_deg: float | None, following: bool) -> ScanPlan:
        """The next sweep (relayd/core/scan/plan.py), each in the other direction than the last."""
        sp, lost = self._params, self.lost(now, heading_deg, following)
        planned = None if lost else self._model.window(now, heading_deg, full_window(sp))
        window = next_window(sp, lost, planned, self.bearing_now(now, heading_deg))
        plan, self._ascending = sweep_plan(sp, window, self._ascending), not self._ascending
        return plan
