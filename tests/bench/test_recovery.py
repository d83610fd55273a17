"""bench/recovery.py's arithmetic: which breaks count, the rate, the table (no simulation)."""

from __future__ import annotations

from typing import Any

from bench.recovery import aggregate, healed, results, table


def run(
    breaks: list[tuple[float, float | None]],
    *,
    end: float = 200.0,
    down: float = 0.0,
    collisions: int = 0,
    goal: bool = False,
    episodes: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    return {
        "sim_seconds": end,
        "downtime_s": down,
        "collisions": collisions,
        "goal_reached": goal,
        "link_breaks": [
            {"start_s": a, "end_s": b, "duration_s": None if b is None else b - a}
            for a, b in breaks
        ],
        "followers": [{"recovery_episodes": episodes or []}],
    }


def test_breaks_healed_within_60_s_and_late_open_breaks_censored() -> None:
    s = run([(10.0, 30.0), (40.0, 120.0), (130.0, None), (170.0, None)])
    # 20 s: healed; 80 s: not; open since 130 (70 s before the end): not; open since 170: censored.
    assert healed(s) == (3, 1, 1)


def test_aggregate_and_table() -> None:
    ep = {"kind": "rear", "start_s": 1.0, "end_s": 5.0, "outcome": "restored", "distance_m": 1.5}
    on = aggregate([run([(10.0, 20.0)], down=10.0, episodes=[ep]), run([], down=0.0)])
    off = aggregate([run([(10.0, None)], down=190.0), run([], down=0.0, goal=True)])
    assert (
        on["rate"] == 1.0
        and on["breaks"] == 1
        and on["down_median_s"] == 5.0
        and on["down_worst_s"] == 10.0
    )
    assert on["outcomes"] == {"restored": 1} and on["episode_m_max"] == 1.5
    assert off["rate"] == 0.0 and off["goal"] == 1
    rows = {"drift": {"off": off, "on": on}, "corridor": {"off": off, "on": off}}
    text = table(rows)
    assert (
        "| drift | on | 2 | 1 (0) | 100 % (1/1) | 5.0 s | 10.0 s | 0/2 | 0 | 1 (restored 1) | 1.5 m |"
        in text
    )
    res = {r.figure: r for r in results(rows, ["drift"])}
    assert res["drift: breaks healed within 60 s, recovery on"].passed is True
    assert res["corridor: unchanged with recovery on"].passed is True
    assert res["drift: collisions, recovery on"].passed is True
