"""The sweep report's robustness section: Wilson interval, categories, repro commands."""

from __future__ import annotations

import pytest

from relayd.sweep.robust import category, kind, section, wilson


def test_wilson_matches_hand_values() -> None:
    lo, hi = wilson(6, 6)
    assert lo == pytest.approx(0.6097, abs=1e-4) and hi == pytest.approx(1.0)
    lo, hi = wilson(95, 100)
    assert lo == pytest.approx(0.8882, abs=1e-3) and hi == pytest.approx(0.9785, abs=1e-3)


def _row(**kw: object) -> dict[str, object]:
    base: dict[str, object] = {
        "scenario": "generated-office-3",
        "relays": 2,
        "seed": 1,
        "status": "ok",
        "goal_reached": "True",
        "link_broken_at_s": "",
        "collisions": "0",
        "min_e2e_mbps": "19.0",
        "relay1_reason": "rear_weak",
        "relay2_reason": "leader_near",
    }
    base.update(kw)
    return base


def test_categories() -> None:
    assert category(_row()) == "clean"
    assert category(_row(relay1_reason="avoiding (obstacle)")) == "stuck avoiding"
    assert category(_row(relay2_reason="leader_lost")) == "lost"
    assert category(_row(collisions="1")) == "collision"
    assert category(_row(link_broken_at_s="120.0")) == "link broke"
    assert category(_row(goal_reached="False")) == "leader never arrived"


def test_an_obstacle_end_counts_by_the_summarys_own_flag() -> None:
    # The summary knows whether the relay still got somewhere; an old runs.csv without
    # the column falls back to the reason alone, where "obstacle" is not following.
    assert category(_row(relay1_reason="obstacle", relay1_on_rule="True")) == "clean"
    assert category(_row(relay1_reason="obstacle", relay1_on_rule="False")) == "stuck avoiding"
    assert category(_row(relay1_reason="obstacle")) == "stuck avoiding"
    assert category(_row(relay1_reason="leader_near", relay1_on_rule="")) == "clean"


def test_section_names_the_repro_command() -> None:
    text = "\n".join(section([_row(), _row(seed=2, relay1_reason="leader_lost")]))
    assert "Clean: 1/2" in text
    assert "`relayd sim --scenario generated:office:3 --relays 2 --seed 2`" in text


def test_section_sets_the_settings_side_by_side() -> None:
    rows = [
        _row(**{"control.pursuit": "bearing"}),
        _row(**{"control.pursuit": "bearing", "seed": 2}),
        _row(**{"control.pursuit": "trail", "relay1_reason": "leader_lost"}),
        _row(**{"control.pursuit": "trail", "seed": 2}),
    ]
    text = "\n".join(section(rows, ["control.pursuit"]))
    assert "| control.pursuit=bearing | 2/2 (100.0 %) | 34.2-100.0 % | 0 |" in text
    assert "| control.pursuit=trail | 1/2 (50.0 %) | 9.5-90.5 % | 1 |" in text
    assert "seed 1, control.pursuit=trail (lost)" in text


def test_section_splits_generated_kinds() -> None:
    rows = [
        _row(**{"control.detour": "False"}),
        _row(**{"control.detour": "True", "relay2_reason": "avoiding (obstacle)"}),
        _row(scenario="generated-corridors-7", **{"control.detour": "False"}),
        _row(scenario="generated-corridors-7", **{"control.detour": "True"}),
    ]
    text = "\n".join(section(rows, ["control.detour"]))
    assert "| corridors, control.detour=False | 1/1 (100.0 %) |" in text
    assert "| office, control.detour=True | 0/1 (0.0 %) |" in text
    assert kind({"scenario": "generated-office-12"}) == "office"
    assert kind({"scenario": "corridor"}) == "corridor"
    # Kinds apart even with no --set axis.
    text = "\n".join(section(rows[::2]))
    assert "| corridors | 1/1 (100.0 %) |" in text and "| office | 1/1 (100.0 %) |" in text


def test_sweep_without_dask_names_the_extra_and_exits_2() -> None:
    import subprocess
    import sys

    code = (
        "import sys; sys.modules['distributed'] = None\n"
        "from relayd.cli import main\n"
        "sys.exit(main(['sweep', '--scenario', 'convoy']))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert out.returncode == 2, out.stderr
    assert "relayd[sweep]" in out.stderr and "Traceback" not in out.stderr


def test_worst_runs_come_with_their_world_drawn(tmp_path) -> None:
    pytest.importorskip("matplotlib")
    (tmp_path / "plots").mkdir()
    rows = [_row(relay1_reason="leader_lost"), _row(seed=2)]
    text = "\n".join(section(rows, maps=tmp_path))
    assert "![generated-office-3: the world and the leader's route](plots/worst-1.png)" in text
    assert (tmp_path / "plots" / "worst-1.png").stat().st_size > 10_000
    assert not (tmp_path / "plots" / "worst-2.png").exists()  # one failure: one map


def test_settings_are_listed_in_numeric_order() -> None:
    rows = [
        _row(seed=k, **{"control.threshold_b_dbm": v}) for k, v in enumerate(("-70", "-75", "-8"))
    ]
    text = "\n".join(section(rows, ["control.threshold_b_dbm"]))
    at = [text.index(f"control.threshold_b_dbm={v} |") for v in ("-75", "-70", "-8")]
    assert at == sorted(at)
