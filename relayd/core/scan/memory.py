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
from relayd.core.scan.leader import LeaderParams, make_model
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
        #: The bearing estimator behind the bearing memory below (`relayd.core.scan.leader`).
        self.model = make_model(leader)
        #: The scanner asked for a plan while the servo was not answering: plan when it is.
        self._wanted = False
        self.last_scan_t: float | None = None
        #: Scans that gave an estimate (the recovery's breadcrumbs count them).
        self.count = 0
        self.lost_count = 0
        self.bearing_deg: float | None = None
        self.bearing_heading_deg: float | None = None
        self.prev_bearing_deg: float | None = None
        self.prev_heading_deg: float | None = None
        self.rssi_leader_dbm: float | None = None

    @property
    def leader_lost(self) -> bool:
        return self.lost_count >= LOST_AFTER_SCANS

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
                est = self.model.scan_done(
                    ev.t,
                    heading_end if heading_end is not None else samples[-1].heading_deg,
                    est,
                    times,
                )
            if est is not None:
                period_s = ev.t - ev.started_t
                self.prev_bearing_deg, self.prev_heading_deg = (
                    self.bearing_deg,
                    self.bearing_heading_deg,
                )
                self.bearing_deg, self.bearing_heading_deg = est.bearing_deg, heading_end
                self.rssi_leader_dbm = est.rssi_leader_dbm
                self.lost_count = update_lost_count(
                    self.lost_count, est.rssi_leader_dbm, self._params.lost_rssi_dbm
                )
                self.last_scan_t = ev.t
                self.count += 1
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
            self.model.lost(now, heading_deg) and not self.stale(now, following)
        )

    def stale(self, now: float, following: bool) -> bool:
        """No completed scan for `scan_timeout_s` while following, once a bearing exists."""
        limit = self._params.scan_timeout_s
        return (
            limit is not None
            and following
            and self.last_scan_t is not None
            and now - self.last_scan_t > limit
        )

    def bearing_now(self, now: float, heading_deg: float | None) -> float | None:
        """The bearing to steer by: the filter's prediction, else the last scan's in the current frame."""
        predicted = self.model.bearing_now(now, heading_deg)
        if predicted is not None:
            return predicted
        return in_current_frame(self.bearing_deg, self.bearing_heading_deg, heading_deg)

    def prev_bearing_now(self, heading_deg: float | None) -> float | None:
        """The scan before the last one's bearing, in the current frame (the controller's D term)."""
        return in_current_frame(self.prev_bearing_deg, self.prev_heading_deg, heading_deg)

    def plan(self, now: float, heading_deg: float | None, following: bool) -> ScanPlan:
        """The next sweep (relayd/core/scan/plan.py), each in the other direction than the last."""
        sp, lost = self._params, self.lost(now, heading_deg, following)
        planned = None if lost else self.model.window(now, heading_deg, full_window(sp))
        window = next_window(sp, lost, planned, self.bearing_now(now, heading_deg))
        plan, self._ascending = sweep_plan(sp, window, self._ascending), not self._ascending
        return plan
