"""The floor-plan generator's open kinds: "hall" (an open hall with pillars and furniture),
"warehouse" (aisles between long racks) and "mixed" (a hall, then a warehouse through an
inner door). relayd/sim/generate.py draws the kinds; this module draws these three.

Every building is entered the same way: a corridor runs east along y = 0 from the west
wall (x = -3 m), where the command center and the convoy stand, to a doorway in the first
section's west wall. Sections follow one another eastward, each behind a wall with one
doorway at a drawn height. The person's goal is in the last section: the far end of a
hall, or the middle of one of a warehouse's last aisles.

A rack is a box (the simulator's "box" material for the radio, an obstacle for the sonar
and the planner): long, 1.0-1.4 m deep, with aisles of 1.5-4 m between racks and cross
aisles at both ends. Pillars are small square boxes on a grid; furniture is a few
table-sized boxes placed clear of everything else, so every passage stays passable for
the robot (the planner's clearance decides; a draw it cannot route through is retried).
"""

from __future__ import annotations

import random

Point = tuple[float, float]
Box = tuple[Point, Point]

WEST_M = -3.0
#: Each section's length (m), alone and in a mixed building.
HALL_M = ((28.0, 40.0), (14.0, 22.0))
RACKS_M = ((30.0, 42.0), (20.0, 28.0))
#: Obstacles keep this far (m) from walls and from each other: a passage of at least
#: twice the planner's clearance.
GAP_M = 1.6


def _r(x: float) -> float:
    return round(x, 2)


def _apart(box: Box, others: list[Box], gap_m: float) -> bool:
    (ax, ay), (bx, by) = box
    return all(
        ax >= ox2 + gap_m or bx <= ox1 - gap_m or ay >= oy2 + gap_m or by <= oy1 - gap_m
        for (ox1, oy1), (ox2, oy2) in others
    )


def _pillars(rng: random.Random, x0: float, x1: float, half_h: float, boxes: list[Box]) -> None:
    spacing = rng.uniform(5.0, 8.0)
    side = _r(rng.uniform(0.4, 0.8))
    x = x0 + spacing / 2 + 1.0
    while x + side < x1 - 2.0:
        y = -half_h + spacing / 2
        while y + side < half_h - 2.0:
            box = ((_r(x), _r(y)), (_r(x + side), _r(y + side)))
            if _apart(box, boxes, GAP_M):
                boxes.append(box)
            y += spacing
        x += spacing


def _furniture(
    rng: random.Random, x0: float, x1: float, half_h: float, boxes: list[Box], count: int
) -> None:
    for _ in range(count):
        w, d = _r(rng.uniform(0.6, 1.6)), _r(rng.uniform(0.6, 1.0))
        x = _r(rng.uniform(x0 + GAP_M, x1 - GAP_M - w))
        y = _r(rng.uniform(-half_h + GAP_M, half_h - GAP_M - d))
        box = ((x, y), (_r(x + w), _r(y + d)))
        if _apart(box, boxes, GAP_M):
            boxes.append(box)


def _racks(rng: random.Random, x0: float, x1: float, half_h: float, boxes: list[Box]) -> Point:
    """Racks running north-south between cross aisles; the goal, in one of the last aisles."""
    depth = _r(rng.uniform(1.0, 1.4))
    cross = (_r(rng.uniform(2.0, 3.5)), _r(rng.uniform(2.0, 3.5)))
    y0, y1 = _r(-half_h + cross[0]), _r(half_h - cross[1])
    x = x0 + 3.0  # room to come in through the door before the first rack
    aisles: list[tuple[float, float]] = []
    while True:
        aisle = _r(rng.uniform(1.5, 4.0))
        if x + depth + aisle + depth > x1 - 3.0:
            break
        boxes.append(((_r(x), y0), (_r(x + depth), y1)))
        aisles.append((x + depth, x + depth + aisle))
        x += depth + aisle
    boxes.append(((_r(x), y0), (_r(x + depth), y1)))
    a, b = rng.choice(aisles[-3:])
    return _r((a + b) / 2), _r(rng.uniform(y0 + 0.25 * (y1 - y0), y1 - 0.25 * (y1 - y0)))


def building(rng: random.Random, sections: list[str], loss: dict[str, float]) -> dict[str, object]:
    """One world of the given sections ("hall" or "racks") east of the entrance corridor
    (the generator's world dict; see generate._office)."""
    w0 = rng.choice([1.5, 2.0, 2.5, 3.0])
    x0 = _r(rng.uniform(8.0, 14.0))
    half_h = _r(rng.uniform(7.0, 13.0))
    outer = rng.choice(["brick", "concrete"])
    inner = rng.choice(["light", "brick", "light"])
    alone = len(sections) == 1
    lengths = [
        _r(rng.uniform(*(HALL_M if s == "hall" else RACKS_M)[0 if alone else 1])) for s in sections
    ]
    edges = [x0]
    for length in lengths:
        edges.append(_r(edges[-1] + length))
    x_end = edges[-1]
    walls: list[tuple[list[Point], str]] = []
    doors: list[tuple[Point, Point]] = []
    # The entrance corridor, then the shell round the sections.
    corridor = [(x0, _r(-w0 / 2)), (WEST_M, _r(-w0 / 2)), (WEST_M, _r(w0 / 2)), (x0, _r(w0 / 2))]
    walls.append((corridor, outer))
    walls.append(([(x0, -half_h), (x_end, -half_h), (x_end, half_h), (x0, half_h)], outer))
    # Each section's west wall with its doorway: from the corridor, or at a drawn height.
    keep: list[Box] = []
    for k, xa in enumerate(edges[:-1]):
        if k == 0:
            dw = _r(rng.uniform(0.8, min(1.4, w0 - 0.2)))
            dy = _r(rng.uniform(-w0 / 2 + 0.1, w0 / 2 - 0.1 - dw))
        else:
            dw = _r(rng.uniform(0.8, 1.4))
            dy = _r(rng.uniform(-half_h + 2.0, half_h - 2.0 - dw))
        material = outer if k == 0 else inner
        walls.append(([(xa, -half_h), (xa, dy)], material))
        walls.append(([(xa, _r(dy + dw)), (xa, half_h)], material))
        doors.append(((xa, dy), (xa, _r(dy + dw))))
        # No furniture in front of a doorway, on either side.
        keep.append(((_r(xa - 2.5), _r(dy - 0.5)), (_r(xa + 2.5), _r(dy + dw + 0.5))))
    boxes: list[Box] = list(keep)
    goal: Point = (0.0, 0.0)
    for kind, xa, xb in zip(sections, edges[:-1], edges[1:], strict=True):
        if kind == "hall":
            _pillars(rng, xa, xb, half_h, boxes)
            _furniture(rng, xa, xb, half_h, boxes, rng.randint(3, 7))
            goal = (_r(xb - rng.uniform(2.0, 4.0)), _r(rng.uniform(-half_h + 2.0, half_h - 2.0)))
        else:
            goal = _racks(rng, xa, xb, half_h, boxes)
    return {
        "walls": walls,
        "doors": doors,
        "boxes": boxes[len(keep) :],
        "goal": goal,
        "loss": loss,
    }
