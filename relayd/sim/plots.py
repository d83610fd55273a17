"""PNG figures of a simulation run, like the paper's: the map with every path, RSSI^l and
bearing histories, end-to-end throughput over time, 0/1/2-relay comparisons, and the
sweeps' mean-and-band throughput plots.

matplotlib is optional (the `sim` extra): `available()` says whether it imports, and
every function here is only called when it does. The Agg backend is used so nothing
needs a display.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from relayd.sim.world import World


def available() -> bool:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot
    except ImportError:
        return False
    return True


def pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


#: Shading of a relay's drive state (the daemon's DriveState) behind its time plots.
STATE_COLORS: dict[str, str] = {
    "driving": "#c7e9c0",
    "stopped": "#fdd0a2",
    "avoiding": "#fcbba1",
    "leader_lost": "#d9d9d9",
    "fault": "#bcbddc",
}
#: Hatching of the stop reasons that matter for a relay chain (the link rule's two halves).
REASON_HATCH: dict[str, str] = {"leader_near": "//", "rear_weak": "\\\\"}
#: Where map legends go: outside the axes, right of them, so no legend covers a wall.
LEGEND_OUTSIDE: dict[str, Any] = {
    "loc": "upper left",
    "bbox_to_anchor": (1.02, 1.0),
    "borderaxespad": 0.0,
}


#: Time labels on the map closer than this share of its extent are not both drawn.
LABEL_SEPARATION = 0.025
#: A path plot shows at least this much floor both ways (m).
MIN_PATH_SPAN_M = 3.0


def save(fig: Any, path: Path, **kw: Any) -> None:
    """Every figure's one way out (tests replace it to look at the figure)."""
    import matplotlib.pyplot as plt

    try:
        fig.savefig(path, **kw)
    finally:
        plt.close(fig)


def marks_every(records: Sequence[dict[str, Any]], every_s: float = 20.0) -> list[dict[str, Any]]:
    """The first record at or after each multiple of `every_s` (the paper's 20 s circles)."""
    out = []
    nxt = 0.0
    for r in records:
        if r["t"] >= nxt:
            out.append(r)
            nxt = (int(r["t"] // every_s) + 1) * every_s
    return out


def spans(records: Sequence[dict[str, Any]], i: int, key: str) -> list[tuple[float, float, str]]:
    """Consecutive runs of relay i's `key` (state or reason): (t_start, t_end, value)."""
    out: list[tuple[float, float, str]] = []
    for r in records:
        v = str(r["relays"][i][key])
        t = float(r["t"])
        if out and out[-1][2] == v:
            out[-1] = (out[-1][0], t, v)
        else:
            if out:
                out[-1] = (out[-1][0], t, out[-1][2])
            out.append((t, t, v))
    return out


def relay_thresholds(world: World, i: int) -> tuple[float, float]:
    """Relay i's threshold_l and threshold_b (dBm): the scenario's [control], its own
    overrides, else the daemon's defaults."""
    from relayd.config.model import ControlSettings

    control = dict(world.scenario.control)
    control.update(world.scenario.relay[i].control)
    c = ControlSettings.model_validate(control)
    return float(c.threshold_l_dbm), float(c.threshold_b_dbm)


RELAY_COLORS = ("tab:blue", "tab:green", "tab:purple", "tab:orange", "tab:cyan")


def plot_map(world: World, records: Sequence[dict[str, Any]], path: Path) -> None:
    """Walls, boxes, the command center, the leader's path and every relay's path, with
    a filled start marker, circles every 20 s labelled with their time (as in the paper's
    convoy figure) and the goal; the legend sits outside the map."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9.5, 6))
    for w in world.walls:
        ax.plot(
            [w.x1, w.x2],
            [w.y1, w.y2],
            color="saddlebrown" if w.material == "brick" else "grey",
            lw=2.5 if w.material in ("brick", "concrete") else 1.2,
        )
    for b in world.boxes:
        ax.add_patch(
            plt.Rectangle(
                (b.x_min, b.y_min), b.x_max - b.x_min, b.y_max - b.y_min, color="dimgray", alpha=0.7
            )
        )
    if world.points:
        # A map's scan points (relayd/sim/mapscenario.py), drawn only when there are any.
        ax.plot(
            [p[0] for p in world.points],
            [p[1] for p in world.points],
            ls="",
            marker=".",
            ms=1.5,
            color="dimgray",
        )
    ax.plot(*world.cc, marker="s", color="black", ms=9, ls="", label="command center")
    route = world.scenario.leader.waypoints
    if len(route) > 1:
        ax.plot(
            [w.x for w in route],
            [w.y for w in route],
            color="red",
            lw=1.0,
            ls="--",
            alpha=0.5,
            label="leader's route (planned)",
        )
    if not records:  # the world alone: where the convoy starts
        for i, body in enumerate(world.relays):
            ax.plot(body.x_m, body.y_m, marker="o", color=RELAY_COLORS[i % 5], ms=7, ls="")
    if records:
        lx = [r["leader"]["x"] for r in records]
        ly = [r["leader"]["y"] for r in records]
        ax.plot(lx, ly, color="red", lw=1.5, label="leader")
        ax.plot(lx[0], ly[0], marker="o", color="red", ms=8, ls="", label="start")
        ax.plot(lx[-1], ly[-1], marker="*", color="red", ms=14, ls="")
        for i, body in enumerate(world.relays):
            xs = [r["relays"][i]["x"] for r in records]
            ys = [r["relays"][i]["y"] for r in records]
            c = RELAY_COLORS[i % len(RELAY_COLORS)]
            ax.plot(xs, ys, color=c, lw=1.5, label=body.name)
            ax.plot(xs[0], ys[0], marker="o", color=c, ms=8, ls="")
            ax.plot(xs[-1], ys[-1], marker="D", color=c, ms=7, ls="")
            # Pursuit "trail": where this relay estimated its leader (the sim's
            # odometry starts at the body's world pose, so its frame is the world's).
            est = [
                t["leader_xy_m"]
                for r in records
                if (t := r["relays"][i].get("trail")) is not None and t["leader_xy_m"] is not None
            ]
            if est:
                ax.plot(
                    [p[0] for p in est],
                    [p[1] for p in est],
                    color=c,
                    lw=0.8,
                    ls=":",
                    label=f"{body.name}'s leader estimate",
                )
        # A body standing still gets one label (its first time there), not a pile of them,
        # and no label is drawn on top of another body's ("20 s 20 s" once overlapped).
        last_labelled: dict[int, tuple[float, float]] = {}
        placed: list[tuple[float, float]] = []
        xs_all = [w.x1 for w in world.walls] + [w.x2 for w in world.walls] + lx
        ys_all = [w.y1 for w in world.walls] + [w.y2 for w in world.walls] + ly
        sep = LABEL_SEPARATION * max(max(xs_all) - min(xs_all), max(ys_all) - min(ys_all), 1.0)
        for r in marks_every(records):
            if r["t"] == 0:
                continue
            label = f"{r['t']:.0f} s"
            bodies = [(-1, r["leader"]["x"], r["leader"]["y"])] + [
                (i, rel["x"], rel["y"]) for i, rel in enumerate(r["relays"])
            ]
            for k, x, y in bodies:
                ax.plot(x, y, marker="o", mfc="white", mec="red" if k < 0 else "black", ms=5, ls="")
                prev = last_labelled.get(k)
                if prev is not None and abs(prev[0] - x) + abs(prev[1] - y) < 0.5:
                    continue
                last_labelled[k] = (x, y)
                if any(abs(px - x) < 2 * sep and abs(py - y) < sep for px, py in placed):
                    continue  # a label is there already: the circle alone says enough
                placed.append((x, y))
                ax.annotate(
                    label,
                    (x, y),
                    xytext=(4, 4) if k < 0 else (4, -8),
                    textcoords="offset points",
                    fontsize=6,
                    color="red" if k < 0 else "dimgrey",
                )
    gx, gy = world.leader_script.goal
    ax.plot(gx, gy, marker="o", mfc="none", mec="red", ms=12, ls="", label="goal")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{world.scenario.name}: paths (filled: start, circles every 20 s, diamonds: end)")
    ax.legend(fontsize=8, **LEGEND_OUTSIDE)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save(fig, path, dpi=110, bbox_inches="tight")


def _shade(ax: Any, records: Sequence[dict[str, Any]], i: int) -> None:
    """Drive states as coloured spans, the link rule's stop reasons hatched on top."""
    for t0, t1, state in spans(records, i, "state"):
        ax.axvspan(t0, t1, color=STATE_COLORS.get(state, "white"), alpha=0.5, lw=0)
    for t0, t1, reason in spans(records, i, "reason"):
        hatch = REASON_HATCH.get(reason)
        if hatch:
            ax.axvspan(t0, t1, facecolor="none", edgecolor="grey", hatch=hatch, lw=0, alpha=0.5)


def _shade_legend(fig: Any, rows: int) -> None:
    """The drive states' key, once for the figure, under the panels: a legend hung off one
    axes once widened the figure's gutter and sat small and far below."""
    import matplotlib.patches as mpatches

    handles = [mpatches.Patch(color=c, alpha=0.5, label=s) for s, c in STATE_COLORS.items()]
    handles += [
        mpatches.Patch(facecolor="none", edgecolor="grey", hatch=h, label=f"stopped: {r}")
        for r, h in REASON_HATCH.items()
    ]
    bottom = 0.5 / (3.4 * rows)  # half an inch, whatever the figure's height
    fig.tight_layout(rect=(0, bottom, 1, 1))
    fig.legend(handles=handles, fontsize=9, ncol=4, loc="lower center", frameon=False)


def plot_rssi_bearing(
    records: Sequence[dict[str, Any]],
    path: Path,
    thresholds: Sequence[tuple[float, float]] | None = None,
) -> None:
    """Per relay: RSSI$^l$ and RSSI$^b$ over time with the thresholds, and the estimated
    vs true bearing; the relay's drive state shaded behind both, its stop reason hatched."""
    plt = pyplot()
    n = len(records[0]["relays"]) if records else 0
    fig, axes = plt.subplots(max(1, n), 2, figsize=(11, 3.4 * max(1, n)), squeeze=False)
    t = [r["t"] for r in records]
    for i in range(n):
        name = records[0]["relays"][i]["name"]
        a1, a2 = axes[i][0], axes[i][1]
        _shade(a1, records, i)
        _shade(a2, records, i)
        a1.plot(t, [r["relays"][i]["rssi_l_dbm"] for r in records], label=r"RSSI$^l$")
        a1.plot(t, [r["relays"][i]["rssi_b_dbm"] for r in records], label=r"RSSI$^b$", alpha=0.8)
        if thresholds is not None and i < len(thresholds):
            th_l, th_b = thresholds[i]
            a1.axhline(
                th_l, color="tab:blue", ls="--", lw=0.9, label=rf"Threshold$_l$ {th_l:g} dBm"
            )
            a1.axhline(
                th_b, color="tab:orange", ls="--", lw=0.9, label=rf"Threshold$_b$ {th_b:g} dBm"
            )
            lo, hi = a1.get_ylim()
            a1.set_ylim(min(lo, th_l - 3, th_b - 3), max(hi, th_l + 3, th_b + 3))
        a1.set_ylabel("dBm")
        a1.set_title(f"{name}: RSSI")
        a1.legend(fontsize=7, loc="lower left")
        a1.grid(alpha=0.3)
        a2.plot(t, [r["relays"][i]["bearing_deg"] for r in records], label="estimated")
        true = [r["relays"][i]["true_bearing_deg"] for r in records]
        if any(v is not None for v in true):  # a recording from a robot has no ground truth
            a2.plot(t, true, label="true", alpha=0.7)
        a2.set_ylabel("deg")
        a2.set_title(f"{name}: bearing")
        a2.legend(fontsize=7, loc="lower left")
        a2.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    if n:
        _shade_legend(fig, n)
    else:
        fig.tight_layout()
    save(fig, path, dpi=100, bbox_inches="tight")


def plot_paths(
    paths: Mapping[str, tuple[Sequence[float], Sequence[float]]], path: Path, title: str
) -> None:
    """Paths in the plane (e.g. each robot's odometry), start and end marked, equal axes
    at least MIN_PATH_SPAN_M wide both ways (a 1.7 m path was once a strip), the legend
    beside the plot."""
    from matplotlib.ticker import MaxNLocator

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 6))
    xs_all: list[float] = []
    ys_all: list[float] = []
    for name, (xs, ys) in paths.items():
        line = ax.plot(xs, ys, lw=1.5, label=name)[0]
        if xs:
            ax.plot(xs[0], ys[0], marker="s", color=line.get_color(), ms=7, ls="", label="start")
            ax.plot(xs[-1], ys[-1], marker="o", color=line.get_color(), ms=9, ls="", label="end")
        xs_all += list(xs)
        ys_all += list(ys)
    if xs_all:
        half = max(max(xs_all) - min(xs_all), max(ys_all) - min(ys_all), MIN_PATH_SPAN_M) * 0.55
        cx, cy = (max(xs_all) + min(xs_all)) / 2, (max(ys_all) + min(ys_all)) / 2
        ax.set_xlim(cx - half, cx + half)
        ax.set_ylim(cy - half, cy + half)
    ax.set_aspect("equal", adjustable="box")
    ax.xaxis.set_major_locator(MaxNLocator(6))
    ax.yaxis.set_major_locator(MaxNLocator(6))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title)
    ax.legend(fontsize=8, **LEGEND_OUTSIDE)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save(fig, path, dpi=110, bbox_inches="tight")


def write_run_plots(world: World, records: Sequence[dict[str, Any]], out: Path) -> list[Path]:
    """The standard figures of one run into `out`; returns the files written."""
    from relayd.sim.plots_throughput import plot_throughput

    out.mkdir(parents=True, exist_ok=True)
    files = [out / "map.png", out / "throughput.png"]
    plot_map(world, records, files[0])
    plot_throughput(
        [(f"{len(world.relays)} relay(s)", records)],
        files[1],
        f"{world.scenario.name}: end-to-end throughput",
    )
    if world.relays:
        files.append(out / "rssi_bearing.png")
        plot_rssi_bearing(
            records, files[-1], [relay_thresholds(world, i) for i in range(len(world.relays))]
        )
    return files
