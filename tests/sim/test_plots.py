"""Plot helpers of relayd.sim.plots (markers, shading spans, thresholds) and the figures
they draw, and the paper-comparison verdicts of relayd.sweep.validation."""

from __future__ import annotations

from pathlib import Path

import pytest

from relayd.sim import plots, plots_throughput
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
    plots_throughput.plot_throughput_bands(
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


def _figures(monkeypatch: pytest.MonkeyPatch) -> list:
    """The figures the plot functions draw, kept open instead of saved."""
    kept: list = []
    monkeypatch.setattr(plots, "save", lambda fig, path, **kw: kept.append(fig))
    return kept


def _two_relays_together() -> list[dict]:
    recs = _recs(450)
    for r in recs:
        r["relays"].append({**r["relays"][0], "name": "relay2", "x": r["relays"][0]["x"] + 0.05})
    return recs


def test_map_time_labels_never_sit_on_each_other(monkeypatch: pytest.MonkeyPatch) -> None:
    """Two relays side by side once got '20 s 20 s' printed over each other."""
    pytest.importorskip("matplotlib")
    kept = _figures(monkeypatch)
    world = World(load_scenario("corridor").with_relays(2), seed=1)
    plots.plot_map(world, _two_relays_together(), Path("unused.png"))
    (fig,) = kept
    labels = [t for t in fig.axes[0].texts if t.get_text().endswith(" s")]
    fig.canvas.draw()
    boxes = [t.get_window_extent() for t in labels]
    assert labels
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            assert not a.overlaps(b), "two time labels overlap"


def test_rssi_bearing_has_its_key_under_the_panels_and_no_gutter(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    pytest.importorskip("matplotlib")
    kept = _figures(monkeypatch)
    plots.plot_rssi_bearing(_two_relays_together(), Path("unused.png"), [(-30, -40)] * 2)
    (fig,) = kept
    assert len(fig.legends) == 1 and fig.legends[0].get_texts()[0].get_fontsize() >= 9
    left, right = fig.axes[0].get_position(), fig.axes[1].get_position()
    assert right.x0 - left.x1 < 0.12, "a wide gutter between the two columns"


def test_a_short_path_is_drawn_on_a_readable_square(monkeypatch: pytest.MonkeyPatch) -> None:
    """A 1.7 m path was once squeezed into a strip, ticks overlapping, the legend on the title."""
    pytest.importorskip("matplotlib")
    kept = _figures(monkeypatch)
    xs = [0.01 * k for k in range(170)]
    plots.plot_paths({"relay1": (xs, [0.02 * x for x in xs])}, Path("unused.png"), "path")
    (fig,) = kept
    ax = fig.axes[0]
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert x1 - x0 >= plots.MIN_PATH_SPAN_M and y1 - y0 >= plots.MIN_PATH_SPAN_M
    assert len(ax.get_xticks()) <= 8
    fig.canvas.draw()
    legend = ax.get_legend().get_window_extent()
    assert legend.x0 >= ax.get_window_extent().x1, "the legend sits on the plot"
