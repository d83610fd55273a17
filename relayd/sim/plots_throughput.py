"""Throughput over time: one run's, several runs' on one axis, and several seeds' mean
with a +-1 sd band (the sweep's report and the paper comparison). Drawn and saved through
relayd.sim.plots (its matplotlib set-up and `save`), looked up at call time so a test that
replaces `plots.save` sees these figures too."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from relayd.sim import plots as _base


def plot_throughput(
    runs: Sequence[tuple[str, Sequence[dict[str, Any]]]], path: Path, title: str
) -> None:
    """End-to-end throughput over time; several runs (e.g. 0/1/2 relays) on one axis."""
    plt = _base.pyplot()
    fig, ax = plt.subplots(figsize=(9, 4))
    for label, records in runs:
        ax.plot([r["t"] for r in records], [r["e2e_mbps"] for r in records], label=label)
    _finish_throughput(fig, ax, title, path)


def plot_throughput_bands(
    curves: Sequence[tuple[str, Sequence[float], Sequence[float], Sequence[float]]],
    path: Path,
    title: str,
    marks: Sequence[tuple[float, str]] = (),
    hlines: Sequence[tuple[float, str]] = (),
) -> None:
    """Paper-style throughput over time for several seeds: per curve (label, t, mean, sd)
    a mean line and a +-1 sd band (clipped at 0 Mbps); `marks` are labelled vertical
    lines (e.g. when the leader passes a corner), `hlines` labelled horizontal ones."""
    plt = _base.pyplot()
    fig, ax = plt.subplots(figsize=(9, 4))
    for x, label in marks:
        ax.axvline(x, color="grey", ls="--", lw=0.8)
        ax.annotate(
            label,
            (x, 1.0),
            xycoords=("data", "axes fraction"),
            xytext=(3, -12),
            textcoords="offset points",
            fontsize=8,
            color="dimgrey",
        )
    for y, label in hlines:
        ax.axhline(y, color="grey", ls=":", lw=0.8)
        ax.annotate(
            label,
            (0.0, y),
            xycoords=("axes fraction", "data"),
            xytext=(3, 2),
            textcoords="offset points",
            fontsize=8,
            color="dimgrey",
        )
    for label, t, mean, sd in curves:
        (line,) = ax.plot(t, mean, label=label)
        ax.fill_between(
            t,
            [max(0.0, m - s) for m, s in zip(mean, sd, strict=True)],
            [m + s for m, s in zip(mean, sd, strict=True)],
            color=line.get_color(),
            alpha=0.2,
            lw=0,
        )
    _finish_throughput(fig, ax, title, path)


def _finish_throughput(fig: Any, ax: Any, title: str, path: Path) -> None:
    """The axes, title, legend and file every throughput-over-time plot shares."""
    ax.set_xlabel("time (s)")
    ax.set_ylabel("end-to-end throughput (Mbps)")
    ax.set_ylim(bottom=0)
    ax.set_title(title)
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    _base.save(fig, path, dpi=100)
