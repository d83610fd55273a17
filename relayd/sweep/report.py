"""DIR/report.md of a sweep: per grid cell (scenario x --set values) a table of the
metrics' mean +- sd over seeds for each relay count, and a throughput plot with the
mean line and a +-1 sd band per relay count (DIR/plots/*.png, when matplotlib imports).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

Cell = tuple[str, tuple[tuple[str, Any], ...]]


def mean_sd(values: Sequence[float]) -> tuple[float, float] | None:
    """Mean and sample standard deviation (0 for one value); None for no values."""
    vals = [float(v) for v in values]
    if not vals:
        return None
    m = sum(vals) / len(vals)
    if len(vals) == 1:
        return m, 0.0
    return m, math.sqrt(sum((v - m) ** 2 for v in vals) / (len(vals) - 1))


def fmt_ms(ms: tuple[float, float] | None, digits: int = 1) -> str:
    return "-" if ms is None else f"{ms[0]:.{digits}f} ± {ms[1]:.{digits}f}"


def load_series(out: Path, row: dict[str, Any]) -> dict[str, list[float]] | None:
    try:
        data: dict[str, list[float]] = json.loads(
            (out / row["run_dir"] / "series.json").read_text(encoding="utf-8")
        )
    except (OSError, ValueError):
        return None
    return data


def band(series: Sequence[dict[str, list[float]]]) -> tuple[list[float], list[float], list[float]]:
    """Time, mean and sd over the runs that reach each second."""
    length = max((len(s["t"]) for s in series), default=0)
    ts, means, sds = [], [], []
    for k in range(length):
        vals = [s["e2e_mbps"][k] for s in series if k < len(s["e2e_mbps"])]
        ms = mean_sd(vals)
        if ms is None:
            continue
        ts.append(float(k))
        means.append(ms[0])
        sds.append(ms[1])
    return ts, means, sds


def cells(
    rows: Sequence[dict[str, Any]], set_keys: Sequence[str]
) -> dict[Cell, list[dict[str, Any]]]:
    out: dict[Cell, list[dict[str, Any]]] = {}
    for r in rows:
        key: Cell = (str(r["scenario"]), tuple((k, r[k]) for k in set_keys))
        out.setdefault(key, []).append(r)
    return out


def _num(rows: Sequence[dict[str, Any]], key: str) -> list[float]:
    return [float(r[key]) for r in rows if r.get("status") == "ok" and r.get(key) not in ("", None)]


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "-", text).strip("-") or "cell"


def plot_cell(
    out: Path, title: str, by_relays: dict[int, list[dict[str, list[float]]]], path: Path
) -> None:
    from relayd.sim.plots_throughput import plot_throughput_bands

    curves = []
    for n in sorted(by_relays):
        ts, means, sds = band(by_relays[n])
        curves.append((f"{n} relay(s), {len(by_relays[n])} runs", ts, means, sds))
    plot_throughput_bands(curves, path, title)


def write_report(
    out: Path, rows: Sequence[dict[str, Any]], set_keys: Sequence[str], plots: bool = True
) -> Path:
    """Write DIR/report.md (and DIR/plots/) from the runs.csv rows; returns the report's path."""
    lines = [
        "# Sweep report",
        "",
        f"{len(rows)} runs: {sum(r['status'] == 'ok' for r in rows)} ok, "
        f"{sum(r['status'] != 'ok' for r in rows)} failed. Values are mean ± sd over the seeds "
        "that finished; `broken` counts the runs whose link broke, `broken at` averages those runs only. "
        "Per-run numbers are in runs.csv.",
        "",
    ]
    if plots:
        (out / "plots").mkdir(exist_ok=True)
    for (scenario, params), cell_rows in cells(rows, set_keys).items():
        label = scenario + (" (" + ", ".join(f"{k}={v}" for k, v in params) + ")" if params else "")
        lines += [
            f"## {label}",
            "",
            "| relays | runs ok/failed | goal reached | broken | broken at (s) | start e2e (Mbps) "
            "| min e2e (Mbps) | final e2e (Mbps) | collisions |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        by_relays: dict[int, list[dict[str, Any]]] = {}
        for r in cell_rows:
            by_relays.setdefault(int(r["relays"]), []).append(r)
        series: dict[int, list[dict[str, list[float]]]] = {}
        for n in sorted(by_relays):
            rs = by_relays[n]
            ok = [r for r in rs if r["status"] == "ok"]
            goal = sum(str(r["goal_reached"]) == "True" for r in ok)
            broken = _num(rs, "link_broken_at_s")
            lines.append(
                f"| {n} | {len(ok)}/{len(rs) - len(ok)} | {goal}/{len(ok)} | {len(broken)}/{len(ok)} "
                f"| {fmt_ms(mean_sd(broken))} | {fmt_ms(mean_sd(_num(rs, 'start_e2e_mbps')))} "
                f"| {fmt_ms(mean_sd(_num(rs, 'min_e2e_mbps')))} "
                f"| {fmt_ms(mean_sd(_num(rs, 'final_e2e_mbps')))} "
                f"| {fmt_ms(mean_sd(_num(rs, 'collisions')), 2)} |"
            )
            loaded = [s for s in (load_series(out, r) for r in ok) if s is not None]
            if loaded:
                series[n] = loaded
        failed = [r for r in cell_rows if r["status"] != "ok"]
        for r in failed:
            lines.append("")
            lines.append(
                f"- failed: `{r['run_dir']}` after {r['attempts']} attempt(s): {r['error']}"
            )
        if plots and series:
            png = Path("plots") / f"{_slug(label)}.png"
            plot_cell(out, f"{label}: end-to-end throughput, mean ± 1 sd", series, out / png)
            lines += ["", f"![{label}]({png.as_posix()})"]
        lines.append("")
    from relayd.sweep.robust import section

    lines += section(rows, set_keys, maps=out if plots else None)
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
