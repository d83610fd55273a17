"""Where is the leader in one scan, without knowing the antenna: a main-lobe fit.

Near its peak almost every directional antenna's gain in dB is a downward parabola,
`peak - 12 ((theta - centre) / beamwidth_3db)^2`, so `fit_main_lobe` fits peak, centre
and beamwidth on every scan (robust weighted least squares over the run of samples
around the peak) and returns the centre with its sd, or None when no lobe is there (the
tracker then counts a miss). Several scans can be fitted as one, each with its own level
(`scan_ids`; relayd.core.scan.pool). The choices and their measurements: docs/CONTROL.md
section 10.2. No I/O, no clock, no NumPy (the 3x3 normal equations in closed form).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from operator import itemgetter

#: dB below the peak where the parabola is 3 dB down: 12 (u / bw)^2 = 3 at u = bw / 2.
_DB_AT_HALF_BEAMWIDTH = 3.0


@dataclass(frozen=True, slots=True)
class LobeParams:
    """Settings of the main-lobe fit."""

    #: The lobe is fitted down to this far below its peak: `drop_fraction` of the scan's
    #: dynamic range (so a 12 dB front-to-back floor stays out), within these bounds.
    drop_min_db: float = 6.0
    drop_max_db: float = 14.0
    drop_fraction: float = 0.7
    #: Residual noise is never assumed below this (dB): model mismatch and quantisation.
    min_noise_db: float = 0.5
    max_extrapolation_deg: float = 20.0
    #: The propagated sd is multiplied by this: over cos^n and Gaussian lobes with uniform
    #: jitter, Rician and Rayleigh fading, the real errors were 1.1 to 1.7 times it
    #: (heavy tails, the parabola's mismatch), and a filter that trusts a scan too much
    #: does not average.
    sd_scale: float = 1.5
    #: A "lobe" wider than this is no lobe: a flat scan, or RSSI drifting during the sweep.
    max_beamwidth_deg: float = 150.0
    iterations: int = 3
    #: Relative spread (sd / value) of the curvature prior; see `fit_main_lobe`.
    prior_spread: float = 0.35
    #: The noise level (dB) at which the prior is weighed against the samples.
    prior_noise_db: float = 1.0


@dataclass(frozen=True, slots=True)
class LobeFit:
    """What the fit says about one scan."""

    bearing_deg: float
    sd_deg: float
    beamwidth_deg: float  # fitted 3 dB beamwidth
    peak_dbm: float  # fitted gain at the centre
    used: int  # samples in the fitted run
    #: The centre lies outside the sampled span (only one side of the lobe was seen).
    extrapolated: bool
    #: The residuals' robust scale (dB) the sd was computed with.
    noise_db: float = 0.0


Fit = tuple[list[float], list[list[float]], dict[int, float]]


def _wls(
    us: Sequence[float],
    ys: Sequence[float],
    ws: Sequence[float],
    prior: tuple[float, float] | None,
    gs: Sequence[int] | None = None,
) -> Fit | None:
    """Weighted quadratic fit: coefficients (a, b, c), (X^T W X)^-1 and each scan's level.

    `prior` = (c0, weight): a pseudo-observation c = c0 of that weight (in units of one
    sample's weight), so a one-sided lobe still has a curvature. `gs`: the scan each
    sample came from; each scan then has its own level a_g (the leader's distance and the
    shadowing change between scans, the lobe's shape does not), and `a` is the newest's.
    """
    if gs is not None:
        return _wls_pooled(us, ys, ws, prior, gs)
    s = [0.0] * 5  # sums of w u^k, k = 0..4
    t = [0.0] * 3  # sums of w y u^k, k = 0..2
    for u, y, w in zip(us, ys, ws, strict=True):
        p = w
        for k in range(5):
            s[k] += p
            if k < 3:
                t[k] += p * y
            p *= u
    if prior is not None:
        t[2] += prior[1] * prior[0]
    inv = _inverse_sym3(s[0], s[1], s[2], s[3], s[4] + (prior[1] if prior else 0.0))
    if inv is None:
        return None
    coef = [inv[i][0] * t[0] + inv[i][1] * t[1] + inv[i][2] * t[2] for i in range(3)]
    return coef, inv, {}


def _inverse_sym3(
    s0: float, s1: float, s2: float, s3: float, s4: float
) -> list[list[float]] | None:
    """The inverse of the normal matrix [[s0, s1, s2], [s1, s2, s3], [s2, s3, s4]] by its
    adjugate: one closed form instead of four eliminations (a scan end fits this a dozen
    times). None when it is singular to working precision."""
    c00 = s2 * s4 - s3 * s3
    c01 = s2 * s3 - s1 * s4
    c02 = s1 * s3 - s2 * s2
    det = s0 * c00 + s1 * c01 + s2 * c02
    if not abs(det) > 1e-12 * max(1.0, abs(s0 * s2 * s4)):
        return None
    c11 = s0 * s4 - s2 * s2
    c12 = s1 * s2 - s0 * s3
    c22 = s0 * s2 - s1 * s1
    return [
        [c00 / det, c01 / det, c02 / det],
        [c01 / det, c11 / det, c12 / det],
        [c02 / det, c12 / det, c22 / det],
    ]


def _wls_pooled(
    us: Sequence[float],
    ys: Sequence[float],
    ws: Sequence[float],
    prior: tuple[float, float] | None,
    gs: Sequence[int],
) -> Fit | None:
    """`_wls` with one level per scan: (b, c) from the data centred within each scan.

    One pass accumulates each scan's weighted sums of 1, u, u^2, y and their products;
    the centred (within-scan) normal equations follow from those sums.
    """
    if not (len(us) == len(ys) == len(ws) == len(gs)):
        raise ValueError("samples, weights and scan ids must be as many")
    by_scan: dict[int, list[int]] = {}
    for i, g in enumerate(gs):
        by_scan.setdefault(g, []).append(i)
    sums: dict[int, tuple[float, ...]] = {}
    for g, members in by_scan.items():
        # Plain locals in the loop: this is the scan end's innermost loop.
        sw = su = sv = sy = suu = suv = svv = suy = svy = 0.0
        for i in members:
            u, y, w = us[i], ys[i], ws[i]
            v = u * u
            wu, wv = w * u, w * v
            sw += w
            su += wu
            sv += wv
            sy += w * y
            suu += wu * u
            suv += wu * v
            svv += wv * v
            suy += wu * y
            svy += wv * y
        sums[g] = (sw, su, sv, sy, suu, suv, svv, suy, svy)
    means: dict[int, tuple[float, float, float]] = {}
    m00 = m01 = m11 = r0 = r1 = 0.0
    for g, (sw, su, sv, sy, suu, suv, svv, suy, svy) in sums.items():
        if sw <= 0:
            continue
        mu, mv, my = su / sw, sv / sw, sy / sw
        means[g] = (mu, mv, my)
        # sum w (u - mu)(v - mv) = sum w u v - sw mu mv, and alike.
        m00 += suu - sw * mu * mu
        m01 += suv - sw * mu * mv
        m11 += svv - sw * mv * mv
        r0 += suy - sw * mu * my
        r1 += svy - sw * mv * my
    if prior is not None:
        m11 += prior[1]
        r1 += prior[1] * prior[0]
    det = m00 * m11 - m01 * m01
    if not means or abs(det) < 1e-12 * max(1.0, m00 * m11):
        return None
    b, c = (m11 * r0 - m01 * r1) / det, (m00 * r1 - m01 * r0) / det
    levels = {g: my - b * mu - c * mv for g, (mu, mv, my) in means.items()}
    inv = [[0.0, 0.0, 0.0], [0.0, m11 / det, -m01 / det], [0.0, -m01 / det, m00 / det]]
    return [levels[max(levels)], b, c], inv, levels


def _run_around(values: Sequence[float], peak: int, floor: float) -> tuple[int, int]:
    """The index range [lo, hi] of the contiguous run around `peak` with values >= floor."""
    lo = peak
    while lo > 0 and values[lo - 1] >= floor:
        lo -= 1
    hi = peak
    while hi < len(values) - 1 and values[hi + 1] >= floor:
        hi += 1
    # Always the peak and a neighbour each side (where there is one): a parabola needs 3.
    while hi - lo + 1 < 3 and (lo > 0 or hi < len(values) - 1):
        if lo > 0:
            lo -= 1
        if hi - lo + 1 < 3 and hi < len(values) - 1:
            hi += 1
    return lo, hi


def _median(xs: Sequence[float]) -> float:
    s = sorted(xs)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


def fit_main_lobe(
    angles_deg: Sequence[float],
    rssi_dbm: Sequence[float],
    params: LobeParams = LobeParams(),
    *,
    beamwidth_prior_deg: float | None = None,
    scan_ids: Sequence[int] | None = None,
) -> LobeFit | None:
    """The leader's bearing from one scan by a parabolic fit of the main lobe in dB.

    `beamwidth_prior_deg`: the antenna's 3 dB beamwidth as learned from earlier scans
    (`BeamwidthLearner`), a soft prior on the curvature (relative spread
    `params.prior_spread`). A lobe seen on both sides hardly needs it; a lobe cut by a
    servo limit, seen on one side only, has its curvature from it, so its centre comes
    from the slope of the side that was seen.

    None when the scan shows no concave lobe (too few samples, a flat or a convex
    profile): no bearing rather than a made-up one.
    """
    if len(angles_deg) != len(rssi_dbm):
        raise ValueError(f"{len(angles_deg)} angles but {len(rssi_dbm)} RSSI values")
    if scan_ids is not None and len(scan_ids) != len(angles_deg):
        raise ValueError(f"{len(angles_deg)} angles but {len(scan_ids)} scan ids")
    ids = list(scan_ids) if scan_ids is not None else [0] * len(angles_deg)
    offsets = _scan_levels(angles_deg, rssi_dbm, ids) if scan_ids is not None else {0: 0.0}
    # Each scan at its own top (its level is fitted again below): the peak and the run are
    # then chosen on the lobe's shape, not on which scan was loudest.
    # Sorted by angle, then scan (not by value): the same samples give the same order
    # whatever each scan's level was, to the last bit.
    if not (all(map(math.isfinite, angles_deg)) and all(map(math.isfinite, rssi_dbm))):
        a, r = next(
            (a, r)
            for a, r in zip(angles_deg, rssi_dbm, strict=True)
            if not (math.isfinite(a) and math.isfinite(r))
        )
        raise ValueError(f"samples must be finite, got angle {a!r}, rssi {r!r}")
    triples = sorted(
        ((a, r - offsets[g], g) for a, r, g in zip(angles_deg, rssi_dbm, ids, strict=True)),
        key=itemgetter(0, 2),
    )
    if len(triples) < 3:
        return None
    angles = [a for a, _, _ in triples]
    rssi = [r for _, r, _ in triples]
    groups = [g for _, _, g in triples] if scan_ids is not None else None
    n = len(rssi)
    smooth = _running_mean3(rssi)
    peak = max(range(n), key=lambda i: (smooth[i], rssi[i]))
    ranked = sorted(smooth)
    dynamic_db = ranked[-1] - ranked[max(0, n // 10)]
    drop_db = min(max(params.drop_fraction * dynamic_db, params.drop_min_db), params.drop_max_db)
    floor = smooth[peak] - drop_db
    lo, hi = _run_around(smooth, peak, floor)
    u0 = angles[peak]
    coef: list[float] | None = None
    inv: list[list[float]] | None = None
    weights: dict[int, float] = {}
    prior: tuple[float, float] | None = None
    if beamwidth_prior_deg is not None:
        if not (beamwidth_prior_deg > 0 and math.isfinite(beamwidth_prior_deg)):
            raise ValueError(f"beamwidth_prior_deg must be > 0, got {beamwidth_prior_deg!r}")
        c0 = -4.0 * _DB_AT_HALF_BEAMWIDTH / (beamwidth_prior_deg * beamwidth_prior_deg)
        sd_c = params.prior_spread * abs(c0)
        prior = (c0, (params.prior_noise_db / sd_c) ** 2)
    resid_scale = params.min_noise_db
    for _ in range(max(1, params.iterations)):
        idx = list(range(lo, hi + 1))
        us = [angles[i] - u0 for i in idx]
        ys = [rssi[i] for i in idx]
        ws = [weights.get(i, 1.0) for i in idx]
        gs = None if groups is None else [groups[i] for i in idx]
        fit = _wls(us, ys, ws, prior, gs)
        if fit is None:
            return None
        coef, inv, levels = fit
        a, b, c = coef
        lv = [a] * len(idx) if gs is None else [levels[g] for g in gs]
        res = [y - (la + b * u + c * u * u) for u, y, la in zip(us, ys, lv, strict=True)]
        # Huber weights: a robust scale from the median absolute residual.
        mad = _median([abs(x) for x in res]) / 0.6745
        resid_scale = max(params.min_noise_db, mad)
        k = 1.345 * resid_scale
        weights = {i: (1.0 if abs(r) <= k else k / abs(r)) for i, r in zip(idx, res, strict=True)}
        if c >= 0:
            break
        # Choose the run again from the fitted lobe (its peak, not the luckiest sample):
        # every sample the parabola puts within drop_db of its top, at least 3.
        centre = u0 - b / (2.0 * c)
        half = math.sqrt(drop_db / -c)
        inside = [i for i in range(n) if abs(angles[i] - centre) <= half]
        if inside:
            lo, hi = inside[0], inside[-1]
        else:
            lo = hi = min(range(n), key=lambda i: abs(angles[i] - centre))
        lo, hi = _widen(lo, hi, n, centre, angles)
    if coef is None or inv is None:  # the loop runs at least once; no fit is no lobe
        return None
    a, b, c = coef
    if c >= 0:
        return None
    centre_u = -b / (2.0 * c)
    # Covariance of (b, c) times the residual variance, through centre = -b / 2c.
    s2 = resid_scale * resid_scale
    gb, gc = -1.0 / (2.0 * c), b / (2.0 * c * c)
    var = s2 * (gb * gb * inv[1][1] + 2.0 * gb * gc * inv[1][2] + gc * gc * inv[2][2])
    sd = params.sd_scale * math.sqrt(max(var, 0.0))
    centre = u0 + centre_u
    span_lo, span_hi = angles[0], angles[-1]
    extrapolated = not (span_lo <= centre <= span_hi)
    centre = min(
        max(centre, span_lo - params.max_extrapolation_deg), span_hi + params.max_extrapolation_deg
    )
    peak_dbm = a + b * centre_u + c * centre_u * centre_u + offsets[max(offsets)]
    beamwidth = 2.0 * math.sqrt(_DB_AT_HALF_BEAMWIDTH / -c)
    if beamwidth > params.max_beamwidth_deg:
        return None
    return LobeFit(
        bearing_deg=centre,
        sd_deg=sd,
        beamwidth_deg=beamwidth,
        peak_dbm=peak_dbm,
        used=hi - lo + 1,
        extrapolated=extrapolated,
        noise_db=resid_scale,
    )


def _scan_levels(
    angles: Sequence[float], rssi: Sequence[float], ids: Sequence[int]
) -> dict[int, float]:
    """Each scan's top: the highest 3-point running mean of its samples in angle order."""
    by_scan: dict[int, list[tuple[float, float]]] = {}
    for a, r, g in zip(angles, rssi, ids, strict=True):
        by_scan.setdefault(g, []).append((a, r))
    levels = {}
    for g, pairs in by_scan.items():
        levels[g] = max(_running_mean3([r for _, r in sorted(pairs)]))
    return levels


def _running_mean3(v: Sequence[float]) -> list[float]:
    """The mean of each value and its neighbours (the ends: of the two there are)."""
    n = len(v)
    if n < 2:
        return [float(x) for x in v]
    out = [(v[0] + v[1]) / 2.0]
    out += [(v[i - 1] + v[i] + v[i + 1]) / 3.0 for i in range(1, n - 1)]
    out.append((v[n - 2] + v[n - 1]) / 2.0)
    return out


def _widen(lo: int, hi: int, n: int, centre: float, angles: Sequence[float]) -> tuple[int, int]:
    """Grow [lo, hi] to at least 3 samples, toward the side nearer the centre first."""
    while hi - lo + 1 < 3 and (lo > 0 or hi < n - 1):
        left = abs(angles[lo - 1] - centre) if lo > 0 else math.inf
        right = abs(angles[hi + 1] - centre) if hi < n - 1 else math.inf
        if left <= right:
            lo -= 1
        else:
            hi += 1
    return lo, hi
