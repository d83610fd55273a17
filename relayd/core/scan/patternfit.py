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

A table known only in part (`AntennaPattern.known_deg`: a pattern learnt online,
relayd/core/scan/learn.py) is data within that range and an upper bound beyond: there a
sample costs the noise it would have had, plus its excess when it is louder than the
bound, and the levels come from the known samples (`_censored_cost`). A measured file
has no such range and is fitted exactly as above.

Several scans can be fitted as one (`scan_ids`): each scan has its own level, the
bearing is shared, as in `relayd.core.scan.bearing`.

Pure: no I/O, no clock, no NumPy.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
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
    #: Where a table is only a bound (`AntennaPattern.known_deg`), the gain is taken to lie
    #: between the bound and a floor: this much (dB) below the lowest known value, and at
    #: most `bound_floor_db` (a table known only high on its lobe says nothing of the floor).
    bound_depth_db: float = 10.0
    bound_floor_db: float = -30.0
    #: Beyond this rate (deg/s) the parabola fits instead (scan/moving.py, CONTROL.md 10.6).
    parabola_rate_deg_s: float = 10.0


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


def _censored_cost(
    b: float,
    pattern: AntennaPattern,
    angles: Sequence[float],
    ys: Sequence[float],
    ws: Sequence[float],
    gs: Sequence[int],
    s2: float,
    floor_db: float = -math.inf,
) -> tuple[float, dict[int, float], float]:
    """`_cost` for a table that is data only within `pattern.known_deg`: each scan's level
    from its samples there; a sample outside counts as the noise it would have (`s2`, so a
    bearing that moves samples out of the data gains nothing by it) plus its excess over
    the bound when it is louder than the table allows, or under `floor_db` when quieter
    than that. Also the cost without the `s2`
    terms (what the no-lobe test compares with a flat scan). Infinite with fewer than three
    known samples in a scan, or a fifth of them."""
    ms = [pattern.gain_db(b - a) for a in angles]
    kn = [pattern.known(b - a) for a in angles]
    kw = [w if k else 0.0 for w, k in zip(ws, kn, strict=True)]
    lv = _levels(ys, ms, kw, gs)
    counts: dict[int, list[int]] = {}
    for g, k in zip(gs, kn, strict=True):
        c = counts.setdefault(g, [0, 0])
        c[0] += 1 if k else 0
        c[1] += 1
    # A bearing that leaves a scan only a few known samples explains them too easily (a
    # leader at +85 deg was put at +147, its two loudest samples called the floor).
    if any(k < max(3, math.ceil(m / 5)) for k, m in counts.values()):
        return math.inf, lv, math.inf
    data = penalty = 0.0
    for y, m, w, g, k in zip(ys, ms, ws, gs, kn, strict=True):
        r = y - m - lv.get(g, 0.0)
        if k:
            data += w * r * r
        else:
            # Between the bound and the floor: an unknown part of a real antenna is not
            # far below everything known of it (else a leader's loudest samples could be
            # "explained" as the floor, the rest as anything below it).
            below = min(y - floor_db - lv.get(g, 0.0), 0.0)
            data += w * (max(r, 0.0) ** 2 + below * below)
            penalty += w * s2
    return data + penalty, lv, data


def _censored_search(
    grid: Sequence[float],
    pattern: AntennaPattern,
    angles: Sequence[float],
    ys: Sequence[float],
    gs: Sequence[int],
    min_noise_db: float,
    floor_db: float,
) -> tuple[float, list[float]]:
    """Every bearing's `_censored_cost`, and the noise a censored sample stands for: the
    known samples' residual variance at the best bearing of a first pass (at the noise
    floor). Not from the table taken as all data: where it is only a bound the truth can
    lie far below it, and that noise would pull every fit toward the bearings that keep
    samples known."""
    ws = [1.0] * len(ys)
    # Never below the scan's own roughness: neighbouring samples' differences (the
    # lobe's slope inflates it a little, which only makes leaving the data dearer). A
    # first pass that keeps only a few samples known fits them closely, and its small
    # residuals would make every censored sample cheap (a leader at -60 deg was put at
    # -130, where three samples were known).
    order = sorted(range(len(ys)), key=lambda i: (gs[i], angles[i]))
    steps = [abs(ys[j] - ys[i]) for i, j in itertools.pairwise(order) if gs[i] == gs[j]]
    rough = _median(steps) / 0.6745 / math.sqrt(2.0) if steps else 0.0
    floor = max(min_noise_db, rough) ** 2
    s2 = floor
    for _ in range(2):
        costs = [_censored_cost(g, pattern, angles, ys, ws, gs, s2, floor_db)[0] for g in grid]
        b = grid[min(range(len(grid)), key=lambda i: costs[i])]
        _, lv, _ = _censored_cost(b, pattern, angles, ys, ws, gs, s2, floor_db)
        known = [
            (y - pattern.gain_db(b - a) - lv.get(g, 0.0)) ** 2
            for a, y, g in zip(angles, ys, gs, strict=True)
            if pattern.known(b - a)
        ]
        dof = len(known) - len(set(gs))
        if dof <= 0:
            break
        s2 = max(floor, sum(known) / dof)
    return s2, costs


def _median(xs: Sequence[float]) -> float:
    s = sorted(xs)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


Cost = Callable[[float, Sequence[float]], tuple[float, dict[int, float]]]


def _refine(
    b: float,
    cost: Cost,
    pattern: AntennaPattern,
    angles: Sequence[float],
    ys: Sequence[float],
    gs: Sequence[int],
    params: PatternFitParams,
) -> tuple[float, list[float], float]:
    """Step 2: around the search's best, finely, Huber-weighted, three rounds; the
    bearing, the weights and the residual scale."""
    n = len(ys)
    ws = [1.0] * n
    scale = params.min_noise_db
    fine = params.fine_step_deg
    span = round(params.search_step_deg / fine) + 1
    for _ in range(3):
        cands = [b + k * fine for k in range(-span, span + 1)]
        cs = [cost(c, ws)[0] for c in cands]
        k = min(range(len(cands)), key=lambda i: cs[i])
        b = cands[k]
        if 0 < k < len(cands) - 1 and all(map(math.isfinite, cs[k - 1 : k + 2])):
            # The parabola through the three lowest costs: between the grid's points.
            den = cs[k - 1] - 2.0 * cs[k] + cs[k + 1]
            if den > 0:
                b += 0.5 * fine * (cs[k - 1] - cs[k + 1]) / den
        _, lv = cost(b, [1.0] * n)
        res = [
            y - pattern.gain_db(b - a) - lv.get(g, 0.0)
            for a, y, g in zip(angles, ys, gs, strict=True)
        ]
        # Below a bound is no residual (the leader is at least that far down there).
        res = [r if pattern.known(b - a) else max(r, 0.0) for r, a in zip(res, angles, strict=True)]
        scale = max(params.min_noise_db, _median([abs(r) for r in res]) / 0.6745)
        kk = params.huber_k * scale
        ws = [1.0 if abs(r) <= kk else kk / abs(r) for r in res]
    return b, ws, scale


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
    s2_bound, floor_db = 0.0, -math.inf
    if pattern.known_deg is not None:
        table = zip(pattern.angles_deg, pattern.gain_db_table, strict=True)
        lowest = min((g for a, g in table if pattern.known(a)), default=0.0)
        floor_db = min(lowest - params.bound_depth_db, params.bound_floor_db)
        s2_bound, costs = _censored_search(
            grid, pattern, angles, ys, gs, params.min_noise_db, floor_db
        )
    best = min(range(len(grid)), key=lambda i: costs[i])
    if not math.isfinite(costs[best]):
        return None  # too few samples where the table is known, wherever the leader is
    b = grid[best]

    # 2. Refine, Huber-weighted.
    def cost(c: float, weights: Sequence[float]) -> tuple[float, dict[int, float]]:
        if pattern.known_deg is None:
            return _cost(c, pattern, angles, ys, weights, gs)
        total, levels, _ = _censored_cost(c, pattern, angles, ys, weights, gs, s2_bound, floor_db)
        return total, levels

    b, ws, scale = _refine(b, cost, pattern, angles, ys, gs, params)
    b = wrap180(b)
    cost_b, lv = _cost(b, pattern, angles, ys, ws, gs)
    if pattern.known_deg is not None:
        _, lv, cost_b = _censored_cost(b, pattern, angles, ys, ws, gs, s2_bound, floor_db)
    # 5. No lobe: the pattern at its best explains little more than a flat line.
    flat_lv = _levels(ys, [0.0] * n, ws, gs)
    flat = sum(w * (y - flat_lv.get(g, 0.0)) ** 2 for y, w, g in zip(ys, ws, gs, strict=True))
    s2 = scale * scale
    if (flat - cost_b) / s2 < params.min_explained_chi2:
        return None
    # 3. The sd: the Fisher information of b, each scan's level a nuisance.
    sl = [pattern.slope_db_per_deg(b - a) if pattern.known(b - a) else 0.0 for a in angles]
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
