"""PNG figures of a simulation run, like the paper's: the map with every path, RSSI^l and
bearing histories, end-to-end throughput over time, and 0/1/2-relay comparisons.

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


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_map(world: World, records: Sequence[dict[str, Any]], path: Path) -> None:
    """Walls, boxes, the command center, the leader's path and every relay's path, with
    markers every 20 s as in the paper's convoy figure."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 6))
    for w in world.walls:
        ax.plot([w.x1, w.x2], [w.y1, w.y2], color="saddlebrown" if w.material == "brick" else "grey",
                lw=2.5 if w.material in ("brick", "concrete") else 1.2)
    for b in world.boxes:
        ax.add_patch(plt.Rectangle((b.x_min, b.y_min), b.x_max - b.x_min, b.y_max - b.y_min,
                                   color="dimgray", alpha=0.7))
    ax.plot(*world.cc, marker="s", color="black", ms=9, ls="", label="command center")
    if records:
        lx = [r["leader"]["x"] for r in records]
        ly = [r["leader"]["y"] for r in records]
        ax.plot(lx, ly, color="red", lw=1.5, label="leader")
        ax.plot(lx[-1], ly[-1], marker="*", color="red", ms=14, ls="")
        colors = ["tab:blue", "tab:green", "tab:purple", "tab:orange", "tab:cyan"]
        for i, body in enumerate(world.relays):
            xs = [r["relays"][i]["x"] for r in records]
            ys = [r["relays"][i]["y"] for r in records]
            c = colors[i % len(colors)]
            ax.plot(xs, ys, color=c, lw=1.5, label=body.name)
            ax.plot(xs[-1], ys[-1], marker="o", color=c, ms=9, ls="")
        marks = []
        next_mark = 0.0
        for r in records:
            if r["t"] >= next_mark:
                marks.append(r)
                next_mark += 20.0
        for r in marks:
            ax.plot(r["leader"]["x"], r["leader"]["y"], marker="o", mfc="white", mec="red", ms=5, ls="")
            for rel in r["relays"]:
                ax.plot(rel["x"], rel["y"], marker="o", mfc="white", mec="black", ms=5, ls="")
    gx, gy = world.leader_script.goal
    ax.plot(gx, gy, marker="o", mfc="none", mec="red", ms=12, ls="", label="goal")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{world.scenario.name}: paths (circles every 20 s)")
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_rssi_bearing(records: Sequence[dict[str, Any]], path: Path) -> None:
    """Per relay: RSSI^l and RSSI^b over time, and the estimated vs true bearing."""
    plt = _plt()
    n = len(records[0]["relays"]) if records else 0
    fig, axes = plt.subplots(max(1, n), 2, figsize=(11, 3.2 * max(1, n)), squeeze=False)
    t = [r["t"] for r in records]
    for i in range(n):
        name = records[0]["relays"][i]["name"]
        a1, a2 = axes[i][0], axes[i][1]
        a1.plot(t, [r["relays"][i]["rssi_l_dbm"] for r in records], label="RSSI^l")
        a1.plot(t, [r["relays"][i]["rssi_b_dbm"] for r in records], label="RSSI^b", alpha=0.8)
        a1.set_ylabel("dBm")
        a1.set_title(f"{name}: RSSI")
        a1.legend(fontsize=8)
        a1.grid(alpha=0.3)
        a2.plot(t, [r["relays"][i]["bearing_deg"] for r in records], label="estimated")
        true = [r["relays"][i]["true_bearing_deg"] for r in records]
        if any(v is not None for v in true):  # a recording from a robot has no ground truth
            a2.plot(t, true, label="true", alpha=0.7)
        a2.set_ylabel("deg")
        a2.set_title(f"{name}: bearing")
        a2.legend(fontsize=8)
        a2.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_paths(paths: Mapping[str, tuple[Sequence[float], Sequence[float]]], path: Path, title: str) -> None:
    """Paths in the plane (e.g. each robot's odometry), start and end marked, equal axes."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 6))
    for name, (xs, ys) in paths.items():
        line = ax.plot(xs, ys, lw=1.5, label=name)[0]
        if xs:
            ax.plot(xs[0], ys[0], marker="s", color=line.get_color(), ms=7, ls="")
            ax.plot(xs[-1], ys[-1], marker="o", color=line.get_color(), ms=9, ls="")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_throughput(runs: Sequence[tuple[str, Sequence[dict[str, Any]]]], path: Path, title: str) -> None:
    """End-to-end throughput over time; several runs (e.g. 0/1/2 relays) on one axis."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 4))
    for label, records in runs:
        ax.plot([r["t"] for r in records], [r["e2e_mbps"] for r in records], label=label)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("end-to-end throughput (Mbps)")
    ax.set_ylim(bottom=0)
    ax.set_title(title)
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_run_plots(world: World, records: Sequence[dict[str, Any]], out: Path) -> list[Path]:
    """The standard figures of one run into `out`; returns the files written."""
    out.mkdir(parents=True, exist_ok=True)
    files = [out / "map.png", out / "throughput.png"]
    plot_map(world, records, files[0])
    plot_throughput([(f"{len(world.relays)} relay(s)", records)], files[1],
                    f"{world.scenario.name}: end-to-end throughput")
    if world.relays:
        files.append(out / "rssi_bearing.png")
        plot_rssi_bearing(records, files[-1])
    return files
