"""What `relayd calibrate path-loss` prints and writes: the fit, thresholds, a config snippet, a plot."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from relayd.calibrate.fit import (
    MAX_EXTRAPOLATION,
    PathLossFit,
    required_rssi_dbm,
    threshold_for_hop_length,
    threshold_for_throughput,
)
from relayd.calibrate.sources import Reading
from relayd.core.link.model import LinkModel, LinkPolicyParams, LinkSample

#: Polls needed on each side of the target (meeting it, missing it) for a measured threshold.
MIN_VERDICTS = 5


@dataclass(frozen=True, slots=True)
class Wanted:
    """What the deployer asked thresholds for."""

    link: str = "rear"
    hop_m: float | None = None
    target_mbps: float | None = None
    outage: float = 0.1
    phy: str = "802.11g"
    mac_efficiency: float = 0.5


@dataclass(frozen=True, slots=True)
class Thresholds:
    key: str  # threshold_b_dbm or threshold_l_dbm
    by_length: float | None
    by_throughput: float | None
    #: From the measured airOS rates (the adaptive model over the drive), when the data had rates.
    by_measured_rate: float | None
    #: Leader link only: the threshold_l that keeps the robot within the gap but with the
    #: outage probability (the median there raised by z sigma, as for a hop length), where
    #: `by_length` is the median gap. Shadowing spreads the stopping points of a median
    #: threshold about the gap both ways; this one bounds them.
    bound: float | None = None

    @property
    def chosen(self) -> float | None:
        """The most demanding of the asked-for thresholds (higher = the robot stops sooner)."""
        values = [
            v for v in (self.by_length, self.by_throughput, self.by_measured_rate) if v is not None
        ]
        return max(values) if values else None


def measured_rate_threshold(readings: Sequence[Reading], wanted: Wanted) -> float | None:
    """The adaptive model run over the drive: the RSSI^b where the measured rates meet the target."""
    if wanted.target_mbps is None:
        return None
    verdicts = [
        d >= wanted.target_mbps
        for r in readings
        if (
            d := LinkSample(0.0, r.rssi_dbm, r.tx_mbps, r.rx_mbps, r.ccq_pct).delivered_mbps(
                wanted.mac_efficiency
            )
        )
        is not None
    ]
    if sum(verdicts) < MIN_VERDICTS or len(verdicts) - sum(verdicts) < MIN_VERDICTS:
        return None  # the drive never saw the rate on both sides of the target: nothing measured
    model = LinkModel(
        LinkPolicyParams(
            adaptive=True,
            target_hop_mbps=wanted.target_mbps,
            outage=wanted.outage,
            bounds_dbm=(-95.0, -20.0),
            fallback_dbm=-60.0,
            mac_efficiency=wanted.mac_efficiency,
            half_life_samples=max(60.0, 10.0 * len(readings)),
            stale_s=math.inf,
        )
    )
    for i, r in enumerate(readings):
        model.observe(LinkSample(float(i), r.rssi_dbm, r.tx_mbps, r.rx_mbps, r.ccq_pct), float(i))
    return model.threshold_dbm if model.n_eff >= model.params.min_samples else None


def thresholds(fit: PathLossFit, readings: Sequence[Reading], wanted: Wanted) -> Thresholds:
    key = "threshold_l_dbm" if wanted.link == "leader" else "threshold_b_dbm"
    by_len = (
        None if wanted.hop_m is None else threshold_for_hop_length(fit, wanted.hop_m, wanted.outage)
    )
    by_tp = None
    by_rate = None
    if wanted.target_mbps is not None and key == "threshold_b_dbm":
        by_tp = threshold_for_throughput(
            fit,
            wanted.target_mbps,
            wanted.outage,
            phy=wanted.phy,
            mac_efficiency=wanted.mac_efficiency,
        )
        by_rate = measured_rate_threshold(readings, wanted)
    bound = None
    if key == "threshold_l_dbm" and by_len is not None:
        # The following gap: the robot stops on reaching it, so the median level there, no margin.
        bound = by_len
        by_len = fit.rssi_at(wanted.hop_m or 1.0)
    return Thresholds(key, by_len, by_tp, by_rate, bound)


def _ci(value: float, low: float, high: float, digits: int) -> str:
    return f"{value:.{digits}f}  [{low:.{digits}f} .. {high:.{digits}f}]"


def text_report(fit: PathLossFit, thr: Thresholds, wanted: Wanted, source: str) -> str:
    c = round(fit.confidence * 100)
    lines = [
        f"path loss of the {wanted.link} link, from {source}",
        f"  readings  {fit.points} used ({fit.dropped} left out), "
        f"{fit.distance_range_m[0]:.1f} .. {fit.distance_range_m[1]:.1f} m",
        f"  L0        {_ci(fit.l0_dbm, fit.l0_ci.low, fit.l0_ci.high, 1)} dBm at 1 m  ({c} % interval)",
        f"  n         {_ci(fit.n, fit.n_ci.low, fit.n_ci.high, 2)}",
        f"  sigma     {_ci(fit.sigma_db, fit.sigma_ci.low, fit.sigma_ci.high, 1)} dB  "
        f"(reading to reading {fit.sigma_fast_db:.1f}, slow shadowing {fit.sigma_slow_db:.1f})",
    ]
    width = fit.n_ci.high - fit.n_ci.low
    if width > 0.6:
        lines.append(
            f"  note      n is uncertain (+-{width / 2:.2f}): drive further, or repeat the pass "
            "along another line and give both recordings"
        )
    lines.append(f"thresholds at {wanted.outage:.0%} outage:")
    if thr.by_length is not None:
        what = "following gap" if thr.key == "threshold_l_dbm" else "hop length"
        lines.append(f"  {what} {wanted.hop_m:g} m:  {thr.key} = {thr.by_length:.1f} dBm")
    if thr.bound is not None:
        lines.append(
            f"  gap at most {wanted.hop_m:g} m (outage {wanted.outage:g}):  {thr.key} = {thr.bound:.1f} dBm"
            f"  ({_where(fit, thr.bound, 'a median gap of {:.1f} m')})"
        )
    if thr.by_throughput is not None and wanted.target_mbps is not None:
        need = required_rssi_dbm(wanted.target_mbps, wanted.phy, wanted.mac_efficiency)
        lines.append(
            f"  hop throughput {wanted.target_mbps:g} Mbit/s ({wanted.phy} needs {need:g} dBm, "
            f"+ {thr.by_throughput - need:.1f} dB margin):  {thr.key} = {thr.by_throughput:.1f} dBm"
            f"  ({_where(fit, thr.by_throughput, 'about {:.1f} m in this place')})"
        )
    if thr.by_measured_rate is not None:
        lines.append(
            f"  from the radio's own rates and CCQ on this drive:  {thr.key} = "
            f"{thr.by_measured_rate:.1f} dBm"
        )
    elif thr.by_throughput is not None:
        lines.append(
            "  (the drive never took the radio's rate below the target: drive further for a "
            "threshold measured from the rates)"
        )
    if thr.chosen is None:
        lines.append("  (give --hop-m and/or --target-mbps for thresholds)")
    far = fit.distance_range_m[1]
    if wanted.hop_m is not None and wanted.hop_m > MAX_EXTRAPOLATION * far:
        lines.append(
            f"  note      {wanted.hop_m:g} m is beyond {MAX_EXTRAPOLATION:g} x the farthest "
            f"reading ({far:.1f} m): the threshold for it is extrapolated; drive that far"
        )
    return "\n".join(lines)


def _where(fit: PathLossFit, rssi_dbm: float, text: str) -> str:
    """Where the model puts `rssi_dbm`, or that it lies past what the drive measured."""
    d = fit.measured_distance_at(rssi_dbm)
    if d is None:
        far = MAX_EXTRAPOLATION * fit.distance_range_m[1]
        return f"beyond {far:.1f} m, {MAX_EXTRAPOLATION:g} x the farthest reading: not measured"
    return text.format(d)


def config_snippet(fit: PathLossFit, thr: Thresholds, wanted: Wanted, source: str) -> str:
    """A [control] snippet to paste into relayd.toml (values rounded to what matters)."""
    lines = [
        f"# relayd calibrate path-loss: {wanted.link} link from {source}",
        f"# L0 = {fit.l0_dbm:.1f} dBm, n = {fit.n:.2f}, sigma = {fit.sigma_db:.1f} dB "
        f"({fit.points} readings, {fit.distance_range_m[0]:.1f}-{fit.distance_range_m[1]:.1f} m)",
        "[control]",
    ]
    chosen = thr.chosen
    if chosen is None:
        lines.append(f"# {thr.key}: give --hop-m or --target-mbps")
    else:
        asked = []
        if wanted.hop_m is not None:
            asked.append(f"hop {wanted.hop_m:g} m")
        if wanted.target_mbps is not None:
            asked.append(f"{wanted.target_mbps:g} Mbit/s")
        # The leader link's threshold is the median at the gap (the robot stops on reaching
        # it); the outage applies to its "gap at most" line in the report, not to this one.
        how = (
            "the median gap"
            if thr.bound is not None and chosen == thr.by_length
            else f"at {100 * wanted.outage:g} % outage"
        )
        lines.append(f"{thr.key} = {round(chosen)}   # {', '.join(asked)}, {how}")
    if thr.key == "threshold_b_dbm" and wanted.target_mbps is not None:
        lines += [
            f"target_hop_mbps = {wanted.target_mbps:g}",
            f"outage_probability = {wanted.outage:g}",
            f'# link_policy = "adaptive" starts from {thr.key} and learns from there '
            "(docs/CONTROL.md section 5.1)",
        ]
    return "\n".join(lines) + "\n"


def plain_log_axis(ax: Any) -> None:
    """A log distance axis labelled in plain metres (1, 2, 5, 10, 20 ...), not 2x10^0."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    ax.set_xscale("log")
    ax.xaxis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())


def plot_fit(
    fit: PathLossFit, readings: Sequence[Reading], thr: Thresholds, path: Path, title: str
) -> bool:
    """RSSI against distance (log axis), the fitted line with its +-sigma band, the thresholds.
    False when matplotlib is not installed (`pip install 'relayd[sim]'`)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    fig, ax = plt.subplots(figsize=(8, 5))
    try:
        d = [r.distance_m for r in readings]
        ax.scatter(
            d, [r.rssi_dbm for r in readings], s=6, alpha=0.4, color="tab:blue", label="readings"
        )
        lo, hi = fit.distance_range_m
        xs = [lo * (hi / lo) ** (i / 100) for i in range(101)]
        mid = [fit.rssi_at(x) for x in xs]
        ax.plot(xs, mid, color="black", label=f"L0 = {fit.l0_dbm:.1f} dBm, n = {fit.n:.2f}")
        ax.fill_between(
            xs,
            [m - fit.sigma_db for m in mid],
            [m + fit.sigma_db for m in mid],
            color="grey",
            alpha=0.25,
            label=f"+-sigma = {fit.sigma_db:.1f} dB",
        )
        for value, name, style in (
            (thr.by_length, "by hop length", "--"),
            (thr.by_throughput, "by throughput", ":"),
            (thr.by_measured_rate, "by measured rate", "-."),
        ):
            if value is not None:
                ax.axhline(
                    value, linestyle=style, color="tab:red", label=f"{thr.key} {name}: {value:.1f}"
                )
        plain_log_axis(ax)
        ax.set_xlabel("distance from the node (m, odometry)")
        ax.set_ylabel("RSSI (dBm)")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="lower left", fontsize=8)
        fig.tight_layout()
        fig.savefig(path, dpi=100)
    finally:
        plt.close(fig)
    return True
