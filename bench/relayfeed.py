"""A relay following a relay on its leader's own path (the leader feed, docs/CONTROL.md 7.1).

The world: a 5 m corridor east with a partition across it and a 1.6 m door in it, a corner north, a corner east. A person walks it; relay1 follows the
person (the estimated trail); relay2 follows relay1 with `control.pursuit = "trail"`,
so the simulator gives it relay1's GET /path as its `leader_url`. Measured: relay2's
distance to the path relay1 drove (RMS over the run, after it starts moving), with the
feed up all along, and with the feed cut halfway through (relay2 then finishes on its
estimated trail; the trace says why: `trail.feed` = "stale").

    python bench/relayfeed.py                    # seeds 1-3, feed up and cut
    python bench/relayfeed.py --seeds 5 --markdown
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: The world (an ordinary scenario document).
WORLD: dict[str, Any] = {
    "name": "relay-feed",
    "description": "a relay following a relay through a door and round two corners",
    "environment": "indoor",
    "duration_s": 130,
    "settle_after_goal_s": 90,
    "relays": 2,
    "command_center": {"x": -1.5, "y": 0.0},
    # The hop behind may fade further than the default's -60 dBm: the command center stays
    # at the start, and relay2 must get round both corners to show it follows the path.
    "control": {"threshold_b_dbm": -75.0},
    "leader": {
        "kind": "person",
        "speed_m_s": 0.35,
        "start_s": 2.0,
        "waypoints": [
            {"x": 4.5, "y": 0.0},
            {"x": 10.5, "y": 0.0},
            {"x": 10.5, "y": 8.0},
            {"x": 22.0, "y": 8.0},
        ],
    },
    "relay": [
        {"name": "relay1", "x": 2.0, "y": 0.0, "theta_deg": 0.0},
        {"name": "relay2", "x": 0.5, "y": 0.0, "theta_deg": 0.0},
    ],
    "walls": [
        # Outer side of corner 1, inner side of corner 2 (corridors 5-6.5 m wide).
        {"points": [[-3.0, -2.5], [14.0, -2.5], [14.0, 4.5], [26.0, 4.5]], "material": "light"},
        # Inner side of corner 1, outer side of corner 2.
        {"points": [[-3.0, 2.5], [8.0, 2.5], [8.0, 11.0], [26.0, 11.0]], "material": "light"},
        {"points": [[-3.0, -2.5], [-3.0, 2.5]], "material": "light"},
        {"points": [[26.0, 4.5], [26.0, 11.0]], "material": "light"},
        # The partition across the corridor at x = 6, its door at y -0.8..0.8.
        {"points": [[6.0, -2.5], [6.0, -0.8]], "material": "light"},
        {"points": [[6.0, 0.8], [6.0, 2.5]], "material": "light"},
    ],
}


def scenario(*, pursuit: str = "trail") -> Any:
    from bench.pursuit import calibrated
    from relayd.sim.scenario import parse_scenario

    sc = parse_scenario(WORLD)
    return sc.model_copy(update={"control": {**sc.control, **calibrated(sc), "pursuit": pursuit}})


@dataclass(frozen=True, slots=True)
class Outcome:
    seed: int
    cut_at_s: float | None
    rms_m: float
    rms_before_cut_m: float | None
    rms_after_cut_m: float | None
    max_m: float
    samples: int
    sources: dict[str, int]
    final_source: str
    final_feed: str | None
    final_reason: str
    collisions: int


def _dist_to_path(p: tuple[float, float], path: Sequence[tuple[float, float]]) -> float:
    if len(path) == 1:
        return math.dist(p, path[0])
    best = math.inf
    for a, b in itertools.pairwise(path):
        ax, ay = b[0] - a[0], b[1] - a[1]
        seg2 = ax * ax + ay * ay
        u = 0.0 if seg2 <= 1e-12 else ((p[0] - a[0]) * ax + (p[1] - a[1]) * ay) / seg2
        u = min(max(u, 0.0), 1.0)
        best = min(best, math.dist(p, (a[0] + u * ax, a[1] + u * ay)))
    return best


def path_errors(
    records: Sequence[dict[str, Any]], leader: int = 0, follower: int = 1, join_m: float = 0.3
) -> list[tuple[float, float]]:
    """(t, the follower's true distance to the path its leader truly drove until then), from
    the moment the follower first comes within `join_m` of it: it starts behind the leader's
    start, off its path, and drives onto it (the simulator's poses, not odometry)."""
    path: list[tuple[float, float]] = []
    joined = False
    out = []
    for r in records:
        lead, fol = r["relays"][leader], r["relays"][follower]
        xy = (lead["x"], lead["y"])
        if not path or math.dist(path[-1], xy) >= 0.05:
            path.append(xy)
        d = _dist_to_path((fol["x"], fol["y"]), path)
        joined = joined or d <= join_m
        if joined:
            out.append((r["t"], d))
    return out


def rms(values: Sequence[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values)) if values else math.nan


async def run(seed: int, cut_at_s: float | None, seconds: float | None = None) -> Outcome:
    """One run; with `cut_at_s`, relay2's feed dies at that simulated time."""
    from relayd.sim.runner import SimRunner

    runner = SimRunner(scenario(), speed=None, seed=seed, seconds=seconds)
    cut = {"done": False}

    def progress(rec: dict[str, Any]) -> None:
        if cut_at_s is not None and not cut["done"] and rec["t"] >= cut_at_s:
            feed = runner.relays[1].daemon.leader_feed
            assert feed is not None, "relay2 has no leader feed"
            feed.client.cut()  # type: ignore[attr-defined]
            cut["done"] = True

    runner.on_progress = progress
    result = await runner.run()
    errs = path_errors(result.records)
    after = [e for t, e in errs if cut_at_s is not None and t >= cut_at_s]
    before = [e for t, e in errs if cut_at_s is not None and t < cut_at_s]
    sources: dict[str, int] = {}
    for r in result.records:
        tr = r["relays"][1].get("trail") or {}
        src = str(tr.get("source"))
        sources[src] = sources.get(src, 0) + 1
    last = result.records[-1]["relays"][1]
    return Outcome(
        seed,
        cut_at_s,
        rms([e for _, e in errs]),
        rms(before) if cut_at_s is not None else None,
        rms(after) if cut_at_s is not None else None,
        max((e for _, e in errs), default=math.nan),
        len(errs),
        sources,
        str(last["trail"]["source"]),
        last["trail"].get("feed"),
        str(last["reason"]),
        int(last["collisions"]),
    )


def main(argv: Sequence[str] | None = None) -> int:
    from relayd.runtime import vtime

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="seeds 1..N")
    ap.add_argument("--cut-at", type=float, default=80.0, help="simulated s the feed dies at")
    ap.add_argument("--markdown", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    for seed in range(1, args.seeds + 1):
        for cut in (None, args.cut_at):
            o = vtime.run(run(seed, cut))
            rows.append(o)
            print(o, file=sys.stderr)
    print(
        "| seed | feed | RMS to relay1's path | before the cut | after the cut | max "
        "| relay2 ends on (trail.source) | trail.feed | reason | collisions |"
    )
    print("|" + "---|" * 10)
    for o in rows:
        feed = "up" if o.cut_at_s is None else f"cut at {o.cut_at_s:g} s"
        before = "" if o.rms_before_cut_m is None else f"{o.rms_before_cut_m:.3f} m"
        after = "" if o.rms_after_cut_m is None else f"{o.rms_after_cut_m:.2f} m"
        print(
            f"| {o.seed} | {feed} | {o.rms_m:.3f} m | {before} | {after} | {o.max_m:.2f} m | "
            f"{o.final_source} | {o.final_feed} | {o.final_reason} | {o.collisions} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
