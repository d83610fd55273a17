"""The brain's bearing memory, two ways: the paper's centroid, or a lobe fit with a tracking filter.

`relayd.core.brain` asks a `BearingModel` three things: what a finished scan says
(`scan_done`), where the leader is now (`bearing_now`) and where to sweep next
(`window`). `CentroidModel` ("wca") is the paper's weighted centroid, kept until the
next scan. `TrackingModel` ("lobe") fits each scan's main lobe (core/scan/bearing.py),
pools a steady leader's scans (pool.py), feeds a Kalman filter on bearing and rate
(tracker.py) whose prediction the wheels steer by, and with `window = "adaptive"` sizes
the sweep from its confidence (window.py); why, in docs/CONTROL.md 10. No clock, no I/O.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol

from relayd.core.scan import tracker
from relayd.core.scan.bearing import LobeFit, LobeParams, fit_main_lobe
from relayd.core.scan.estimator import ScanEstimate
from relayd.core.scan.learn import LearnParams, LearnStatus, PatternLearner
from relayd.core.scan.moving import fit_moving
from relayd.core.scan.pattern import AntennaPattern
from relayd.core.scan.patternfit import PatternFitParams, fit_pattern
from relayd.core.scan.plan import in_current_frame
from relayd.core.scan.pool import PooledScan, PoolParams, ScanPool
from relayd.core.scan.tracker import Track, TrackerParams
from relayd.core.scan.window import Window, WindowParams, sized_window

ESTIMATORS = ("wca", "lobe")
WINDOWS = ("full", "adaptive")


@dataclass(frozen=True, slots=True)
class LeaderParams:
    estimator: str = "wca"
    window: str = "full"
    lobe: LobeParams = field(default_factory=LobeParams)
    #: The antenna's measured pattern (`[scan] pattern_file`): with it each scan is fitted by
    #: matching the pattern (`relayd.core.scan.patternfit`), not by the main-lobe parabola.
    pattern: AntennaPattern | None = None
    pattern_fit: PatternFitParams = field(default_factory=PatternFitParams)
    #: No file: learn the pattern from sure scans, fit with it once learnt (scan/learn.py).
    learn_pattern: bool = False
    learn: LearnParams = field(default_factory=LearnParams)
    tracker: TrackerParams = field(default_factory=TrackerParams)
    adaptive: WindowParams = field(default_factory=WindowParams)
    #: Two-sided fits the beamwidth is learnt from (median of the last ones).
    beamwidth_memory: int = 9
    pool: PoolParams = field(default_factory=PoolParams)
    #: Fit a moving leader's scan in its own frame (`TrackingModel._leader_frame`).
    compensate_motion: bool = True
    #: With no lobe fit, the strongest sample at a servo limit is evidence of a leader out
    #: of reach only when at least this loud (dBm): below it is what the lost rule calls no
    #: leader (`control.lost_rssi_dbm`; the daemon sets it from that key).
    evidence_min_rssi_dbm: float = -85.0
    #: Evidence older than this (s) starts no search turn: a few nominal scan periods (the
    #: daemon sets 4; the loss itself takes 3 scans without a usable lobe, docs/CONTROL.md 6.1).
    evidence_max_age_s: float = 14.0

    def __post_init__(self) -> None:
        if self.estimator not in ESTIMATORS:
            raise ValueError(f"estimator must be one of {ESTIMATORS}, got {self.estimator!r}")
        if self.window not in WINDOWS:
            raise ValueError(f"window must be one of {WINDOWS}, got {self.window!r}")
        if self.window == "adaptive" and self.estimator != "lobe":
            raise ValueError("an adaptive window needs the tracking estimator ('lobe')")


class BearingModel(Protocol):
    def scan_done(
        self, t: float, heading_deg: float, est: ScanEstimate, sample_t: Sequence[float]
    ) -> ScanEstimate: ...
    def bearing_now(self, t: float, heading_deg: float | None) -> float | None: ...
    def window(self, t: float, heading_deg: float | None, full: Window) -> Window | None: ...
    def lost(self, t: float, heading_deg: float | None) -> bool: ...
    def sd_deg(self, t: float, heading_deg: float | None) -> float | None: ...
    def search_bearing(self, t: float, heading_deg: float | None) -> float | None: ...


class CentroidModel:
    """The paper's WCA: the brain's own memory of the last scan is the bearing."""

    def scan_done(
        self, t: float, heading_deg: float, est: ScanEstimate, sample_t: Sequence[float]
    ) -> ScanEstimate:
        return est

    def bearing_now(self, t: float, heading_deg: float | None) -> float | None:
        return None  # the brain carries the last scan's bearing into the current frame itself

    def window(self, t: float, heading_deg: float | None, full: Window) -> Window | None:
        return None  # the brain's own rule: the configured width, centred on the last bearing

    def lost(self, t: float, heading_deg: float | None) -> bool:
        return False

    def sd_deg(self, t: float, heading_deg: float | None) -> float | None:
        return None

    def search_bearing(self, t: float, heading_deg: float | None) -> float | None:
        return None  # never lost by its own word: the paper's relay stands and rescans


def _median(xs: Sequence[float]) -> float:
    s = sorted(xs)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


class TrackingModel:
    """Lobe fit + Kalman filter + learned beamwidth + (optionally) the adaptive window."""

    def __init__(self, params: LeaderParams) -> None:
        self.params = params
        self.track: Track | None = None
        self.last_fit: LobeFit | None = None
        self._beamwidths: deque[float] = deque(maxlen=max(1, params.beamwidth_memory))
        #: ... and of every fit, one-sided ones too (the window's fallback only).
        self._any_beamwidths: deque[float] = deque(maxlen=max(1, params.beamwidth_memory))
        #: The residual noise (dB) of recent fits: a fit whose few residuals happen to be
        #: small is not trusted beyond what the channel's noise allows.
        self._noise: deque[float] = deque(maxlen=max(1, params.beamwidth_memory))
        #: How long the last sweep took (s): the window leads the prediction by half of it.
        self._sweep_s = 0.0
        self._pool = ScanPool(params.pool)
        #: The servo's range (from the full window the brain plans with), once known.
        self._span: tuple[float, float] | None = None
        #: Where the scans last put the leader, sure or not, when that was at or beyond a servo
        #: limit (bearing at the scan's end, the heading then, the scan's time): a lost relay
        #: turns toward it (`relayd.core.control.search`) while it is recent.
        self._evidence: tuple[float, float, float] | None = None
        self._pattern_bw = params.pattern.beamwidth_deg() if params.pattern is not None else None
        learn = params.learn_pattern and params.pattern is None
        self.learner = PatternLearner(params.learn) if learn else None

    @property
    def pattern(self) -> AntennaPattern | None:
        """The pattern the fit matches: the file's, else the learnt one once ready, else none."""
        if (file := self.params.pattern) is not None or self.learner is None:
            return file
        return self.learner.pattern() if self.learner.ready else None

    def learned_status(self) -> LearnStatus | None:
        """How far the learnt pattern has come (None: not learning)."""
        return None if self.learner is None else self.learner.status()

    @property
    def beamwidth_deg(self) -> float | None:
        """The antenna's 3 dB beamwidth: the file's, else learnt from two-sided scans, or None."""
        if self.params.pattern is not None:
            return self._pattern_bw
        if (learnt := self.pattern) is not None:
            return learnt.beamwidth_deg()
        return _median(self._beamwidths) if self._beamwidths else None

    def _fit(self, angles: Sequence[float], values: Sequence[float], fast: bool) -> LobeFit | None:
        """One scan's fit: the pattern's (a fast leader's: `fit_moving`), else the parabola."""
        p = self.params
        if (pattern := self.pattern) is not None:
            if fast:
                return fit_moving(angles, values, pattern, p.lobe)
            return fit_pattern(angles, values, pattern, p.pattern_fit)
        return fit_main_lobe(angles, values, p.lobe, beamwidth_prior_deg=self.beamwidth_deg)

    def _learn(self, fit: LobeFit, angles: Sequence[float]) -> None:
        # Only a lobe seen well on both sides says how wide it is.
        lo, hi = min(angles), max(angles)
        half = fit.beamwidth_deg / 2.0
        if 5.0 <= fit.beamwidth_deg <= 180.0:
            self._any_beamwidths.append(fit.beamwidth_deg)
        if (
            not fit.extrapolated
            and fit.bearing_deg - half >= lo
            and fit.bearing_deg + half <= hi
            and fit.sd_deg <= self.params.tracker.confident_sd_deg
            and 5.0 <= fit.beamwidth_deg <= 180.0
        ):
            self._beamwidths.append(fit.beamwidth_deg)

    def _now(self, t: float, heading_deg: float | None) -> Track | None:
        if self.track is None:
            return None
        h = self.track.heading_deg if heading_deg is None else heading_deg
        return tracker.predict(self.track, t, h, self.params.tracker)

    def scan_done(
        self, t: float, heading_deg: float, est: ScanEstimate, sample_t: Sequence[float]
    ) -> ScanEstimate:
        p = self.params
        values = est.nrssi_dbm
        angles, t_ref = self._leader_frame(t, heading_deg, est.angles_deg, sample_t)
        w = self.track.rate_deg_s if self.track and t_ref is not None else 0.0
        fast = abs(w) > p.pattern_fit.parabola_rate_deg_s
        fit = self._fit(angles, values, fast)
        if fit is None and est.situation == 2:
            # The PRSSI penalty carved up the lobe itself: the "obstacle" is the leader, or
            # right beside it (a relay close behind its leader robot). The raw scan still
            # says where the leader is; losing the track over it would stop the relay.
            values = est.rssi_dbm
            fit = self._fit(angles, values, fast)
        self.last_fit = fit
        self._remember(fit, angles, est.rssi_dbm, t, heading_deg)
        if len(sample_t) >= 2:
            self._sweep_s = max(0.0, sample_t[-1] - sample_t[0])
        if fit is not None:
            self._learn(fit, angles)
            # The beam crossed the leader when the sample nearest the fitted bearing was taken
            # (a moving leader's: the moment its samples were carried to).
            t_meas, centre = t, fit.bearing_deg
            if t_ref is not None:
                t_meas = min(t_ref, t)
            elif len(sample_t) == len(angles) and sample_t:
                nearest = min(range(len(sample_t)), key=lambda i: abs(angles[i] - centre))
                t_meas = min(sample_t[nearest], t)
            fit = self.last_fit = self._trusted(fit)
            self._update(PooledScan(angles, tuple(values), t_meas, heading_deg, self.track, fit))
            self._learn_pattern(t, heading_deg, est)
        else:
            self._pool.clear()
            if self.track is not None:
                self.track = tracker.miss(self.track, t, heading_deg, p.tracker)
        now = self._now(t, heading_deg)
        if now is None or tracker.is_lost(now, p.tracker):
            # No track to speak of: the scan's own word (the fit, else the centroid), flagged unsure.
            bearing = fit.bearing_deg if fit is not None else est.bearing_deg
            return replace(est, bearing_deg=bearing, bearing_sd_deg=None)
        return replace(est, bearing_deg=self._seen(now.bearing_deg), bearing_sd_deg=now.sd_deg)

    def _learn_pattern(self, t: float, heading_deg: float, est: ScanEstimate) -> None:
        """The scan's raw RSSI and the track's bearing to the learner, if the track is sure."""
        now = self._now(t, heading_deg)
        still = now is not None and abs(now.rate_deg_s) <= self.params.adaptive.moving_rate_deg_s
        if self.learner is None or now is None or now.updates < 3 or not still:
            return
        if self.learner.scans == 0 and (bw := self.beamwidth_deg) is not None:
            self.learner.set_prior_beamwidth(bw)
        self.learner.add(est.angles_deg, est.rssi_dbm, now.bearing_deg, now.sd_deg)

    def _remember(
        self,
        fit: LobeFit | None,
        angles: Sequence[float],
        rssi_dbm: Sequence[float],
        t: float,
        heading_deg: float,
    ) -> None:
        """The scan's word on where the leader is, when that is at or beyond a servo limit
        (out of the sweep's reach): its fit there, however unsure; with no fit, the strongest
        sample when it lies at a limit (the lobe beyond) and is louder than the lost rule's
        "no leader" (`evidence_min_rssi_dbm`: a leader that faded out leaves only noise, whose
        strongest sample lies at a limit as often as anywhere). A word from within the sweep
        clears it: the next full sweeps see the leader there without a turn."""
        if self._span is None:
            return
        edge = self.params.lobe.max_extrapolation_deg / 2.0
        lo, hi = self._span[0] + edge, self._span[1] - edge
        if fit is not None:
            b = fit.bearing_deg
        elif angles and len(angles) == len(rssi_dbm):
            i = max(range(len(angles)), key=lambda k: rssi_dbm[k])
            b = angles[i]
            if lo < b < hi or not rssi_dbm[i] >= self.params.evidence_min_rssi_dbm:
                return  # no lobe, nothing heard at a limit: the scan says nothing new
        else:
            return
        self._evidence = (b, heading_deg, t) if not lo < b < hi else None

    def search_bearing(self, t: float, heading_deg: float | None) -> float | None:
        """While lost, where the scans last put the leader (today's frame) if that was beyond
        the servo's reach at most `evidence_max_age_s` ago; else None."""
        if self._evidence is None or not self.lost(t, heading_deg):
            return None
        b, h, seen_t = self._evidence
        if t - seen_t > self.params.evidence_max_age_s:
            return None
        return in_current_frame(b, h, heading_deg)

    def _leader_frame(
        self, t: float, heading_deg: float, angles_deg: Sequence[float], sample_t: Sequence[float]
    ) -> tuple[tuple[float, ...], float | None]:
        """The scan's angles as seen from a leader that moves during the sweep, and the time
        they refer to (None: as sampled).

        At 14 deg/s a 1.5 s sweep sees the leader move 20 deg: the beam meets it sooner or
        later than a still one, and the lobe looks wider or narrower than the antenna's,
        which the beamwidth prior then pulls on. While the filter says the bearing moves,
        each sample is carried by the filter's rate to the moment the beam is predicted to
        cross the leader, and the fit's centre is the bearing at that moment.
        """
        angles = tuple(angles_deg)
        now = self._now(t, heading_deg)
        if (
            not self.params.compensate_motion
            or now is None
            or tracker.is_lost(now, self.params.tracker)
            or abs(now.rate_deg_s) <= self.params.adaptive.moving_rate_deg_s
            or len(sample_t) != len(angles)
            or not angles
        ):
            return angles, None
        w = now.rate_deg_s
        ref = min(
            range(len(angles)),
            key=lambda i: abs(angles[i] - (now.bearing_deg + w * (sample_t[i] - t))),
        )
        t_ref = sample_t[ref]
        return tuple(a - w * (ti - t_ref) for a, ti in zip(angles, sample_t, strict=True)), t_ref

    def _seen(self, bearing_deg: float) -> float:
        """A prediction kept within the servo's range plus the fit's extrapolation: beyond, a
        rate would steer toward a bearing no scan has seen; turning to the limit is right."""
        if self._span is None:
            return bearing_deg
        ext = self.params.lobe.max_extrapolation_deg
        return min(max(bearing_deg, self._span[0] - ext), self._span[1] + ext)

    def _trusted(self, fit: LobeFit) -> LobeFit:
        """The fit with its sd as the channel's noise allows: a scan's few residuals can be
        small by luck (a lucky MAD), its sd with them; the recent scans' noise is the floor."""
        self._noise.append(fit.noise_db)
        typical = _median(self._noise)
        if fit.noise_db >= typical or fit.noise_db <= 0.0:
            return fit
        return replace(fit, sd_deg=fit.sd_deg * typical / fit.noise_db, noise_db=typical)

    def _update(self, scan: PooledScan) -> None:
        """Update the filter with the pooled fit where the scans may be pooled, else with this scan's."""
        tp = self.params.tracker
        fit = scan.fit
        pooled = self._pool.fit(
            self.track, scan, self.params.lobe, self.beamwidth_deg, self.pattern
        )
        if pooled is not None:
            fit, base = pooled
            self.last_fit = fit
        else:
            base = self.track
            self._pool.clear()
        if base is None or tracker.is_lost(base, tp):
            self.track, accepted = (
                tracker.start(scan.t, scan.heading_deg, fit.bearing_deg, fit.sd_deg, tp),
                True,
            )
        else:
            self.track, accepted = tracker.update(
                base, scan.t, scan.heading_deg, fit.bearing_deg, fit.sd_deg, tp
            )
        if not accepted or self.track.updates == 1:
            self._pool.clear()  # a gated scan or a new track: what came before is another leader
        if accepted:
            self._pool.add(scan)

    def bearing_now(self, t: float, heading_deg: float | None) -> float | None:
        now = self._now(t, heading_deg)
        lost = now is None or tracker.is_lost(now, self.params.tracker)
        return None if lost or now is None else self._seen(now.bearing_deg)

    def lost(self, t: float, heading_deg: float | None) -> bool:
        return (now := self._now(t, heading_deg)) is not None and tracker.is_lost(
            now, self.params.tracker
        )

    def sd_deg(self, t: float, heading_deg: float | None) -> float | None:
        return None if (now := self._now(t, heading_deg)) is None else now.sd_deg

    def window(self, t: float, heading_deg: float | None, full: Window) -> Window | None:
        """The next sweep. "full": the configured window, centred on the prediction.

        "adaptive": narrow around the prediction while the filter is confident (once a
        beamwidth is known: learnt, else the one-sided fits' median), at the configured
        window's sample spacing, so a sweep takes fewer samples; the servo's whole range
        while it is not.
        """
        p = self.params
        self._span = (
            full.centre_deg - full.width_deg / 2.0,
            full.centre_deg + full.width_deg / 2.0,
        )
        now = self._now(t, heading_deg)
        if now is None or tracker.is_lost(now, p.tracker):
            return None if p.window == "full" else full
        if p.window != "adaptive":
            return None
        if not tracker.is_confident(now, p.tracker):
            return full
        bw = self.beamwidth_deg
        if bw is None and self._any_beamwidths:
            # A leader standing where the servo limit cuts its lobe never shows both sides:
            # the one-sided fits' widths (less sure, hence the median) size the window
            # rather than the full range's slow sweep.
            bw = _median(self._any_beamwidths)
        if bw is None:
            return None
        return sized_window(now, bw, self._sweep_s, full, p.adaptive)


def make_model(params: LeaderParams) -> BearingModel:
    return TrackingModel(params) if params.estimator == "lobe" else CentroidModel()
