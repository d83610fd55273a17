"""Where is the leader in one scan, knowing the antenna: the measured pattern matched to the scan.

With a pattern file (`[scan] pattern_file`, `relayd.core.scan.pattern`) the scan's shape is
known up to two things: where the leader is (bearing b) and how loud it is (a level L,
the leader's distance and the shadowing). Sample i, taken with the servo at angle a_i,
is then

    rssi_i = L + P(b - a_i) + noise

and the fit is the maximum-likelihood (b, L) under that model, robustly:

1. Every bearing around the sweep, every `search_step_deg`: L in closed form (the mean
   of rssi - P), the sum of squared residuals. The best of the grid is the global
   minimum's neighbourhood whatever the pattern: a side lobe, a back lobe or a squinted
   peak cannot capture the bearing the way a local search started at the loudest sample
   can, because every bearing is tried against every sample. The grid reaches a
   beamwidth beyond the sweep's ends (a leader out of the servo's reach is found there,
   and flagged); further out the scan saw only the pattern's far side, which in a narrow
   window can look just like the main lobe.
2. Around it, on a fine grid, Huber-weighted (scale from the residuals' MAD, so one
   faded sample or an obstacle's PRSSI dip does not drag the fit), twice.
3. The sd of b from the same fit: the Fisher information of b with L a nuisance,
   sum_i w_i (P'(b - a_i) - mean P')^2 / s^2, s the residual scale (never below
   `min_noise_db`). So a scan that saw only the pattern's flat floor, or one flank of a
   lobe far beyond the servo's reach, is as unsure as it is.
4. Ambiguity is honest too: when another bearing, more than half a beamwidth away,
   explains the scan nearly as well (its cost within `ambiguity_chi2` of the best, in
   units of s^2: a back lobe the shape of the main one, a side lobe at the sweep's
   edge), the sd is at least the distance between the two.
5. No lobe, no bearing: when the best bearing explains the scan no better than a flat
   line would (`min_explained_chi2`), the fit is None, as the main-lobe fit's is.
   A bearing beyond the sampled span is kept (the leader is out of the servo's reach,
   and the fit says where) and flagged `extrapolated`.

Several scans can be fitted as one (`scan_ids`): each scan has its own level, the
bearing is shared, as in `relayd.core.scan.bearing`.

Pure: no I/O, no clock, no NumPy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from relayd.core.scan.bearing import LobeFit
from relayd.core.scan.pattern import LOOKUP_STEP_DEG, AntennaPattern, wrap180


@dataclass(frozen=True, slots=True)
class PatternFitParams:
    """Settings of the pattern fit."""

    #: The global search's grid step (deg).
    search_step_deg: float = 2.0
    #: The refinement's step (deg) and half-width (in grid steps).
    fine_step_deg: float = 0.25
    #: Residual noise is never assumed below this (dB): quantisation, the table's own error.
    min_noise_db: float = 0.7
    #: The Fisher sd is multiplied by this (heavy-tailed fading, the table's error).
    sd_scale: float = 1.3
    huber_k: float = 1.345
    #: A second bearing within this much cost (units of s^2) of the best is as plausible.
    ambiguity_chi2: float = 4.0
    #: The best bearing must explain this much more than a flat scan (units of s^2).
    min_explained_chi2: float = 9.0
    #: Bearings up to the pattern's beamwidth, at least this (deg), beyond the sweep's ends
    #: are searched.
    min_reach_deg: float = 30.0


def _levels(
    ys: Sequence[float], ms: Sequence[float], ws: Sequence[float], gs: Sequence[int]
) -> dict[int, float]:
    sw: dict[int, float] = {}
    sr: dict[int, float] = {}
    for y, m, w, g in zip(ys, ms, ws, gs, strict=True):
        sw[g] = sw.get(g, 0.0) + w
        sr[g] = sr.get(g, 0.0) + w * (y - m)
    return {g: sr[g] / sw[g] for g in sw if sw[g] > 0}


def _cost(
    b: float,
    pattern: AntennaPattern,
    angles: Sequence[float],
    ys: Sequence[float],
    ws: Sequence[float],
    gs: Sequence[int],
) -> tuple[float, dict[int, float]]:
    """Weighted sum of squared residuals at bearing b, each scan at its best level."""
    gain = pattern.gain_db
    ms = [gain(b - a) for a in angles]
    lv = _levels(ys, ms, ws, gs)
    c = 0.0
    for y, m, w, g in zip(ys, ms, ws, gs, strict=True):
        r = y - m - lv.get(g, 0.0)
        c += w * r * r
    return c, lv


def _search_costs(
    grid: Sequence[float],
    pattern: AntennaPattern,
    angles: Sequence[float],
    ys: Sequence[float],
    gs: Sequence[int],
) -> list[float]:
    """`_cost` with unit weights at every bearing of the grid, by each scan's sums of the
    residual d = y - P and of d^2 (cost = sum d^2 - (sum d)^2 / n per scan): the search
    is the fit's hot loop (a hundred bearings a scan)."""
    lk = pattern.lookup
    last = len(lk) - 1
    inv = 1.0 / LOOKUP_STEP_DEG
    members: dict[int, list[int]] = {}
    for i, g in enumerate(gs):
        members.setdefault(g, []).append(i)
    parts = [([angles[i] for i in m], [ys[i] for i in m]) for m in members.values()]
    out = []
    for b in grid:
        c = 0.0
        for a_s, y_s in parts:
            ds = []
            for a, y in zip(a_s, y_s, strict=True):
                # pattern.gain_db inlined: the lookup table, linear between its points.
                x = (b - a + 180.0) % 360.0 * inv
                i = int(x)
                gv = lk[last] if i >= last else lk[i] + (x - i) * (lk[i + 1] - lk[i])
                ds.append(y - gv)
            sd = sum(ds)
            c += sum(d * d for d in ds) - sd * sd / len(ds)
        out.append(c)
    return out


def _median(xs: Sequence[float]) -> float:
    s = sorted(xs)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


# Complexity: one fit in its steps (search, refine, sd, ambiguity, no-lobe), each a few lines.
def fit_pattern(
    angles_deg: Sequence[float],
    rssi_dbm: Sequence[float],
    pattern: AntennaPattern,
    params: PatternFitParams = PatternFitParams(),
    *,
    scan_ids: Sequence[int] | None = None,
    around_deg: float | None = None,
) -> LobeFit | None:
    """The leader's bearing from a scan (or several, `scan_ids`) by matching `pattern` to it.

    `around_deg`: search only within one beamwidth of this bearing (the pooled fit of scans
    whose own fits already agree there), not round the whole circle.

    None when the scan shows no lobe the pattern explains (too few samples, flat).
    """
    n = len(angles_deg)
    if len(rssi_dbm) != n:
        raise ValueError(f"{n} angles but {len(rssi_dbm)} RSSI values")
    if scan_ids is not None and len(scan_ids) != n:
        raise ValueError(f"{n} angles but {len(scan_ids)} scan ids")
    if not (all(map(math.isfinite, angles_deg)) and all(map(math.isfinite, rssi_dbm))):
        raise ValueError("samples must be finite")
    gs = list(scan_ids) if scan_ids is not None else [0] * n
    groups = set(gs)
    if n < len(groups) + 3:
        return None
    angles, ys = list(angles_deg), list(rssi_dbm)
    ws = [1.0] * n
    # 1. The global search.
    step = params.search_step_deg
    bw = pattern.beamwidth_deg() or 30.0
    lo, hi = min(angles), max(angles)
    # Bearings a beamwidth beyond the sweep's ends at most: further out the scan saw only
    # the pattern's far side (a back lobe can look just like the main lobe in a narrow
    # window), and a leader there is out of reach whichever way it is.
    reach = min(max(bw, params.min_reach_deg), 180.0)
    grid = [
        b
        for b in (-180.0 + i * step for i in range(round(360.0 / step)))
        if hi - lo + 2.0 * reach >= 360.0 or lo - reach <= b <= hi + reach
    ]
    if around_deg is not None:
        grid = [g for g in grid if abs(wrap180(g - around_deg)) <= bw] or [around_deg]
    costs = _search_costs(grid, pattern, angles, ys, gs)
    best = min(range(len(grid)), key=lambda i: costs[i])
    b = grid[best]
    # 2. Refine, Huber-weighted.
    scale = params.min_noise_db
    fine = params.fine_step_deg
    span = round(step / fine) + 1
    for _ in range(3):
        cands = [b + k * fine for k in range(-span, span + 1)]
        cs = [_cost(c, pattern, angles, ys, ws, gs)[0] for c in cands]
        k = min(range(len(cands)), key=lambda i: cs[i])
        b = cands[k]
        if 0 < k < len(cands) - 1:
            # The parabola through the three lowest costs: between the grid's points.
            den = cs[k - 1] - 2.0 * cs[k] + cs[k + 1]
            if den > 0:
                b += 0.5 * fine * (cs[k - 1] - cs[k + 1]) / den
        _, lv = _cost(b, pattern, angles, ys, [1.0] * n, gs)
        res = [
            y - pattern.gain_db(b - a) - lv.get(g, 0.0)
            for a, y, g in zip(angles, ys, gs, strict=True)
        ]
        scale = max(params.min_noise_db, _median([abs(r) for r in res]) / 0.6745)
        kk = params.huber_k * scale
        ws = [1.0 if abs(r) <= kk else kk / abs(r) for r in res]
    b = wrap180(b)
    cost_b, lv = _cost(b, pattern, angles, ys, ws, gs)
    # 5. No lobe: the pattern at its best explains little more than a flat line.
    flat_lv = _levels(ys, [0.0] * n, ws, gs)
    flat = sum(w * (y - flat_lv.get(g, 0.0)) ** 2 for y, w, g in zip(ys, ws, gs, strict=True))
    s2 = scale * scale
    if (flat - cost_b) / s2 < params.min_explained_chi2:
        return None
    # 3. The sd: the Fisher information of b, each scan's level a nuisance.
    sl = [pattern.slope_db_per_deg(b - a) for a in angles]
    sw: dict[int, float] = {}
    sj: dict[int, float] = {}
    for j, w, g in zip(sl, ws, gs, strict=True):
        sw[g] = sw.get(g, 0.0) + w
        sj[g] = sj.get(g, 0.0) + w * j
    info = (
        sum(w * (j - sj[g] / sw[g]) ** 2 for j, w, g in zip(sl, ws, gs, strict=True) if sw[g] > 0)
        / s2
    )
    sd = params.sd_scale / math.sqrt(info) if info > 0 else math.inf
    # 4. Ambiguity: another bearing, away from this one, nearly as good (unweighted costs,
    # as the search compared them; the best of the grid against its rivals).
    away = [(costs[i], grid[i]) for i in range(len(grid)) if abs(wrap180(grid[i] - b)) > bw / 2.0]
    if away:
        rival_cost, rival = min(away)
        if (rival_cost - costs[best]) / s2 < params.ambiguity_chi2:
            sd = max(sd, abs(wrap180(rival - b)))
    newest = max(groups)
    return LobeFit(
        bearing_deg=b,
        sd_deg=sd,
        beamwidth_deg=bw,
        peak_dbm=lv.get(newest, 0.0),
        used=n,
        extrapolated=not (lo <= b <= hi),
        noise_db=scale,
    )
