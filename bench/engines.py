"""The same world on two engines: one ARIA map and route on relayd's own world and on MobileSim.

Runs `relayd sim --map MAP --scenario SCENARIO` with `--engine builtin` (virtual time)
and `--engine mobilesim` (real time; RELAYD_MOBILESIM or --mobilesim names the program),
then prints, side by side, each relay's travelled distance, the time it passed each
corner of the leader's route (first within CORNER_M of it), its minimum clearance from
the map's wall lines (robot centre to line), its time in avoidance, its stall episodes,
its final gap and reason, and the wall time of each run. With `--door X Y` (a doorway's
middle, bench/doorways.py) also each relay's least distance to it and the second the
leader came within 0.3 m of it; with `--markdown` the table as Markdown, dated, as
bench/RESULTS.md keeps it.

    python bench/engines.py --map AMROffice.map --scenario bench/amroffice.toml
    python bench/engines.py --map AMROffice.map --scenario bench/amroffice_door.toml \
        --door -4.52 -2.75 --runs 3 --markdown
    python bench/engines.py --map tests/fixtures/maps/corner.map --runs 3 --keep runs/
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import tempfile
import time
import tomllib
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from relayd.sim.ariamap import load_map
from relayd.sim.mapscenario import with_map
from relayd.sim.scenario import parse_scenario

#: A relay has passed a corner once its centre comes this close to it (m).
CORNER_M = 1.0
#: The leader has gone through the door once its centre comes this close to its middle (m).
DOOR_M = 0.3


def _seg_dist(px: float, py: float, x1: float, y1: float, x2: float, y2: float) -> float:
    ex, ey = x2 - x1, y2 - y1
    n2 = ex * ex + ey * ey
    u = 0.0 if n2 == 0 else max(0.0, min(1.0, ((px - x1) * ex + (py - y1) * ey) / n2))
    return math.hypot(px - x1 - u * ex, py - y1 - u * ey)


def run_engine(engine: str, args: argparse.Namespace, out: Path) -> tuple[float, float, int]:
    """Wall s, CPU s (the run and its children: MobileSim and Xvfb too), exit status."""
    cmd = [sys.executable, "-m", "relayd", "sim", "--engine", engine, "--map", args.map,
           "--no-plots", "--speed", "max", "--out", str(out)]  # fmt: skip
    if args.scenario:
        cmd += ["--scenario", args.scenario]
    if args.mobilesim:
        cmd += ["--mobilesim", args.mobilesim]
    t0 = time.monotonic()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        print(proc.stderr[-2000:], file=sys.stderr)
    cpu_s = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return time.monotonic() - t0, cpu_s, proc.returncode


def metrics(
    out: Path,
    lines: list[tuple[float, float, float, float]],
    corners: list[Any],
    door: tuple[float, float] | None = None,
) -> list[dict[str, Any]]:
    recs = [json.loads(x) for x in (out / "trace.jsonl").read_text().splitlines()]
    summary = json.loads((out / "summary.json").read_text())
    leader_door_s = None
    if door is not None:
        leader_door_s = next(
            (
                rec["t"]
                for rec in recs
                if math.hypot(rec["leader"]["x"] - door[0], rec["leader"]["y"] - door[1]) < DOOR_M
            ),
            None,
        )
    rows = []
    for k, f in enumerate(summary["followers"]):
        clear = math.inf
        avoid_s = 0.0
        passed: list[float | None] = [None] * len(corners)
        stalls = 0
        prev_t = None
        was_stalled = False
        door_m = math.inf
        for rec in recs:
            r = rec["relays"][k]
            if door is not None:
                door_m = min(door_m, math.hypot(r["x"] - door[0], r["y"] - door[1]))
            near = [ln for ln in lines if min(ln[0], ln[2]) - 2 < r["x"] < max(ln[0], ln[2]) + 2
                    and min(ln[1], ln[3]) - 2 < r["y"] < max(ln[1], ln[3]) + 2]  # fmt: skip
            for ln in near:
                clear = min(clear, _seg_dist(r["x"], r["y"], *ln))
            if prev_t is not None and r["state"] == "avoiding":
                avoid_s += rec["t"] - prev_t
            prev_t = rec["t"]
            for c, (cx, cy) in enumerate(corners):
                if passed[c] is None and math.hypot(r["x"] - cx, r["y"] - cy) < CORNER_M:
                    passed[c] = rec["t"]
            st = bool(rec.get("stalled", [False] * (k + 1))[k])
            stalls += st and not was_stalled
            was_stalled = st
        rows.append({
            "name": f["name"], "travelled_m": f["travelled_m"], "corners_s": passed,
            "min_clearance_m": clear, "avoiding_s": avoid_s, "stalls": stalls,
            "collisions": f["collisions"], "final_gap_m": f["final_gap_m"],
            "reason": f["stopped_reason"], "goal": summary["goal_reached"],
            "on_rule": f.get("on_link_rule"), "door_m": door_m, "leader_door_s": leader_door_s,
        })  # fmt: skip
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--map", required=True)
    ap.add_argument("--scenario", default=None, help="scenario TOML (default: the map alone)")
    ap.add_argument("--mobilesim", default=None)
    ap.add_argument("--runs", type=int, default=1, help="MobileSim runs (real time, vary)")
    ap.add_argument("--keep", default=None, help="keep each run's outputs under this folder")
    ap.add_argument("--door", type=float, nargs=2, metavar=("X", "Y"), help="a doorway's middle")
    ap.add_argument("--markdown", action="store_true", help="the table as Markdown, dated")
    args = ap.parse_args()
    door = (args.door[0], args.door[1]) if args.door else None
    started = datetime.now(UTC)
    doc: dict[str, Any] = {}
    if args.scenario:
        doc = tomllib.loads(Path(args.scenario).read_text())
        doc.pop("map", None)
    sc = parse_scenario(with_map(doc, args.map))
    corners = [(w.x, w.y) for w in sc.leader.waypoints[1:-1]]
    lines = [(ln.x1, ln.y1, ln.x2, ln.y2) for ln in load_map(args.map).lines]
    print(f"map {args.map}: route corners {[(round(x, 2), round(y, 2)) for x, y in corners]}")
    with tempfile.TemporaryDirectory(prefix="relayd-engines-") as scratch:
        tmp = args.keep or scratch
        results = []
        for engine, n in (("builtin", 1), ("mobilesim", args.runs)):
            for i in range(n):
                out = Path(tmp) / f"{engine}-{i}"
                wall_s, cpu_s, rc = run_engine(engine, args, out)
                if rc != 0:
                    print(f"{engine} run {i}: exit {rc}")
                    continue
                sim_s = json.loads((out / "summary.json").read_text())["sim_seconds"]
                print(f"{engine}#{i + 1}: {sim_s:.0f} s simulated, {wall_s:.0f} s wall,"
                      f" {cpu_s:.1f} s CPU ({cpu_s / sim_s:.3f} CPU s per simulated s)")  # fmt: skip
                results.append((f"{engine}#{i + 1}", wall_s, metrics(out, lines, corners, door)))
    if args.markdown:
        print_markdown(results, started, door is not None)
        return 0
    head = f"{'run':<12} {'wall s':>6} {'relay':<7} {'travel m':>8} {'corners s':<18} {'min clr m':>9} {'avoid s':>7} {'stalls':>6} {'gap m':>6}  reason / goal"
    print(head)
    print("-" * len(head))
    for name, wall_s, rows in results:
        for r in rows:
            cs = ",".join("-" if c is None else f"{c:.0f}" for c in r["corners_s"])
            print(f"{name:<12} {wall_s:>6.0f} {r['name']:<7} {r['travelled_m']:>8.2f} {cs:<18} "
                  f"{r['min_clearance_m']:>9.2f} {r['avoiding_s']:>7.1f} {r['stalls']:>6} "
                  f"{r['final_gap_m']:>6.2f}  {r['reason']} / {'yes' if r['goal'] else 'NO'}")  # fmt: skip
    return 0


def print_markdown(
    results: list[tuple[str, float, list[dict[str, Any]]]], started: datetime, door: bool
) -> None:
    """The table as bench/RESULTS.md keeps it, under the UTC time the runs began and ended."""
    ended = datetime.now(UTC)
    print(f"\nbench/engines.py, {started:%Y-%m-%d %H:%M}-{ended:%H:%M} UTC\n")
    cols = ["run", "wall s", "relay", "travel m", "corners s", "min clr m", "avoid s", "stalls"]
    cols += ["door m", "leader door s"] if door else []
    cols += ["gap m", "reason / on rule / goal"]
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for name, wall_s, rows in results:
        for r in rows:
            cs = ", ".join("-" if c is None else f"{c:.0f}" for c in r["corners_s"])
            cells = [name.replace("#", " "), f"{wall_s:.0f}", r["name"], f"{r['travelled_m']:.2f}",
                     cs, f"{r['min_clearance_m']:.2f}", f"{r['avoiding_s']:.1f}", str(r["stalls"])]  # fmt: skip
            if door:
                ld = r["leader_door_s"]
                cells += [f"{r['door_m']:.2f}", "-" if ld is None else f"{ld:.0f}"]
            rule = "yes" if r["on_rule"] else "NO"
            cells += [f"{r['final_gap_m']:.2f}",
                      f"{r['reason']} / {rule} / {'yes' if r['goal'] else 'NO'}"]  # fmt: skip
            print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    sys.exit(main())
