"""bench/robustness.py without --set: the shipped law's sweep and the paper's, one table."""

from __future__ import annotations

import csv
from pathlib import Path

from bench.robustness import LAWS, PAPER, read_rows, table
from relayd.sweep.grid import parse_set

FIELDS = [
    "scenario",
    "relays",
    "seed",
    "status",
    "goal_reached",
    "link_broken_at_s",
    "collisions",
    "min_e2e_mbps",
    "sim_seconds",
    "wall_s",
    "relay1_reason",
]


def _sweep(out: Path, reasons: list[str]) -> None:
    out.mkdir(parents=True)
    with (out / "runs.csv").open("w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, FIELDS)
        w.writeheader()
        for i, reason in enumerate(reasons):
            w.writerow(
                {
                    "scenario": f"generated-office-{i}",
                    "relays": 2,
                    "seed": 1,
                    "status": "ok",
                    "goal_reached": True,
                    "link_broken_at_s": "",
                    "collisions": 0,
                    "min_e2e_mbps": 10.0,
                    "sim_seconds": 100.0,
                    "wall_s": 2.0,
                    "relay1_reason": reason,
                }
            )


def test_the_paper_keys_are_sweep_axes_and_turn_each_addition_off() -> None:
    axes = [parse_set(a) for a in PAPER]
    assert {a.key: a.values for a in axes} == {
        "control.side_keep_m": (0,),
        "control.wall_slide_m": (0,),
        "control.beside_speed_floor": (0,),
        "avoidance.lane_pass_margin_m": (0,),
        "avoidance.keep_episode_when_lost": (False,),
        "avoidance.lost_manoeuvre_s": (0,),
        "avoidance.blocked_retry_s": (0,),
        "avoidance.unpin": (False,),
        "avoidance.align_open_deg": (0,),
        "avoidance.beside_turn": (False,),
    }
    assert set(LAWS) == {"default", "paper"} and LAWS["default"] == ()


def test_both_laws_in_one_table(tmp_path: Path) -> None:
    _sweep(tmp_path / "default", ["rear_weak", "leader_near", "rear_weak"])
    _sweep(tmp_path / "paper", ["rear_weak", "avoiding", "blocked"])
    rows = read_rows(tmp_path, "")
    assert [r["law"] for r in rows] == ["default"] * 3 + ["paper"] * 3
    text = "\n".join(table(tmp_path, ""))
    assert "| law=default | 3/3 (100.0 %)" in text
    assert "| law=paper | 1/3 (33.3 %)" in text


def test_one_sweep_without_the_laws_is_read_as_it_is(tmp_path: Path) -> None:
    _sweep(tmp_path / "one", ["rear_weak", "avoiding"])
    tmp_path = tmp_path / "one"
    assert len(read_rows(tmp_path, "")) == 2
    assert any("Clean: 1/2" in line for line in table(tmp_path, ""))
