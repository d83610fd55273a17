"""ARIA map import: the parser, the scenario it makes, `relayd sim --map`, the vendor's maps."""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from relayd.sim.ariamap import MapError, load_map, parse_map
from relayd.sim.mapscenario import ROUTE_CLEARANCE_M, with_map
from relayd.sim.scenario import ScenarioError, load_scenario, parse_scenario
from relayd.sim.world import World

MAPS = Path(__file__).resolve().parents[1] / "fixtures" / "maps"
SMALL = MAPS / "small.map"


def _vendor_map(name: str) -> Path:
    prog = os.environ.get("RELAYD_MOBILESIM")
    if not prog:
        pytest.skip("RELAYD_MOBILESIM is not set: the vendor's example maps are beside MobileSim")
    path = Path(prog).parent / name
    if not path.is_file():
        pytest.skip(f"no {name} beside RELAYD_MOBILESIM ({prog})")
    return path


def test_every_construct_of_the_small_map() -> None:
    m = load_map(SMALL)
    assert len(m.lines) == 7 and m.lines[0].lineno == 19
    assert (m.lines[4].x1, m.lines[4].y1, m.lines[4].x2, m.lines[4].y2) == (5.0, 2.0, 5.0, 0.2)
    assert m.points == ((3.0, 1.8), (3.02, 1.8), (7.0, 0.0), (7.0, 0.04))
    assert m.resolution_m == pytest.approx(0.04)
    assert [(h.x, h.y, h.name) for h in m.homes] == [
        (1.5, 0.0, "front"),
        (0.5, 0.0, "back"),
        (-0.5, 0.0, "base"),
    ]
    assert [(g.x, g.y) for g in m.goals] == [(2.5, 0.0), (8.0, -1.0)]
    assert [b.rect for b in m.boxes] == [(4.0, -2.0, 4.5, -1.5)]
    assert {o.kind for o in m.objects} >= {"Dock", "ForbiddenLine"}


def test_the_scenario_of_the_small_map() -> None:
    doc = with_map(
        {
            "name": "small",
            "map_material": "light",
            "map_walls": [{"line": 23, "material": "glass"}],
        },
        SMALL,
    )
    sc = parse_scenario(doc)
    # Homes in file order: relay1, relay2, then the command center.
    assert [(r.name, r.x, r.y) for r in sc.relay] == [("relay1", 1.5, 0.0), ("relay2", 0.5, 0.0)]
    assert sc.relays == 2 and (sc.command_center.x, sc.command_center.y) == (-0.5, 0.0)
    # Six walls (the zero-length line is dropped), the one override, the box, the points
    # (thinned to one per 0.1 m square).
    assert [w.material for w in sc.walls] == ["light"] * 4 + ["glass", "light"]
    assert [(b.min, b.max) for b in sc.boxes] == [((4.0, -2.0), (4.5, -1.5))]
    assert sc.points == [(3.0, 1.8), (7.0, 0.0)] and sc.point_radius_m == pytest.approx(0.02)
    # The route runs from the first goal to the second through the doorway in x = 5.
    wps = [(w.x, w.y) for w in sc.leader.waypoints]
    assert wps[0] == (2.5, 0.0) and wps[-1] == (8.0, -1.0) and len(wps) > 2
    world = World(sc)
    crossing = [(a, b) for a, b in itertools.pairwise(wps) if (a[0] - 5.0) * (b[0] - 5.0) <= 0]
    assert crossing, wps
    (ax, ay), (bx, by) = crossing[0]
    y_at_wall = ay + (by - ay) * (5.0 - ax) / (bx - ax) if bx != ax else ay
    assert -0.9 + ROUTE_CLEARANCE_M - 0.15 <= y_at_wall <= 0.2 - ROUTE_CLEARANCE_M + 0.15
    # The points are solid and echo: a relay on a point collides, a sonar facing one hears it.
    assert not world.motion_ok(0, 7000.0, 300.0, 90.0)
    ring = world.sonar_mm(0, 6000.0, 20.0, 0.0)
    assert min(ring[3], ring[4]) == pytest.approx(1000 - 20 - 240, abs=60)


def test_sonar_keeps_only_the_points_its_cone_can_meet(monkeypatch: pytest.MonkeyPatch) -> None:
    """The per-sonar pruning of map points changes no range: the same rings with every
    point handed to every cone."""
    import random

    from relayd.sim.sonar import SonarReadings

    rng = random.Random(7)
    doc = with_map({"name": "s", "relays": 1, "map_route": "straight"}, SMALL)
    doc["points"] = [[rng.uniform(-1.0, 9.0), rng.uniform(-2.0, 2.0)] for _ in range(400)]
    world = World(parse_scenario(doc))
    poses = [
        (rng.uniform(0, 8000), rng.uniform(-1500, 1500), rng.uniform(-180, 180)) for _ in range(40)
    ]
    pruned = [world.sonar_mm(0, *p) for p in poses]
    monkeypatch.setattr(SonarReadings, "_cone_points", lambda self, ox, oy, h: list(world.points))
    assert [world.sonar_mm(0, *p) for p in poses] == pruned
    assert any(min(r) < 5000 for r in pruned)


def test_points_off_and_straight_route() -> None:
    sc = parse_scenario(
        with_map({"name": "s", "map_points": "off", "map_route": "straight"}, SMALL)
    )
    assert sc.points == [] and [(w.x, w.y) for w in sc.leader.waypoints] == [
        (2.5, 0.0),
        (8.0, -1.0),
    ]


def test_scenario_file_with_a_map_key(tmp_path: Path) -> None:
    (tmp_path / "w.map").write_bytes(SMALL.read_bytes())
    (tmp_path / "s.toml").write_text('name = "s"\nmap = "w.map"\nrelays = 1\n', encoding="utf-8")
    sc = load_scenario(tmp_path / "s.toml")
    assert sc.map == str((tmp_path / "w.map").resolve()) and sc.relays == 1


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ((MAPS / "bad.map").read_text(), "bad.map:5: LINES entry needs 4 numbers, got 3"),
        ("2D-Map\nDATA\n1 x\n", "m:3: DATA point needs numbers"),
        ("hello\n", "m:1: not an ARIA map"),
        ("2D-Map\nCairn: Goal 1 2\n", "m:2: Cairn needs a type, x, y and theta"),
        ("2D-Map\nwhat is this\n", "m:2: expected 'Key: value'"),
    ],
)
def test_malformed_maps_name_the_line(text: str, where: str) -> None:
    source = "bad.map" if "bad.map" in where else "m"
    with pytest.raises(MapError, match=where):
        parse_map(text, source)


def test_bad_override_names_its_key() -> None:
    with pytest.raises(ScenarioError, match=r"map_walls.0.line: line 3 of .* is not a LINES entry"):
        with_map({"name": "s", "map_walls": [{"line": 3, "material": "glass"}]}, SMALL)
    with pytest.raises(ScenarioError, match="map_material: unknown material 'cheese'"):
        parse_scenario(with_map({"name": "s", "map_material": "cheese"}, SMALL))


def _relayd(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "relayd", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def test_sim_with_a_malformed_map_exits_2(tmp_path: Path) -> None:
    proc = _relayd("sim", "--map", str(MAPS / "bad.map"), "--out", str(tmp_path), cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "bad.map:5: LINES entry needs 4 numbers" in proc.stderr


def test_sim_runs_a_map(tmp_path: Path) -> None:
    proc = _relayd(
        "sim", "--map", str(SMALL), "--relays", "1", "--seconds", "8", "--speed", "max",
        "--no-plots", "--out", str(tmp_path / "o"), cwd=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "small with 1 relay(s), 8 s simulated" in proc.stdout
    assert (tmp_path / "o" / "trace.jsonl").stat().st_size > 0


@pytest.mark.parametrize("name", ["AMROffice.map", "columbia.map"])
def test_vendor_maps_load_fast(name: str) -> None:
    path = _vendor_map(name)
    t0 = time.perf_counter()
    m = load_map(path)
    assert len(m.lines) > 200 and len(m.points) > 20000
    doc = {
        "name": name,
        "map_route": "straight",
        "relays": 0,
        "command_center": {"x": 0.0, "y": 0.0},
        "leader": {"waypoints": [{"x": 0.0, "y": 0.0}]},
    }
    world = World(parse_scenario(with_map(doc, path)))
    x0, y0, x1, y1 = m.bounds()
    # A sonar ring anywhere in the building costs about as much as in a small world.
    t1 = time.perf_counter()
    for k in range(20):
        world.sonar_mm(0, 1000 * (x0 + (x1 - x0) * k / 20), 1000 * (y0 + y1) / 2, 0.0)
    assert time.perf_counter() - t0 < 20.0
    assert time.perf_counter() - t1 < 5.0


def test_mobilesim_engine_without_its_program_exits_2(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "RELAYD_MOBILESIM"}
    proc = subprocess.run(
        [sys.executable, "-m", "relayd", "sim", "--engine", "mobilesim", "--map", str(SMALL),
         "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=120, check=False, env=env,
    )  # fmt: skip
    assert proc.returncode == 2
    assert "give --mobilesim PATH or set RELAYD_MOBILESIM" in proc.stderr
