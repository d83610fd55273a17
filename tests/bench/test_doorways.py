"""bench/doorways.py: a map's door-like gaps, on the project's door map (two doors, 0.9 m
and 0.8 m, in partitions across a corridor) and on one drawn here with scan points in a door."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.doorways import doorways

DOORS = Path(__file__).resolve().parents[1] / "fixtures" / "maps" / "doors.map"


def test_the_door_maps_two_doors_and_nothing_else() -> None:
    found = doorways(DOORS)
    assert [(round(f["mid_x"], 2), round(f["mid_y"], 2)) for f in found] == [
        (6.0, 0.0),
        (10.0, 0.0),
    ]
    assert [f["width_m"] for f in found] == pytest.approx([0.9, 0.8])
    assert [f["clear_m"] for f in found] == pytest.approx([0.9, 0.8])


def test_scan_points_in_a_door_narrow_its_clear_width(tmp_path: Path) -> None:
    # A 1.2 m door in a wall along y = 0; a chair's points 0.3 m in from its left jamb.
    text = DOORS.read_text().split("LINES")[0] + "\n".join(
        ["LINES", "0 0 3000 0", "4200 0 8000 0", "DATA", "3300 50", "3300 -40"]
    )
    path = tmp_path / "chair.map"
    path.write_text(text + "\n")
    (door,) = doorways(path)
    assert door["width_m"] == pytest.approx(1.2)
    assert door["clear_m"] == pytest.approx(0.9)  # from the chair's points to the right jamb
