"""The paper's statements about its throughput figures (6-17 indoors, 6-21 outdoors), each
with how to measure it on a sweep's run (relayd/sweep/validation.py sets them against it).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

Series = dict[str, list[float]]


@dataclass(frozen=True, slots=True)
class Check:
    """One paper figure's statement: its value (point, range or bound) and how to measure it."""

    what: str
    relays: int
    paper: str
    kind: str  # "point" | "range" | "max" | "min" | "order" | "count"
    target: tuple[float, ...]
    measure: Callable[[dict[str, Any], Series], float | None]


def _f(row: dict[str, Any], key: str) -> float | None:
    v = row.get(key)
    return None if v in ("", None) else float(v)


def window_mean(s: Series, t0: float, t1: float) -> float | None:
    vals = [e for t, e in zip(s["t"], s["e2e_mbps"], strict=True) if t0 <= t < t1]
    return sum(vals) / len(vals) if vals else None


def first_below(s: Series, mbps: float, after_s: float = 0.0) -> float | None:
    return next(
        (t for t, e in zip(s["t"], s["e2e_mbps"], strict=True) if t >= after_s and e < mbps), None
    )


def min_at(s: Series) -> float | None:
    """The first time the end-to-end throughput was at its lowest."""
    if not s["e2e_mbps"]:
        return None
    low = min(s["e2e_mbps"])
    return next(t for t, e in zip(s["t"], s["e2e_mbps"], strict=True) if e == low)


def leader_corner_s(scenario: str, k: int) -> float:
    """When the scenario's scripted leader reaches waypoint k (0 is where it starts; the
    shipped corridor and outdoor scenarios have their corners at 1 and 2)."""
    from relayd.sim.leader_script import LeaderScript
    from relayd.sim.scenario import load_scenario

    sc = load_scenario(scenario)
    wps = sc.leader.waypoints
    script = LeaderScript(
        [(w.x, w.y, w.pause_s) for w in wps], sc.leader.speed_m_s, sc.leader.start_s
    )
    t = sc.leader.start_s
    for a, b in itertools.pairwise(wps[: k + 1]):
        t += ((b.x - a.x) ** 2 + (b.y - a.y) ** 2) ** 0.5 / sc.leader.speed_m_s + a.pause_s
    return round(min(t, script.end_s), 1)


FIGURES: dict[str, tuple[str, str, list[Check]]] = {
    "6-17": (
        "corridor",
        "Indoor corridor, Knoy Hall (fig. 6-17)",
        [
            Check(
                "first corner passed (s)",
                0,
                "80-100",
                "range",
                (80, 100),
                lambda r, s: leader_corner_s("corridor", 1),
            ),
            Check(
                "second corner passed (s)",
                0,
                "180-200",
                "range",
                (180, 200),
                lambda r, s: leader_corner_s("corridor", 2),
            ),
            Check(
                "start e2e, first 20 s (Mbps)",
                0,
                "highest",
                "order",
                (0,),
                lambda r, s: _f(r, "start_e2e_mbps"),
            ),
            Check(
                "start e2e, first 20 s (Mbps)",
                1,
                "between",
                "order",
                (1,),
                lambda r, s: _f(r, "start_e2e_mbps"),
            ),
            Check(
                "start e2e, first 20 s (Mbps)",
                2,
                "lowest",
                "order",
                (2,),
                lambda r, s: _f(r, "start_e2e_mbps"),
            ),
            Check(
                "link broken at (s)",
                0,
                "~280",
                "point",
                (280,),
                lambda r, s: _f(r, "link_broken_at_s"),
            ),
            Check(
                "first below 5 Mbps at (s), before the break",
                0,
                "< 280",
                "max",
                (280,),
                lambda r, s: first_below(s, 5.0),
            ),
            Check(
                "runs whose link broke before the goal",
                0,
                "yes",
                "count",
                (1,),
                lambda r, s: 0.0 if str(r["goal_reached"]) == "True" else 1.0,
            ),
            Check("min e2e (Mbps)", 1, ">= 5", "min", (5,), lambda r, s: _f(r, "min_e2e_mbps")),
            Check(
                "final e2e (Mbps)", 1, "~10", "point", (10,), lambda r, s: _f(r, "final_e2e_mbps")
            ),
            Check(
                "e2e after the corners, t >= 200 s (Mbps)",
                2,
                "20-25",
                "range",
                (20, 25),
                lambda r, s: window_mean(s, 200, 1e9),
            ),
            Check(
                "final e2e (Mbps)", 2, "~20", "point", (20,), lambda r, s: _f(r, "final_e2e_mbps")
            ),
            Check(
                "min e2e, whole walk (Mbps)",
                2,
                "very stable",
                "info",
                (),
                lambda r, s: _f(r, "min_e2e_mbps"),
            ),
            Check(
                "when the minimum first came (s)",
                2,
                "-",
                "info",
                (),
                lambda r, s: min_at(s),
            ),
            Check(
                "runs with the link held to the goal",
                1,
                "yes",
                "count",
                (1,),
                lambda r, s: 1.0 if str(r["goal_reached"]) == "True" else 0.0,
            ),
            Check(
                "runs with the link held to the goal",
                2,
                "yes",
                "count",
                (1,),
                lambda r, s: 1.0 if str(r["goal_reached"]) == "True" else 0.0,
            ),
        ],
    ),
    "6-21": (
        "outdoor",
        "Outdoor parking lot (fig. 6-21)",
        [
            Check(
                "start e2e, first 40 s (Mbps)",
                0,
                "highest",
                "order",
                (0,),
                lambda r, s: window_mean(s, 0, 40),
            ),
            Check(
                "start e2e, first 40 s (Mbps)",
                1,
                "between",
                "order",
                (1,),
                lambda r, s: window_mean(s, 0, 40),
            ),
            Check(
                "start e2e, first 40 s (Mbps)",
                2,
                "lowest",
                "order",
                (2,),
                lambda r, s: window_mean(s, 0, 40),
            ),
            Check(
                "first below 5 Mbps at (s)",
                0,
                "~280",
                "point",
                (280,),
                lambda r, s: first_below(s, 5.0),
            ),
            Check(
                "link broken at (s), after the drop below 5 Mbps",
                0,
                "> 280",
                "min",
                (280,),
                lambda r, s: _f(r, "link_broken_at_s"),
            ),
            Check(
                "runs whose link broke before the goal",
                0,
                "yes",
                "count",
                (1,),
                lambda r, s: 0.0 if str(r["goal_reached"]) == "True" else 1.0,
            ),
            Check(
                "distance walked when the link broke (m)",
                0,
                "almost 60",
                "point",
                (60,),
                lambda r, s: (
                    None
                    if _f(r, "link_broken_at_s") is None
                    else 0.2 * (float(r["link_broken_at_s"]) - 2.0)
                ),
            ),
            Check(
                "runs with the link held to the goal",
                1,
                "yes",
                "count",
                (1,),
                lambda r, s: 1.0 if str(r["goal_reached"]) == "True" else 0.0,
            ),
            Check(
                "final e2e (Mbps)", 2, "> 10", "min", (10,), lambda r, s: _f(r, "final_e2e_mbps")
            ),
            Check(
                "runs with the link held to the goal",
                2,
                "yes",
                "count",
                (1,),
                lambda r, s: 1.0 if str(r["goal_reached"]) == "True" else 0.0,
            ),
        ],
    ),
}
