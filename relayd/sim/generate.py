"""Floor plans nobody drew by hand: seeded, deterministic worlds as scenario TOML.

`generate("office", seed)` builds a corridor with a row of rooms north of it, enters one
room by its corridor door and leaves it by an inner door into the next, plans the
person's route with A* (relayd/sim/planner.py) keeping the P3-AT's half-width plus a
margin from every wall and box, and writes an ordinary scenario document. A draw is kept
only when its own radio says two relays are needed to keep the link to the person's goal
and two are enough (relayd/sim/linkneed.py); otherwise the next draw is tried. The same
kind and seed give the same text, byte for byte (random.Random seeded from the string).
Kinds: "office" (below), "corridors" (a corridor network with L-corners and T-junctions,
relayd/sim/gen_corridors.py), and "hall" (an open hall with pillars), "warehouse" (aisles
between racks) and "mixed" (a hall, then a warehouse) (relayd/sim/gen_halls.py); other
kinds are refused by name.

Each relay scans with an antenna drawn from the simulator's family
(relayd/sim/antennas.py), one draw per relay from a stream of its own seeded from the same
kind and seed, so adding the antennas left every floor plan, route and loss table as it was.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import itertools
import math
import random
from typing import TYPE_CHECKING

from relayd.sim.antennas import DRAWN
from relayd.sim.gen_corridors import corridors
from relayd.sim.gen_halls import building
from relayd.sim.linkneed import PowerFn, relays_needed
from relayd.sim.planner import Point, Segment, plan, route_length_m
from relayd.sim.radio import DEFAULT_WALL_LOSS_DB, Radio

if TYPE_CHECKING:
    from relayd.sim.scenario import Scenario

KINDS = ("office", "corridors", "hall", "warehouse", "mixed")
#: The open kinds' sections, east of their entrance corridor (relayd/sim/gen_halls.py).
SECTIONS = {"hall": ["hall", "room"], "warehouse": ["racks"], "mixed": ["hall", "racks"]}
#: P3-AT: 0.50 m wide (half 0.25 m) plus a 0.25 m margin on each side.
CLEARANCE_M = 0.5
#: A first, cheap filter before the radio's count (relayd/sim/linkneed.py): shorter routes
#: keep the link with one relay in nearly every draw, and the count costs far more.
MIN_ROUTE_M = 40.0
#: About one office draw in eight and one hall draw in thirteen needs two relays and no
#: more: 200 draws leave a seed without a world about once in ten million (50 left 2
#: office and 17 hall seeds of 1000 without one).
MAX_TRIES = 200
#: The person starts ahead of the convoy, as in corridor.toml.
START: Point = (3.5, 0.0)


class GenerateError(ValueError):
    pass


def _r(x: float) -> float:
    return round(x, 2)


def _office(rng: random.Random) -> dict[str, object]:
    w = _r(rng.uniform(1.5, 4.0))  # corridor width
    depth = _r(rng.uniform(4.0, 7.0))
    n_rooms = rng.randint(6, 10)
    widths = [_r(rng.uniform(4.0, 7.0)) for _ in range(n_rooms)]
    outer = rng.choice(["brick", "concrete"])
    inner = rng.choice(["light", "glass", "light"])
    y_s, y_n, y_b = -w / 2, w / 2, w / 2 + depth
    x0 = 3.0
    edges = [x0]
    for rw in widths:
        edges.append(_r(edges[-1] + rw))
    x_end = _r(edges[-1] + 2.0)
    walls: list[tuple[list[Point], str]] = []
    doors: list[tuple[Point, Point]] = []
    # South corridor wall and end wall, the building's shell.
    walls.append(([(-3.0, _r(y_s)), (x_end, _r(y_s)), (x_end, _r(y_b))], outer))
    walls.append(([(-3.0, _r(y_s)), (-3.0, _r(y_n)), (x0, _r(y_n)), (x0, _r(y_b))], outer))
    walls.append(([(x0, _r(y_b)), (x_end, _r(y_b))], outer))
    # North corridor wall with one door per room.
    xs = x0
    door_x = []
    for k in range(n_rooms):
        dw = _r(rng.uniform(0.8, 1.4))
        dx = _r(rng.uniform(edges[k] + 0.5, edges[k + 1] - 0.5 - dw))
        door_x.append((dx, dw))
        walls.append(([(xs, _r(y_n)), (dx, _r(y_n))], inner))
        doors.append(((dx, _r(y_n)), (_r(dx + dw), _r(y_n))))
        xs = _r(dx + dw)
    walls.append(([(xs, _r(y_n)), (x_end, _r(y_n))], inner))
    # The room the person walks into, and the next one through an inner door.
    k = rng.randint(n_rooms - 3, n_rooms - 2)
    for e in range(1, n_rooms):
        x = edges[e]
        if e == k + 1:
            dw = _r(rng.uniform(0.8, 1.4))
            dy = _r(rng.uniform(y_n + 0.6, y_b - 0.6 - dw))
            walls.append(([(x, _r(y_n)), (x, dy)], inner))
            walls.append(([(x, _r(dy + dw)), (x, _r(y_b))], inner))
            doors.append(((x, dy), (x, _r(dy + dw))))
        else:
            walls.append(([(x, _r(y_n)), (x, _r(y_b))], inner))
    # Furniture: a box against the back wall of every room.
    boxes: list[tuple[Point, Point]] = []
    for e in range(n_rooms):
        bw = _r(rng.uniform(0.6, 1.5))
        bx = _r(rng.uniform(edges[e] + 0.2, edges[e + 1] - 0.2 - bw))
        boxes.append(((bx, _r(y_b - 0.8)), (_r(bx + bw), _r(y_b - 0.1))))
    gx = _r((edges[k + 1] + edges[k + 2]) / 2)
    goal = (gx, _r(y_n + depth / 2))
    loss = {m: _r(v * rng.uniform(0.8, 1.2)) for m, v in sorted(DEFAULT_WALL_LOSS_DB.items())}
    return {"walls": walls, "doors": doors, "boxes": boxes, "goal": goal, "loss": loss}


def _segments(world: dict[str, object]) -> list[Segment]:
    segs: list[Segment] = []
    for pts, _m in world["walls"]:  # type: ignore[attr-defined]
        segs.extend(itertools.pairwise(pts))
    for (ax, ay), (bx, by) in world["boxes"]:  # type: ignore[attr-defined]
        c = [(ax, ay), (bx, ay), (bx, by), (ax, by), (ax, ay)]
        segs.extend(itertools.pairwise(c))
    return segs


def build(kind: str, seed: int) -> tuple[dict[str, object], list[Point]]:
    """The world and its route; retries with the next draw until it is valid."""
    world, route = _build(kind, seed)
    return copy.deepcopy(world), list(route)


#: A sweep runs each world once per setting and the tests ask for one several times; a
#: hall's draws cost seconds (the radio's corner graph of every draw counted).
@functools.lru_cache(maxsize=32, typed=True)
def _build(kind: str, seed: int) -> tuple[dict[str, object], list[Point]]:
    if kind not in KINDS:
        raise GenerateError(f"generated: unknown kind {kind!r} (known: {', '.join(KINDS)})")
    rng = random.Random(f"{kind}:{seed}")
    for _ in range(MAX_TRIES):
        if kind == "office":
            world = _office(rng)
        else:
            loss = {
                m: _r(v * rng.uniform(0.8, 1.2)) for m, v in sorted(DEFAULT_WALL_LOSS_DB.items())
            }
            world = (
                corridors(rng, loss) if kind == "corridors" else building(rng, SECTIONS[kind], loss)
            )
        route = plan(_segments(world), START, world["goal"], CLEARANCE_M)  # type: ignore[arg-type]
        if route is None or route_length_m(route) < MIN_ROUTE_M:
            continue
        route = [(_r(x), _r(y)) for x, y in route]
        sc = _scenario(_render(kind, seed, world, route))
        # The straight path through the walls is never stronger than the dominant one, so
        # a world the wall count holds with one relay is refused without the corner graph.
        if count(sc, "wall-count", most=1) >= 2 and count(sc) == 2:
            return world, route
    raise GenerateError(f"generated:{kind}:{seed}: no valid world in {MAX_TRIES} draws")


def needed(text: str) -> int:
    """Relays the world of scenario `text` needs by its own radio (relayd/sim/linkneed.py)."""
    return count(_scenario(text))


def count(sc: Scenario, model: str | None = None, most: int = 2) -> int:
    """Relays scenario `sc`'s world needs by its own radio, or by the radio `model` named
    instead of its own; `most` as relays_needed's."""
    route = [(w.x, w.y) for w in sc.leader.waypoints]
    cc = (sc.command_center.x, sc.command_center.y)
    return relays_needed(budget(sc, model), cc, route, most=most)


def _scenario(text: str) -> Scenario:
    # Imported here: the scenario loader imports this module for `generated:` names.
    import tomllib

    from relayd.sim.scenario import parse_scenario

    return parse_scenario(tomllib.loads(text))


def budget(sc: Scenario, model: str | None = None) -> PowerFn:
    """The local-mean power between two points of scenario `sc`'s world: its radio (or the
    `model` named instead) through its walls and boxes, as the simulator's World builds it,
    without shadowing, so every run seed of the world gets the same answer."""
    params = sc.radio_params()
    params = dataclasses.replace(params, shadow_sigma_db=0.0, model=model or params.model)
    radio = Radio(params, sc.static_segments())
    return lambda a, b: radio.mean_power_dbm(a, b)[0]


def antennas(kind: str, seed: int, relays: int) -> list[str]:
    """The family pattern each of the world's relays scans with, in relay order."""
    # A stream of its own: drawing from the world's would move every later draw, and so
    # every floor plan.
    rng = random.Random(f"{kind}:{seed}:antennas")
    names = list(DRAWN)
    return [rng.choice(names) for _ in range(relays)]


def _pts(points: list[Point]) -> str:
    return "[" + ", ".join(f"[{x}, {y}]" for x, y in points) + "]"


def generate(kind: str, seed: int) -> str:
    """The scenario TOML of world `kind`:`seed`."""
    world, route = build(kind, seed)
    return _render(kind, seed, world, route)


def _render(kind: str, seed: int, world: dict[str, object], route: list[Point]) -> str:
    pattern1, pattern2 = antennas(kind, seed, 2)
    length = route_length_m(route)
    name = f"generated-{kind}-{seed}"
    out = [
        f"# Generated by relayd.sim.generate (kind {kind}, seed {seed}); route {length:.1f} m.",
        f'name = "{name}"',
        f'description = "generated {kind} floor, seed {seed}"',
        'environment = "indoor"',
        f"duration_s = {math.ceil(length / 0.2 + 120)}",
        "relays = 2",
        "",
        "[command_center]",
        "x = -1.5",
        "y = 0.0",
        "",
        "[leader]",
        'kind = "person"',
        "speed_m_s = 0.2",
        "start_s = 2.0",
        "waypoints = [" + ", ".join(f"{{ x = {x}, y = {y} }}" for x, y in route) + "]",
        "",
        "[[relay]]",
        'name = "relay1"',
        "x = 2.0",
        "y = 0.0",
        f'pattern = "{pattern1}"',
        "",
        "[[relay]]",
        'name = "relay2"',
        "x = 0.5",
        "y = 0.0",
        f'pattern = "{pattern2}"',
        "",
        "[sonar]",
        "specular = true",
        "",
        "[radio]",
        'model = "dominant-path"',
        "",
        "[radio.wall_loss_db]",
    ]
    out += [f"{m} = {v}" for m, v in world["loss"].items()]  # type: ignore[attr-defined]
    for pts, material in world["walls"]:  # type: ignore[attr-defined]
        out += ["", "[[walls]]", f"points = {_pts(pts)}", f'material = "{material}"']
    for (ax, ay), (bx, by) in world["boxes"]:  # type: ignore[attr-defined]
        out += ["", "[[boxes]]", f"min = [{ax}, {ay}]", f"max = [{bx}, {by}]"]
    return "\n".join(out) + "\n"


def parse_ref(ref: str) -> tuple[str, int] | None:
    """`generated:KIND:SEED` -> (kind, seed); None when `ref` is not such a name."""
    parts = ref.split(":")
    if len(parts) != 3 or parts[0] != "generated":
        return None
    try:
        return parts[1], int(parts[2])
    except ValueError:
        raise GenerateError(f"{ref}: the seed must be an integer") from None
