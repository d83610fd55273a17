"""bench/adaptive.py still runs: its scenario variants validate, its figures come out of a trace."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench import adaptive
from bench.run import BENCHES
from relayd.sim.scenario import builtin_names


def test_registered() -> None:
    assert BENCHES["adaptive"] == "bench.adaptive"


@pytest.mark.parametrize("name", builtin_names())
def test_every_shipped_scenario_takes_the_adaptive_policy(name: str) -> None:
    sc = adaptive.scenario_with(name, {"link_policy": "adaptive"})
    assert sc.control["link_policy"] == "adaptive"
    assert sc.control["threshold_b_min_dbm"] < sc.control["threshold_b_max_dbm"]


def test_metrics_from_a_trace() -> None:
    def rec(t: float, moving: bool, hops: list[float], broken: bool) -> dict[str, object]:
        return {
            "t": t,
            "leader": {"moving": moving},
            "hops": [{"mbps": m} for m in hops],
            "e2e_mbps": min(hops),
            "broken": broken,
            "relays": [{"x": 1.0, "threshold_b_dbm": -66.0}],
        }

    records = [
        rec(0.0, False, [27, 27], False),
        rec(0.1, True, [27, 12], False),
        rec(0.2, True, [27, 9], False),
        rec(0.3, True, [0, 9], True),
    ]
    m = adaptive.metrics(records, {"goal_reached": False, "collisions": 0}, 10.0)
    assert m["min_e2e_mbps"] == 0 and m["share_above_target"] == pytest.approx(1 / 3)
    assert m["down_s"] == pytest.approx(0.1) and m["final_thr_b"] == [-66.0]
    # Two records below target in a row; the rest of the walk delivers 12 with every hop at the target.
    assert m["below_target_s"] == pytest.approx(0.2) and m["longest_below_s"] == pytest.approx(0.2)
    assert m["min_e2e_at_target_mbps"] == 12


def test_parking_table_per_seed() -> None:
    def row(variant: str, seed: int, min_e2e: float) -> dict[str, object]:
        return {
            "scenario": "parking",
            "variant": variant,
            "seed": seed,
            "min_e2e_mbps": min_e2e,
            "min_e2e_at_target_mbps": 11.0,
            "share_above_target": 0.99,
            "below_target_s": 4.0,
            "longest_below_s": 2.5,
            "down_s": 0.0,
        }

    text = adaptive.parking_table([row("fixed", 1, 14.0), row("adaptive", 1, 2.9)], 2)
    assert "| 1 | 14.0 / 11.0 / 99.0% / 4.0, 2.5 / 0 | 2.9 / 11.0 / 99.0% / 4.0, 2.5 / 0 |" in text
    assert "| 2 | not run | not run |" in text


def test_calibration_part(tmp_path: Path) -> None:
    rows, _ = adaptive.calibration_rows(1, tmp_path)
    assert len(rows) == 2 and all(abs(r["n_err"]) < 1.5 for r in rows)
    assert adaptive.calibration_rows(1, tmp_path)[0] == rows  # cached
