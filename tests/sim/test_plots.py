"""Plot helpers of relayd.sim.plots (markers, shading spans, thresholds) and the figures
they draw, and the paper-comparison verdicts of relayd.sweep.validation."""

from __future__ import annotations

from pathlib import Path

import pytest

from relayd.sim import plots
from relayd.sim.scenario import load_scenario
from relayd.sim.world import World
from relayd.sweep.validation import FIGURES, Check, first_below, verdict, window_mean


def _recs(n: int = 450) -> list[dict]:
    out = []
    for k in range(n):
        t = round(0.1 * k, 2)
        state = "stopped" if t < 10 else "driving" if t < 30 else "stopped"
        reason = "leader_near" if t < 10 else "driving" if t < 30 else "rear_weak"
        out.append(
            {
                "t": t,
                "leader": {"x": 3.5 + 0.2 * t, "y": 0.0, "moving": True},
                "e2e_mbps": 20.0,
                "broken": False,
                "relays": [
                    {
                        "name": "relay1",
                        "x": 2.0 + (0.1 * t if t > 10 else 1.0),
                        "y": 0.0,
                        "state": state,
                        "reason": reason,
                        "rssi_l_dbm": -30.0,
                        "rssi_b_dbm": -35.0,
                        "bearing_deg": 1.0,
                        "true_bearing_deg": 0.0,
                    }
                ],
            }
        )
    return out


def test_marks_every_20_s_and_spans_merge_runs() -> None:
    recs = _recs()
    assert [r["t"] for r in plots.marks_every(recs)] == [0.0, 20.0, 40.0]
    assert [(round(a), round(b), v) for a, b, v in plots.spans(recs, 0, "state")] == [
        (0, 10, "stopped"),
        (10, 30, "driving"),
        (30, 45, "stopped"),
    ]
    assert plots.spans(recs, 0, "reason")[-1][2] == "rear_weak"


def test_relay_thresholds_from_the_scenario_and_the_defaults() -> None:
    corridor = World(load_scenario("corridor").with_relays(2), seed=1)
    assert plots.relay_thresholds(corridor, 0) == (-30.0, -40.0)
    convoy = World(load_scenario("convoy").with_relays(1), seed=1)
    assert plots.relay_thresholds(convoy, 0) == (-30.0, -60.0)


def test_figures_are_written(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    world = World(load_scenario("corridor").with_relays(1), seed=1)
    files = plots.write_run_plots(world, _recs(), tmp_path)
    assert [f.name for f in files] == ["map.png", "throughput.png", "rssi_bearing.png"]
    assert all(f.stat().st_size > 10_000 for f in files)
    plots.plot_throughput_bands(
        [("0 relays", [0.0, 1.0], [30.0, 20.0], [1.0, 2.0])],
        tmp_path / "b.png",
        "t",
        marks=[(0.5, "corner 1")],
        hlines=[(5.0, "5 Mbps")],
    )
    assert (tmp_path / "b.png").exists()


def test_verdicts() -> None:
    point = Check("x", 0, "~280", "point", (280,), lambda r, s: None)
    assert verdict(point, (300.0, 10.0), 10, None) == ("7%", "within 25 %")
    assert verdict(point, (100.0, 10.0), 10, None)[1] == "OFF"
    rng = Check("x", 2, "20-25", "range", (20, 25), lambda r, s: None)
    assert verdict(rng, (23.0, 1.0), 10, None) == ("0%", "within 25 %")
    assert verdict(rng, (15.0, 1.0), 10, None) == ("25%", "within 25 %")
    assert verdict(rng, (14.0, 1.0), 10, None)[1] == "OFF"
    below = Check("x", 0, "< 5", "max", (5,), lambda r, s: None)
    assert (
        verdict(below, (3.0, 1.0), 10, None)[1] == "met"
        and verdict(below, (6.0, 1.0), 10, None)[1] == "OFF"
    )
    assert verdict(point, None, 0, None) == ("-", "no data")


def test_series_windows() -> None:
    s = {"t": [0.0, 1.0, 2.0, 3.0], "e2e_mbps": [30.0, 10.0, 4.0, 0.0]}
    assert window_mean(s, 0, 2) == 20.0
    assert first_below(s, 5.0) == 2.0
    assert first_below(s, 0.0) is None
    assert set(FIGURES) == {"6-17", "6-21"}
