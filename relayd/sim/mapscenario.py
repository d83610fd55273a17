"""A scenario of an ARIA map: the map's walls, points, start poses and goals as scenario keys.

`with_map(doc, path)` takes a scenario document (a TOML table, possibly only a name)
and fills it from the map at `path` (relayd/sim/ariamap.py):

- every `LINES` entry becomes a wall of `map_material` (default brick), except the lines
  `map_walls` names by their line number in the file (`{ line = 57, material = "glass" }`);
- `Sim.BoxObstacle` rectangles become boxes;
- `DATA` points become `points` (solid discs of the map's resolution, one kept per
  POINT_CELL_M square) unless `map_points = "off"`;
- `RobotHome` objects, in file order, are the chain's start poses from the front:
  relay 1, relay 2, ..., and the last one the command center; a document's own
  `[[relay]]` and `[command_center]` win;
- the leader's waypoints are the document's `leader.waypoints`, else the map's `Goal`
  objects in file order (the first one is where the leader starts); with
  `map_route = "plan"` (the default) each leg is planned through the map's walls and
  points with relayd/sim/planner.py's A*, keeping ROUTE_CLEARANCE_M.

Errors raise ScenarioError naming the key or the map's line.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

from relayd.sim.ariamap import AriaMap, MapError, load_map
from relayd.sim.planner import Grid, plan_on
from relayd.sim.scenario import ScenarioError

#: How far the planned route keeps from every wall and point by default (the scenario's
#: map_clearance_m): a P3-AT's half-width (0.25 m) and a margin, small enough for an
#: office doorway of 0.9 m.
ROUTE_CLEARANCE_M = 0.4
#: The planner's grid cell (m).
ROUTE_CELL_M = 0.1
#: The map's points are kept one per square of this side (m): see _points.
POINT_CELL_M = 0.1


def _points(doc: dict[str, Any], amap: AriaMap) -> list[tuple[float, float]]:
    """The map's points, one kept per POINT_CELL_M square (the first in the file)."""
    if doc.get("map_points", "points") == "off":
        return []
    # A scan draws a wall as a point every resolution (20 mm); a sonar beam 30 degrees wide
    # and a body half a metre across cannot tell that from a point every 0.1 m, and each
    # point costs every sonar within reach a test, so the points are thinned to a grid.
    seen: set[tuple[int, int]] = set()
    out = []
    for x, y in amap.points:
        cell = (math.floor(x / POINT_CELL_M), math.floor(y / POINT_CELL_M))
        if cell not in seen:
            seen.add(cell)
            out.append((x, y))
    return out


def _walls(doc: dict[str, Any], amap: AriaMap) -> list[dict[str, Any]]:
    material = doc.get("map_material", "brick")
    by_line: dict[int, Any] = {}
    overrides = doc.get("map_walls", [])
    known = {ln.lineno for ln in amap.lines}
    for i, o in enumerate(overrides if isinstance(overrides, list) else []):
        line = o.get("line") if isinstance(o, dict) else None
        if isinstance(line, int) and line not in known:
            raise ScenarioError(
                [f"map_walls.{i}.line: line {line} of {amap.source} is not a LINES entry"]
            )
        if isinstance(line, int):
            by_line[line] = o.get("material", material)
    return [
        {
            "points": [[ln.x1, ln.y1], [ln.x2, ln.y2]],
            "material": by_line.get(ln.lineno, material),
        }
        for ln in amap.lines
        if (ln.x1, ln.y1) != (ln.x2, ln.y2)
    ]


def _boxes(amap: AriaMap) -> list[dict[str, Any]]:
    out = []
    for b in amap.boxes:
        assert b.rect is not None
        x1, y1, x2, y2 = b.rect
        if x1 != x2 and y1 != y2:
            out.append(
                {
                    "min": [min(x1, x2), min(y1, y2)],
                    "max": [max(x1, x2), max(y1, y2)],
                    "material": "box",
                }
            )
    return out


def _starts(doc: dict[str, Any], amap: AriaMap) -> None:
    homes = amap.homes
    if "relay" not in doc and len(homes) >= 2:
        doc["relay"] = [
            {"name": f"relay{k + 1}", "x": h.x, "y": h.y, "theta_deg": h.theta_deg}
            for k, h in enumerate(homes[:-1])
        ]
        doc.setdefault("relays", len(homes) - 1)
    if "command_center" not in doc:
        if not homes:
            raise ScenarioError(
                [
                    f"command_center: {amap.source} has no RobotHome object: give"
                    " [command_center] (and [[relay]] poses) in the scenario"
                ]
            )
        doc["command_center"] = {"x": homes[-1].x, "y": homes[-1].y}
        if "relay" not in doc:
            doc.setdefault("relays", 0)


def _clear(grid: Grid, a: tuple[float, float], b: tuple[float, float]) -> bool:
    """Whether the straight line a-b stays on free cells (sampled every half cell)."""
    n = max(1, math.ceil(math.dist(a, b) / (grid.cell_m / 2)))
    return all(
        grid.free((a[0] + (b[0] - a[0]) * k / n, a[1] + (b[1] - a[1]) * k / n))
        for k in range(n + 1)
    )


def _taut(grid: Grid, route: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The grid route with its staircase removed: from each kept corner, straight to the
    farthest later corner in sight (the ends are kept)."""
    out = [route[0]]
    i = 0
    while i < len(route) - 1:
        j = len(route) - 1
        while j > i + 1 and not _clear(grid, route[i], route[j]):
            j -= 1
        out.append(route[j])
        i = j
    return out


def _route(doc: dict[str, Any], amap: AriaMap, points: list[tuple[float, float]]) -> None:
    leader = dict(doc.get("leader") or {})
    wps = leader.get("waypoints")
    if not wps:
        goals = amap.goals
        if not goals:
            raise ScenarioError(
                [f"leader.waypoints: {amap.source} has no Goal object: give the leader's route"]
            )
        wps = [{"x": g.x, "y": g.y} for g in goals]
    if doc.get("map_route", "plan") == "plan" and len(wps) >= 2:
        walls = [((ln.x1, ln.y1), (ln.x2, ln.y2)) for ln in amap.lines]
        clearance_m = float(doc.get("map_clearance_m", ROUTE_CLEARANCE_M))
        grid = Grid(walls, clearance_m, ROUTE_CELL_M, points=points)
        planned: list[dict[str, Any]] = [dict(wps[0])]
        for k, (a, b) in enumerate(itertools.pairwise(wps)):
            try:
                start, goal = (float(a["x"]), float(a["y"])), (float(b["x"]), float(b["y"]))
            except (KeyError, TypeError, ValueError):
                raise ScenarioError([f"leader.waypoints.{k}: needs numbers x and y"]) from None
            route = plan_on(grid, start, goal)
            if route is None:
                raise ScenarioError(
                    [
                        f"leader.waypoints.{k + 1}: no way through {amap.source} from"
                        f" ({start[0]:.2f}, {start[1]:.2f}) to ({goal[0]:.2f}, {goal[1]:.2f})"
                        f" keeping {clearance_m} m from walls and points (map_clearance_m)"
                    ]
                )
            route = _taut(grid, route)
            planned += [{"x": round(x, 3), "y": round(y, 3)} for x, y in route[1:-1]]
            planned.append(dict(b))
        wps = planned
    leader["waypoints"] = wps
    doc["leader"] = leader


def map_document(doc: dict[str, Any], amap: AriaMap, path: str) -> dict[str, Any]:
    """`doc` filled from a parsed map (see the module docstring); `doc` is not changed."""
    out = dict(doc)
    out["map"] = path
    out.setdefault("name", Path(path).stem)
    points = _points(out, amap)
    out["walls"] = list(out.get("walls") or []) + _walls(out, amap)
    out["boxes"] = list(out.get("boxes") or []) + _boxes(amap)
    if points:
        out["points"] = list(out.get("points") or []) + [list(p) for p in points]
        out.setdefault("point_radius_m", amap.resolution_m / 2.0)
    _starts(out, amap)
    _route(out, amap, points)
    return out


def with_map(doc: dict[str, Any], path: str | Path) -> dict[str, Any]:
    """`doc` filled from the map file at `path` (ScenarioError on a bad map)."""
    try:
        amap = load_map(path)
    except MapError as exc:
        raise ScenarioError([f"map: {exc}"]) from None
    return map_document(doc, amap, str(Path(path).resolve()))
