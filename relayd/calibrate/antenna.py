"""The measurement of `relayd calibrate antenna`: scan sweeps of a still node -> the antenna's pattern.

A node (the command center's AP, any station the Yagi hears) stands at a known bearing
a few metres from a still relay; the relay sweeps its scan servo, again and again, and
may turn in place between sweeps to show the node to the back half of the antenna too.
Each sample is then the pattern at one off-axis angle:

    off_axis = node_bearing - (heading - heading at the start) - servo angle

plus the link's level (the same for every sample: nothing moves) and noise. So:

1. Samples are grouped by off-axis angle (rounded to `bin_deg`), each group averaged in
   dB; angles heard fewer than `min_repeats` times are left out (one faded sample is not
   a pattern point).
2. The averages are normalised to their peak: the pattern's 0 dB.
3. How well it repeats: the even and the odd sweeps are averaged apart, and the RMS of
   their difference over the main lobe (within 10 dB of the peak) is the repeatability;
   the spread of each sweep's own peak angle says whether the lobe stood still.
4. Refused, with every reason at once, never written: too few sweeps or angles; a flat
   pattern (under `min_range_db` from peak to floor: no directional antenna, or the node
   not heard through it); the node too close (a stated distance under 3 m, or a peak
   louder than `max_peak_dbm`: the adapter saturates and the near field is not the
   pattern); an unstable shape (the halves differ by more than `max_repeat_db` over the
   main lobe, single sweeps scatter about the average by more than `max_scatter_db`, or
   the sweeps' peaks wander: people walking by, multipath that moves); the
   peak at the edge of what was measured (the main lobe was not seen whole).

Pure: samples in, a result out; no I/O, no clock.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from relayd.core.scan.pattern import AntennaPattern, PatternError, wrap180


@dataclass(frozen=True, slots=True)
class AntennaSample:
    """One scan sample of a calibration: when, the robot's heading, the servo's angle, RSSI."""

    t: float
    heading_deg: float
    servo_deg: float
    rssi_dbm: float
    #: Which sweep it belongs to (consecutive samples of one sweep share it).
    sweep: int


@dataclass(frozen=True, slots=True)
class CalibrationParams:
    bin_deg: float = 1.0
    min_repeats: int = 3
    min_sweeps: int = 4
    min_angles: int = 12
    min_range_db: float = 6.0
    max_peak_dbm: float = -25.0
    min_distance_m: float = 3.0
    max_repeat_db: float = 1.5
    #: The sweeps' own peaks may spread (sd) by at most this share of the beamwidth.
    max_peak_spread: float = 0.5
    #: Single sweeps may scatter about the average by at most this (dB RMS, main lobe).
    max_scatter_db: float = 3.0


class CalibrationRefused(ValueError):
    """A measurement no pattern may be written from; `reasons` says every why."""

    def __init__(self, reasons: list[str]) -> None:
        super().__init__("; ".join(reasons))
        self.reasons = reasons


@dataclass(frozen=True, slots=True)
class AntennaCalibration:
    """What a calibration measured: the pattern and how far to trust it."""

    pattern: AntennaPattern
    samples: int
    sweeps: int
    peak_dbm: float
    #: RMS difference (dB) of the even and odd sweeps' patterns over the main lobe.
    repeat_db: float
    #: Each angle's standard error (dB) of its mean, the worst over the main lobe.
    worst_se_db: float
    #: The sd (deg) of the sweeps' own peak angles.
    peak_spread_deg: float
    #: Where the lobe's top is, off the mechanical axis (the fitted top, not the loudest
    #: average): the asymmetry's first figure.
    squint_deg: float
    #: Single sweeps' scatter (dB RMS) about the average over the main lobe.
    scatter_db: float
    beamwidth_deg: float | None
    half_widths_deg: tuple[float | None, float | None]
    front_to_back_db: float | None
    side_lobe_db: float | None
    warnings: tuple[str, ...] = field(default=())


def off_axis_deg(s: AntennaSample, node_bearing_deg: float, heading0_deg: float) -> float:
    return wrap180(node_bearing_deg - wrap180(s.heading_deg - heading0_deg) - s.servo_deg)


def _bin(x: float, step: float) -> float:
    return round(round(x / step) * step, 6)


def _means(
    samples: Sequence[AntennaSample], node: float, h0: float, step: float
) -> dict[float, list[float]]:
    out: dict[float, list[float]] = {}
    for s in samples:
        out.setdefault(_bin(off_axis_deg(s, node, h0), step), []).append(s.rssi_dbm)
    return out


def _mean(xs: Sequence[float]) -> float:
    return sum(xs) / len(xs)


def _sd(xs: Sequence[float]) -> float:
    m = _mean(xs)
    return math.sqrt(sum((x - m) ** 2 for x in xs) / max(1, len(xs) - 1))


def _sweep_peaks(
    samples: Sequence[AntennaSample], node: float, h0: float, lobe: tuple[float, float]
) -> list[float]:
    """Each sweep's loudest off-axis angle (3-point running mean, as the fit's peak), of the
    sweeps that saw the whole main lobe (`lobe`: its 3 dB points); a sweep of the back half
    (the robot turned) has no main-lobe peak to agree on."""
    by: dict[int, list[tuple[float, float]]] = {}
    for s in samples:
        by.setdefault(s.sweep, []).append((off_axis_deg(s, node, h0), s.rssi_dbm))
    peaks = []
    for pts in by.values():
        pts.sort()
        near = [
            any(abs(wrap180(a - x)) <= 10.0 for a, _ in pts)
            for x in (lobe[0], sum(lobe) / 2, lobe[1])
        ]
        if len(pts) < 3 or not all(near):
            continue
        sm = [
            _mean([pts[j][1] for j in range(max(0, i - 1), min(len(pts), i + 2))])
            for i in range(len(pts))
        ]
        peaks.append(pts[max(range(len(pts)), key=lambda i: sm[i])][0])
    return peaks


# Complexity: the checks of a measurement side by side, each a few lines with its reason.
def measure_pattern(  # noqa: C901
    samples: Sequence[AntennaSample],
    *,
    node_bearing_deg: float = 0.0,
    distance_m: float | None = None,
    name: str = "",
    params: CalibrationParams = CalibrationParams(),
) -> AntennaCalibration:
    """The pattern these sweeps measured, or CalibrationRefused saying why not."""
    p = params
    reasons: list[str] = []
    if distance_m is not None and distance_m < p.min_distance_m:
        reasons.append(
            f"node too close: {distance_m:g} m (stand it {p.min_distance_m:g}-15 m away: nearer, "
            "the robot's own body and the near field shape what the antenna hears)"
        )
    if not samples:
        raise CalibrationRefused([*reasons, "too few samples: none"])
    h0 = samples[0].heading_deg
    sweeps = len({s.sweep for s in samples})
    groups = _means(samples, node_bearing_deg, h0, p.bin_deg)
    kept = {a: v for a, v in groups.items() if len(v) >= p.min_repeats}
    if sweeps < p.min_sweeps or len(kept) < p.min_angles:
        reasons.append(
            f"too few samples: {sweeps} sweeps, {len(kept)} angles heard at least "
            f"{p.min_repeats} times (need {p.min_sweeps} sweeps and {p.min_angles} angles)"
        )
        raise CalibrationRefused(reasons)
    angles = sorted(kept)
    means = [_mean(kept[a]) for a in angles]
    peak, peak_at = _peak_level(angles, means)
    floor = min(means)
    if peak - floor < p.min_range_db:
        reasons.append(
            f"flat pattern: {peak - floor:.1f} dB from peak to floor (need {p.min_range_db:g}): "
            "is the node heard through this antenna, and the antenna directional?"
        )
    if peak > p.max_peak_dbm:
        reasons.append(
            f"node too close: the peak is {peak:.0f} dBm (at most {p.max_peak_dbm:g}: the adapter "
            "saturates, and the near field is not the pattern); stand it further away"
        )
    gains = [m - peak for m in means]
    i_peak = max(range(len(angles)), key=lambda i: means[i])
    if i_peak in (0, len(angles) - 1) and not _full_circle(angles, p.bin_deg):
        reasons.append(
            f"the peak is at the edge of what was measured ({angles[i_peak]:+.0f} deg): "
            "stand the node where the servo's middle points"
        )
    # Repeatability: even against odd sweeps, over the main lobe.
    lobe = {a for a, g in zip(angles, gains, strict=True) if g >= -10.0}
    halves: list[dict[float, list[float]]] = [{}, {}]
    for s in samples:
        a = _bin(off_axis_deg(s, node_bearing_deg, h0), p.bin_deg)
        if a in lobe:
            halves[s.sweep % 2].setdefault(a, []).append(s.rssi_dbm)
    both = [a for a in lobe if a in halves[0] and a in halves[1]]
    diffs = [_mean(halves[0][a]) - _mean(halves[1][a]) for a in both]
    if diffs:
        bias = _mean(diffs)  # a level that drifted between halves is not a shape change
        repeat = math.sqrt(_mean([(d - bias) ** 2 for d in diffs]))
    else:
        repeat = math.inf
    # Each sweep's own shape against the average: the scatter of single readings over the
    # main lobe, each sweep at its own level. Fading and whole-dB readings give 1.5-2.5 dB;
    # a second path whose phase moves (people walking by) gives 4 and more.
    mean_at = {a: _mean(kept[a]) for a in lobe}
    per_sweep: dict[int, list[float]] = {}
    for s in samples:
        a = _bin(off_axis_deg(s, node_bearing_deg, h0), p.bin_deg)
        if a in mean_at:
            per_sweep.setdefault(s.sweep, []).append(s.rssi_dbm - mean_at[a])
    resid = [d - _mean(ds) for ds in per_sweep.values() if len(ds) >= 3 for d in ds]
    scatter = math.sqrt(_mean([r * r for r in resid])) if resid else 0.0
    se = [_sd(kept[a]) / math.sqrt(len(kept[a])) for a in lobe]
    worst_se = max(se) if se else math.inf
    try:
        pattern = AntennaPattern(tuple(angles), tuple(gains), name)
    except PatternError as exc:
        raise CalibrationRefused([*reasons, f"no usable table: {exc}"]) from None
    bw = pattern.beamwidth_deg()
    left, right = pattern.half_widths_deg()
    spread = 0.0
    if left is not None and right is not None:
        pk = pattern.peak_deg()
        peaks = _sweep_peaks(samples, node_bearing_deg, h0, (pk - left, pk + right))
        spread = _sd(peaks) if len(peaks) >= 2 else 0.0
    if repeat > p.max_repeat_db:
        reasons.append(
            f"unstable shape: the sweeps disagree by {repeat:.1f} dB RMS over the main lobe (at most "
            f"{p.max_repeat_db:g}): multipath that moves (people, vehicles), or too few repeats"
        )
    if scatter > p.max_scatter_db:
        reasons.append(
            f"unstable shape: single sweeps scatter by {scatter:.1f} dB RMS about the average over "
            f"the main lobe (at most {p.max_scatter_db:g}): strong multipath, or something moving "
            "near the antenna or the node"
        )
    if bw is not None and spread > p.max_peak_spread * bw:
        reasons.append(
            f"unstable shape: the sweeps' peaks wander by {spread:.1f} deg (sd; at most "
            f"{p.max_peak_spread * bw:.1f}): multipath that moves, or the node or robot moved"
        )
    if reasons:
        raise CalibrationRefused(reasons)
    warnings = []
    if not pattern.full_circle:
        warnings.append(
            f"measured from {angles[0]:+.0f} to {angles[-1]:+.0f} deg off axis; beyond, the fit "
            f"takes the lowest level measured ({min(gains):.1f} dB). Turn the robot in place "
            "between sweeps to measure the back half"
        )
    halves_3db = _half_widths(pattern, peak_at)
    return AntennaCalibration(
        pattern=pattern,
        samples=len(samples),
        sweeps=sweeps,
        peak_dbm=peak,
        repeat_db=repeat,
        worst_se_db=worst_se,
        peak_spread_deg=spread,
        squint_deg=peak_at,
        scatter_db=scatter,
        beamwidth_deg=None if None in halves_3db else sum(h for h in halves_3db if h is not None),
        half_widths_deg=halves_3db,
        front_to_back_db=pattern.front_to_back_db(),
        side_lobe_db=pattern.side_lobe_db(),
        warnings=tuple(warnings),
    )


def _peak_level(angles: Sequence[float], means: Sequence[float]) -> tuple[float, float]:
    """The lobe's top and where it is: a parabola through the averages within 4 dB of the
    loudest (its run around it), not the loudest average itself, which the noise lifts by a
    fraction of a dB and moves by a sample or two on a flat top (the maximum of many noisy
    averages is biased up)."""
    top = max(range(len(means)), key=lambda i: means[i])
    lo = hi = top
    while lo > 0 and means[lo - 1] >= means[top] - 4.0:
        lo -= 1
    while hi < len(means) - 1 and means[hi + 1] >= means[top] - 4.0:
        hi += 1
    if hi - lo < 2:
        return means[top], angles[top]
    xs = [angles[i] - angles[top] for i in range(lo, hi + 1)]
    ys = list(means[lo : hi + 1])
    # Least squares y = a + b x + c x^2 by the normal equations (3x3, Cramer's rule).
    s = [sum(x**k for x in xs) for k in range(5)]
    t = [sum(y * x**k for x, y in zip(xs, ys, strict=True)) for k in range(3)]
    m = [[s[0], s[1], s[2]], [s[1], s[2], s[3]], [s[2], s[3], s[4]]]

    def det(a: list[list[float]]) -> float:
        return (
            a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
        )

    d = det(m)
    if abs(d) < 1e-12:
        return means[top], angles[top]
    coef = []
    for j in range(3):
        mj = [row[:] for row in m]
        for i in range(3):
            mj[i][j] = t[i]
        coef.append(det(mj) / d)
    a, b, c = coef
    if c >= 0 or not xs[0] <= -b / (2 * c) <= xs[-1]:
        return means[top], angles[top]
    return a - b * b / (4 * c), angles[top] - b / (2 * c)


def _half_widths(pattern: AntennaPattern, top_deg: float) -> tuple[float | None, float | None]:
    """How far each side of the fitted top the pattern stays above -3 dB."""
    out: list[float | None] = []
    for d in (-1.0, 1.0):
        x = None
        for k in range(1, 1800):
            if pattern.gain_db(top_deg + d * 0.1 * k) <= -3.0:
                x = 0.1 * k
                break
        out.append(x)
    return out[0], out[1]


def _full_circle(angles: Sequence[float], step: float) -> bool:
    return angles[-1] - angles[0] >= 360.0 - 2.0 * step


def text_report(cal: AntennaCalibration, source: str) -> str:
    """The figures a deployer reads: shape, how it repeats, what to look at."""

    def f(v: float | None, unit: str) -> str:
        return "not measured" if v is None else f"{v:.1f} {unit}"

    left, right = cal.half_widths_deg
    lines = [
        f"antenna pattern from {source}",
        f"  samples {cal.samples} in {cal.sweeps} sweeps; peak {cal.peak_dbm:.1f} dBm",
        f"  3 dB beamwidth   {f(cal.beamwidth_deg, 'deg')} "
        f"(left {f(left, 'deg')}, right {f(right, 'deg')})",
        f"  peak off axis    {cal.squint_deg:+.1f} deg",
        f"  front-to-back    {f(cal.front_to_back_db, 'dB')}",
        f"  worst side lobe  {f(cal.side_lobe_db, 'dB')}",
        f"  repeatability    {cal.repeat_db:.2f} dB RMS over the main lobe "
        f"(worst standard error {cal.worst_se_db:.2f} dB); sweeps' peaks within "
        f"{cal.peak_spread_deg:.1f} deg (sd); single sweeps scatter {cal.scatter_db:.1f} dB RMS",
    ]
    lines += [f"  note: {w}" for w in cal.warnings]
    return "\n".join(lines)


def plot_pattern(cal: AntennaCalibration, path: str, title: str) -> bool:
    """A polar and a linear plot of the pattern (False when matplotlib is missing)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    a = cal.pattern.angles_deg
    g = cal.pattern.gain_db_table
    fig = plt.figure(figsize=(10, 4.5))
    ax1 = fig.add_subplot(1, 2, 1, projection="polar")
    ax1.plot([math.radians(x) for x in a], [max(v, -40.0) for v in g])
    ax1.set_theta_zero_location("N")  # type: ignore[attr-defined]  # a PolarAxes
    ax1.set_ylim(-40, 0)
    ax2 = fig.add_subplot(1, 2, 2)
    ax2.plot(a, g, marker=".")
    ax2.axhline(-3.0, ls=":", c="grey")
    ax2.set_xlabel("off-axis angle (deg)")
    ax2.set_ylabel("relative gain (dB)")
    ax2.grid(True)
    fig.suptitle(title)
    # Room between the two: the polar axes' 270 deg label sat on the dB axis's label.
    fig.subplots_adjust(left=0.04, right=0.98, wspace=0.3)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True
