"""The path-loss fit of `relayd calibrate path-loss`: L0, n and sigma with confidence intervals.

The log-distance model (the paper's eq. 6-13) with log-normal shadowing:

    RSSI(d) = L0 - 10 n log10(d) + X,     X ~ N(0, sigma^2)        [dBm, d in metres]

is a straight line in x = 10 log10(d): intercept L0 (the level at 1 m), slope -n.

Decisions:
- **Robust regression.** Huber's M-estimator by iteratively reweighted least squares
  (k = 1.345, 95 % efficient on Gaussian data), with the scale re-estimated each round
  as the normalised median absolute deviation, then a few rounds of Tukey's bisquare
  (c = 4.685) started from it. A drive has outliers a plain least squares fit
  follows: a person stepping between the antennas, a fade the adapter did not average
  away, the first samples while the robot was still at the node. They are one-sided
  (always a loss), and Huber's weights only bound their pull (10 % of readings 15-30 dB
  down still bias L0 by ~2 dB); the bisquare gives readings beyond ~4.7 sd no weight.
- **sigma** is the spread of single readings about the line (the normalised MAD of the
  residuals, robust to the same outliers), i.e. shadowing plus what fast fading the
  radio's averaging leaves: the margin a threshold on single readings has to cover.
  It is also split into a fast part, from the differences of neighbouring readings
  (uncorrelated from one reading to the next), and the slow shadowing part that
  remains, so the report can say which dominates.
- **Confidence intervals by a moving-block bootstrap over distance.** Shadowing is
  correlated over metres, so neighbouring readings are not independent and the
  textbook (i.i.d.) intervals would be too narrow. Resampling blocks of neighbouring
  readings keeps that correlation. The percentile interval of 300 resamples; a
  block is the readings within `block_m` (4 m: twice a typical indoor shadowing
  correlation length) of the drive from a start drawn uniformly in distance, so a
  drive slower in its first metres keeps its proportions. Deterministic for a given seed. A straight pass of D metres holds
  only about D / 4 independent shadowing values, so a short drive gives honest but
  wide intervals: drive 30 m or more, or several passes.
- Readings nearer than `min_distance_m` (0.5 m, the antennas' near field and the
  robot's own length) are left out, as are ones the radio marked as noise floor.

Pure: lists of floats in, a frozen result out; no I/O, no clock, no numpy.
"""

from __future__ import annotations

import bisect
import math
import random
from collections.abc import Sequence
from dataclasses import dataclass
from statistics import NormalDist

from relayd.core.link.rates import RATE_TABLES

HUBER_K = 1.345
BISQUARE_C = 4.685
MAD_TO_SD = 1.4826
MIN_DISTANCE_M = 0.5
#: The fit needs at least this many readings, spread over at least this ratio of distances.
MIN_POINTS = 10
MIN_SPAN_RATIO = 2.0
#: The smallest path-loss exponent taken as a fit. Free space is 2, a corridor that guides
#: the wave about 1.5; below this the RSSI barely falls with distance (the node's radio
#: off, the robot not moving away, a flat recording) and no limit can be placed by it.
MIN_N = 0.5
#: Distances the model is asked for beyond this many times the farthest reading are not
#: given as figures: the fit says nothing about a place the drive never reached.
MAX_EXTRAPOLATION = 2.0


class FitError(ValueError):
    """Data the model cannot be fitted to (too few readings, no spread of distance)."""


@dataclass(frozen=True, slots=True)
class Interval:
    low: float
    high: float

    def __contains__(self, value: object) -> bool:
        return isinstance(value, int | float) and self.low <= value <= self.high


@dataclass(frozen=True, slots=True)
class PathLossFit:
    """The fitted model and how sure it is."""

    l0_dbm: float
    n: float
    sigma_db: float
    l0_ci: Interval
    n_ci: Interval
    sigma_ci: Interval
    #: sigma split: reading-to-reading (fast fading) and slow (shadowing) parts, dB.
    sigma_fast_db: float
    sigma_slow_db: float
    points: int
    dropped: int
    distance_range_m: tuple[float, float]
    confidence: float

    @classmethod
    def known(cls, l0_dbm: float, n: float, sigma_db: float) -> PathLossFit:
        """A model given rather than fitted (a simulator's radio, a site survey's figures):
        exact intervals, no readings. The thresholds are then computed exactly as for a fit."""
        for name, value in (("l0_dbm", l0_dbm), ("n", n), ("sigma_db", sigma_db)):
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value}")
        if n <= 0 or sigma_db < 0:
            raise ValueError(f"need n > 0 and sigma_db >= 0, got n {n}, sigma_db {sigma_db}")
        return cls(
            l0_dbm,
            n,
            sigma_db,
            Interval(l0_dbm, l0_dbm),
            Interval(n, n),
            Interval(sigma_db, sigma_db),
            sigma_fast_db=0.0,
            sigma_slow_db=sigma_db,
            points=0,
            dropped=0,
            distance_range_m=(math.nan, math.nan),
            confidence=1.0,
        )

    def rssi_at(self, distance_m: float) -> float:
        """The model's median RSSI at a distance."""
        return self.l0_dbm - 10.0 * self.n * math.log10(max(distance_m, 1e-3))

    def distance_at(self, rssi_dbm: float) -> float:
        """The distance where the model's median RSSI is `rssi_dbm` (FitError for a model
        whose RSSI does not fall with distance: no such distance exists)."""
        if not self.n > 0:
            raise FitError(f"n = {self.n:.2f}: the RSSI does not fall with distance")
        exponent = (self.l0_dbm - rssi_dbm) / (10.0 * self.n)
        return math.inf if exponent > 300 else float(10.0**exponent)

    def measured_distance_at(self, rssi_dbm: float) -> float | None:
        """`distance_at`, or None when that lies beyond MAX_EXTRAPOLATION x the farthest
        reading (or when the fit has no readings to bound it: a model given, not fitted)."""
        d = self.distance_at(rssi_dbm)
        far = self.distance_range_m[1]
        if math.isfinite(far) and not d <= MAX_EXTRAPOLATION * far:
            return None
        return d

    def to_json(self) -> dict[str, object]:
        return {
            "l0_dbm": round(self.l0_dbm, 2),
            "n": round(self.n, 3),
            "sigma_db": round(self.sigma_db, 2),
            "l0_ci": [round(self.l0_ci.low, 2), round(self.l0_ci.high, 2)],
            "n_ci": [round(self.n_ci.low, 3), round(self.n_ci.high, 3)],
            "sigma_ci": [round(self.sigma_ci.low, 2), round(self.sigma_ci.high, 2)],
            "sigma_fast_db": round(self.sigma_fast_db, 2),
            "sigma_slow_db": round(self.sigma_slow_db, 2),
            "points": self.points,
            "dropped": self.dropped,
            "distance_range_m": [
                round(self.distance_range_m[0], 2),
                round(self.distance_range_m[1], 2),
            ],
            "confidence": self.confidence,
        }


def _median(values: Sequence[float]) -> float:
    s = sorted(values)
    m = len(s) // 2
    return s[m] if len(s) % 2 else (s[m - 1] + s[m]) / 2.0


def _mad_sd(values: Sequence[float]) -> float:
    med = _median(values)
    return MAD_TO_SD * _median([abs(v - med) for v in values])


def _wls(x: Sequence[float], y: Sequence[float], w: Sequence[float]) -> tuple[float, float]:
    """Weighted least squares line y = a + b x: (a, b)."""
    sw = sum(w)
    mx = sum(wi * xi for wi, xi in zip(w, x, strict=True)) / sw
    my = sum(wi * yi for wi, yi in zip(w, y, strict=True)) / sw
    sxx = sum(wi * (xi - mx) ** 2 for wi, xi in zip(w, x, strict=True))
    sxy = sum(wi * (xi - mx) * (yi - my) for wi, xi, yi in zip(w, x, y, strict=True))
    if sxx <= 0:
        raise FitError("all readings at one distance: drive further from the node")
    b = sxy / sxx
    return my - b * mx, b


def huber_line(
    x: Sequence[float], y: Sequence[float], k: float = HUBER_K, rounds: int = 50
) -> tuple[float, float, float]:
    """Robust line y = a + b x: Huber IRLS, then bisquare IRLS from it: (a, b, residual sd of the inliers)."""
    a, b = _wls(x, y, [1.0] * len(x))
    scale = 0.0
    for _ in range(rounds):
        res = [yi - a - b * xi for xi, yi in zip(x, y, strict=True)]
        scale = _mad_sd(res)
        if scale <= 1e-9:  # (nearly) exact line: the plain fit is the answer
            break
        w = [1.0 if abs(r) <= k * scale else k * scale / abs(r) for r in res]
        a2, b2 = _wls(x, y, w)
        done = abs(a2 - a) < 1e-6 and abs(b2 - b) < 1e-7
        a, b = a2, b2
        if done:
            break
    # Bisquare polish from the Huber line, its scale fixed at the Huber residuals' MAD.
    res = [yi - a - b * xi for xi, yi in zip(x, y, strict=True)]
    scale = _mad_sd(res)
    for _ in range(rounds if scale > 1e-9 else 0):
        w = [
            (1.0 - (r / (BISQUARE_C * scale)) ** 2) ** 2 if abs(r) < BISQUARE_C * scale else 0.0
            for r in res
        ]
        if sum(1 for wi in w if wi > 0) < 3:
            break
        try:
            a2, b2 = _wls(x, y, w)
        except FitError:
            break
        done = abs(a2 - a) < 1e-6 and abs(b2 - b) < 1e-7
        a, b = a2, b2
        res = [yi - a - b * xi for xi, yi in zip(x, y, strict=True)]
        if done:
            break
    inliers = [r for r in res if abs(r) < BISQUARE_C * scale] if scale > 1e-9 else res
    return a, b, _mad_sd(inliers if len(inliers) >= 3 else res)


def _fast_sd(x: Sequence[float], res: Sequence[float]) -> float:
    """The reading-to-reading part of the spread: sd of neighbour differences / sqrt 2."""
    order = sorted(range(len(x)), key=lambda i: x[i])
    diffs = [res[order[i + 1]] - res[order[i]] for i in range(len(order) - 1)]
    return _mad_sd(diffs) / math.sqrt(2.0) if len(diffs) >= 2 else 0.0


def fit_path_loss(
    distance_m: Sequence[float],
    rssi_dbm: Sequence[float],
    *,
    confidence: float = 0.95,
    resamples: int = 300,
    seed: int = 0,
    min_distance_m: float = MIN_DISTANCE_M,
    floor_dbm: float | None = None,
    block_m: float = 4.0,
) -> PathLossFit:
    """Fit L0, n and sigma to (distance, RSSI) readings; see the module docstring."""
    if len(distance_m) != len(rssi_dbm):
        raise FitError("distance and RSSI lists differ in length")
    pairs = [
        (d, r)
        for d, r in zip(distance_m, rssi_dbm, strict=True)
        if math.isfinite(d)
        and math.isfinite(r)
        and d >= min_distance_m
        and (floor_dbm is None or r > floor_dbm)
    ]
    dropped = len(distance_m) - len(pairs)
    if len(pairs) < MIN_POINTS:
        raise FitError(
            f"{len(pairs)} usable readings (need {MIN_POINTS} at {min_distance_m:g} m or more)"
        )
    pairs.sort()
    d_lo, d_hi = pairs[0][0], pairs[-1][0]
    if d_hi < MIN_SPAN_RATIO * d_lo:
        raise FitError(
            f"readings only from {d_lo:.1f} to {d_hi:.1f} m: drive to at least "
            f"{MIN_SPAN_RATIO:g} x the start distance for a slope"
        )
    x = [10.0 * math.log10(d) for d, _ in pairs]
    y = [r for _, r in pairs]
    a, b, sd = huber_line(x, y)
    if -b < MIN_N:
        raise FitError(
            f"the RSSI does not fall with distance (n = {-b:.2f}, from {y[0]:.0f} dBm at "
            f"{d_lo:.1f} m to {y[-1]:.0f} dBm at {d_hi:.1f} m; at least {MIN_N:g} is needed): "
            "is the node's radio on, and did the robot drive away from it? No threshold written"
        )
    res = [yi - a - b * xi for xi, yi in zip(x, y, strict=True)]
    fast = min(_fast_sd(x, res), sd)
    slow = math.sqrt(max(0.0, sd * sd - fast * fast))

    # Moving-block bootstrap over distance: each block is the readings within block_m of
    # drive from a start drawn uniformly in distance, so a drive that went slower in
    # places (the first metres, relayd/calibrate/sources.py) is resampled in its own
    # proportions. The starts run from block_m before the first reading to the last, so
    # every distance is equally likely to be drawn, the ends included: drawn only from
    # where a whole block fits, the readings at the start distance (the robot standing
    # there, which pin L0) were never drawn, and the intervals missed their estimates.
    rng = random.Random(seed)
    count = len(x)
    dists = [d for d, _ in pairs]
    span = (d_hi - d_lo) + block_m
    l0s, ns, sds = [], [], []
    for _ in range(resamples):
        idx: list[int] = []
        while len(idx) < count:
            d0 = d_lo - block_m + rng.random() * span
            idx.extend(
                range(bisect.bisect_left(dists, d0), bisect.bisect_right(dists, d0 + block_m))
            )
        idx = idx[:count]
        bx, by = [x[i] for i in idx], [y[i] for i in idx]
        try:
            ba, bb, bsd = huber_line(bx, by)
        except FitError:
            continue  # a resample with one distance only: no slope, skip it
        l0s.append(ba)
        ns.append(-bb)
        sds.append(bsd)
    if len(l0s) < resamples // 2:
        raise FitError("the readings do not support a slope (too few distinct distances)")
    tail = (1.0 - confidence) / 2.0

    def pct(values: list[float]) -> Interval:
        s = sorted(values)
        lo = s[max(0, math.floor(tail * (len(s) - 1)))]
        hi = s[min(len(s) - 1, math.ceil((1.0 - tail) * (len(s) - 1)))]
        return Interval(lo, hi)

    return PathLossFit(
        l0_dbm=a,
        n=-b,
        sigma_db=sd,
        l0_ci=pct(l0s),
        n_ci=pct(ns),
        sigma_ci=pct(sds),
        sigma_fast_db=fast,
        sigma_slow_db=slow,
        points=count,
        dropped=dropped,
        distance_range_m=(d_lo, d_hi),
        confidence=confidence,
    )


# -- thresholds --------------------------------------------------------------------------


def z_of(outage: float) -> float:
    """The one-sided normal quantile for an outage probability (0.1 -> 1.28)."""
    if not 0.0 < outage < 0.5:
        raise ValueError(f"outage probability must be in (0, 0.5), got {outage}")
    return NormalDist().inv_cdf(1.0 - outage)


def threshold_for_hop_length(fit: PathLossFit, hop_m: float, outage: float) -> float:
    """threshold_b so that the relay stops within `hop_m` of the node behind with
    probability 1 - outage: the median RSSI there, raised by z sigma (a reading above
    the median by shadowing would otherwise carry the robot past it)."""
    return fit.rssi_at(hop_m) + z_of(outage) * fit.sigma_db


def required_rssi_dbm(
    target_mbps: float, phy: str = "802.11g", mac_efficiency: float = 0.5
) -> float:
    """The weakest signal whose 802.11 rate still carries `target_mbps` after MAC overhead."""
    need = None
    for sens, rate in RATE_TABLES[phy]:
        if rate * mac_efficiency >= target_mbps:
            need = sens
    if need is None:
        best = RATE_TABLES[phy][0][1] * mac_efficiency
        raise ValueError(
            f"{target_mbps:g} Mbit/s is more than {phy} carries ({best:g} Mbit/s at best)"
        )
    return need


def threshold_for_throughput(
    fit: PathLossFit,
    target_mbps: float,
    outage: float,
    *,
    phy: str = "802.11g",
    mac_efficiency: float = 0.5,
) -> float:
    """threshold_b so that the hop still carries `target_mbps` where the relay stops, with
    probability 1 - outage: the rate's sensitivity plus z sigma of single-reading spread."""
    return required_rssi_dbm(target_mbps, phy, mac_efficiency) + z_of(outage) * fit.sigma_db
