"""Consecutive scans of a steady bearing fitted as one (the lobe estimator's scan pool).

`relayd.core.scan.leader.TrackingModel` hands each scan to `ScanPool` before it updates the
tracking filter; while the filter says the bearing is steady, the pool fits the last few
scans together (`relayd.core.scan.bearing.fit_main_lobe` with one level per scan) and says which
track to update from so that no scan is counted twice. Why: docs/CONTROL.md section 10.2.

Pure: no clock, no I/O; times and headings come in with the scans.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace

from relayd.core.geometry import wrap_deg
from relayd.core.scan.bearing import LobeFit, LobeParams, fit_main_lobe
from relayd.core.scan.pattern import AntennaPattern
from relayd.core.scan.patternfit import fit_pattern
from relayd.core.scan.tracker import Track


@dataclass(frozen=True, slots=True)
class PoolParams:
    """When consecutive scans are fitted as one (`ScanPool`)."""

    #: At most this many scans, the newest included, are fitted together.
    scans: int = 5
    #: ... while the filter says the bearing is steady: |rate| at most this (deg/s) ...
    max_rate_deg_s: float = 2.0
    #: ... and an older scan is carried to the newest one's frame to within this (deg, 1 sd
    #: of rate x time between them); older scans are left out.
    max_shift_sd_deg: float = 4.0
    #: An older scan (and the pooled fit) must agree with the newest scan's own fit within
    #: this many sd of the two: a leader that starts to move is not averaged away.
    agree_sigma: float = 1.5


@dataclass(frozen=True, slots=True)
class PooledScan:
    """One scan as the pool keeps it: its samples, when and in which frame, and the track before it."""

    angles_deg: tuple[float, ...]
    rssi_dbm: tuple[float, ...]
    t: float
    heading_deg: float
    before: Track | None
    #: The scan's own lobe fit.
    fit: LobeFit


class ScanPool:
    """Consecutive scans of a steady bearing fitted as one: a fixed-lag batch fit.

    Under fading one scan's lobe fit is noisy and, where a servo limit cuts the lobe, its
    curvature is poorly seen, which biases the centre toward the samples (`relayd.core.scan.bearing`).
    A relay that stands still keeps scanning a leader that stands still; fitting the last
    few scans together (each with its own level, their angles carried into the newest
    scan's frame by the odometry heading change and the filter's rate) averages the noise
    before the nonlinear centre = -b / 2c instead of after it. The filter is then updated
    from the track as it was before the oldest pooled scan, so no scan is counted twice.
    """

    def __init__(self, params: PoolParams) -> None:
        self.params = params
        self._scans: deque[PooledScan] = deque(maxlen=max(0, params.scans - 1))

    def clear(self) -> None:
        self._scans.clear()

    def add(self, scan: PooledScan) -> None:
        if self._scans.maxlen:
            self._scans.append(scan)

    def fit(
        self,
        track: Track | None,
        newest: PooledScan,
        lobe: LobeParams,
        beamwidth_prior_deg: float | None,
        pattern: AntennaPattern | None = None,
    ) -> tuple[LobeFit, Track | None] | None:
        """(pooled fit, track to update from), or None when the scans may not be pooled.

        Pooled are the newest scan and the run of scans just before it that each, carried
        into its frame, saw the leader where it does (within `agree_sigma` of the two
        fits' sd) and that the filter's rate carries there well enough; none of it while
        the filter says the bearing moves.
        """
        p = self.params
        if track is None or abs(track.rate_deg_s) > p.max_rate_deg_s:
            return None
        used: list[tuple[PooledScan, float]] = []
        for s in reversed(self._scans):
            if track.rate_sd_deg_s * abs(newest.t - s.t) > p.max_shift_sd_deg:
                break
            shift = track.rate_deg_s * (newest.t - s.t) - wrap_deg(
                newest.heading_deg - s.heading_deg
            )
            gap = abs(wrap_deg(s.fit.bearing_deg + shift - newest.fit.bearing_deg))
            if gap > p.agree_sigma * math.hypot(s.fit.sd_deg, newest.fit.sd_deg):
                break
            used.append((s, shift))
        if not used:
            return None
        used.reverse()
        angles: list[float] = []
        rssi: list[float] = []
        ids: list[int] = []
        for k, (s, shift) in enumerate([*used, (newest, 0.0)]):
            angles += [a + shift for a in s.angles_deg]
            rssi += s.rssi_dbm
            ids += [k] * len(s.angles_deg)
        if pattern is not None:
            pooled = fit_pattern(
                angles, rssi, pattern, scan_ids=ids, around_deg=newest.fit.bearing_deg
            )
        else:
            pooled = fit_main_lobe(
                angles, rssi, lobe, beamwidth_prior_deg=beamwidth_prior_deg, scan_ids=ids
            )
        if pooled is None:
            return None
        gap = abs(wrap_deg(pooled.bearing_deg - newest.fit.bearing_deg))
        if gap > p.agree_sigma * math.hypot(newest.fit.sd_deg, pooled.sd_deg):
            return None
        # Trusted no more than the scans' own fits averaged: pooling is there to take the
        # bias out of cut lobes, and a few faded scans fitted together must not look certain.
        averaged_sd = sum(s.fit.sd_deg**-2 for s, _ in [*used, (newest, 0.0)]) ** -0.5
        return replace(pooled, sd_deg=max(pooled.sd_deg, averaged_sd)), used[0][0].before
