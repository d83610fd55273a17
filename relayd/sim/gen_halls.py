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
#: A hall's back room, across its far end.
ROOM_M = ((4.0, 7.0), (4.0, 7.0))
LENGTHS_M = {"hall": HALL_M, "racks": RACKS_M, "room": ROOM_M}
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


def _pillars(
    rng: random.Random, x0_m: float, x1_m: float, half_depth_m: float, boxes: list[Box]
) -> None:
    spacing_m = rng.uniform(7.0, 10.0)
    side_m = _r(rng.uniform(0.4, 0.8))
    x = x0_m + spacing_m / 2 + 1.0
    while x + side_m < x1_m - 2.0:
        y = -half_depth_m + spacing_m / 2
        while y + side_m < half_depth_m - 2.0:
            box = ((_r(x), _r(y)), (_r(x + side_m), _r(y + side_m)))
            if _apart(box, boxes, GAP_M):
                boxes.append(box)
            y += spacing_m
        x += spacing_m


def _furniture(
    rng: random.Random, x0_m: float, x1_m: float, half_depth_m: float, boxes: list[Box], count: int
) -> None:
    for _ in range(count):
        w, d = _r(rng.uniform(0.6, 1.6)), _r(rng.uniform(0.6, 1.0))
        x = _r(rng.uniform(x0_m + GAP_M, x1_m - GAP_M - w))
        y = _r(rng.uniform(-half_depth_m + GAP_M, half_depth_m - GAP_M - d))
        box = ((x, y), (_r(x + w), _r(y + d)))
        if _apart(box, boxes, GAP_M):
            boxes.append(box)


def _racks(
    rng: random.Random, x0_m: float, x1_m: float, half_depth_m: float, boxes: list[Box]
) -> Point:
    """Racks running north-south between cross aisles; the goal, in one of the last aisles."""
    rack_depth_m = _r(rng.uniform(1.0, 1.4))
    cross_m = (_r(rng.uniform(2.0, 3.5)), _r(rng.uniform(2.0, 3.5)))
    y0_m, y1_m = _r(-half_depth_m + cross_m[0]), _r(half_depth_m - cross_m[1])
    x = x0_m + 3.0  # room to come in through the door before the first rack
    aisles: list[tuple[float, float]] = []
    while True:
        aisle_m = _r(rng.uniform(1.5, 4.0))
        if x + rack_depth_m + aisle_m + rack_depth_m > x1_m - 3.0:
            break
        boxes.append(((_r(x), y0_m), (_r(x + rack_depth_m), y1_m)))
        aisles.append((x + rack_depth_m, x + rack_depth_m + aisle_m))
        x += rack_depth_m + aisle_m
    boxes.append(((_r(x), y0_m), (_r(x + rack_depth_m), y1_m)))
    a, b = rng.choice(aisles[-3:])
    return _r((a + b) / 2), _r(
        rng.uniform(y0_m + 0.25 * (y1_m - y0_m), y1_m - 0.25 * (y1_m - y0_m))
    )


def building(rng: random.Random, sections: list[str], loss: dict[str, float]) -> dict[str, object]:
    """One world of the given sections ("hall" or "racks") east of the entrance corridor
    (the generator's world dict; see generate._office)."""
    entry_w_m = rng.choice([1.5, 2.0, 2.5, 3.0])
    x0_m = _r(rng.uniform(8.0, 14.0))
    half_depth_m = _r(rng.uniform(7.0, 13.0))
    outer = rng.choice(["brick", "concrete"])
    inner = rng.choice(["light", "brick", "light"])
    alone = len([s for s in sections if s != "room"]) == 1
    lengths = [_r(rng.uniform(*LENGTHS_M[s][0 if alone else 1])) for s in sections]
    edges = [x0_m]
    for length in lengths:
        edges.append(_r(edges[-1] + length))
    x_end_m = edges[-1]
    walls: list[tuple[list[Point], str]] = []
    doors: list[tuple[Point, Point]] = []
    # The entrance corridor, then the shell round the sections.
    corridor = [
        (x0_m, _r(-entry_w_m / 2)),
        (WEST_M, _r(-entry_w_m / 2)),
        (WEST_M, _r(entry_w_m / 2)),
        (x0_m, _r(entry_w_m / 2)),
    ]
    walls.append((corridor, outer))
    walls.append(
        (
            [
                (x0_m, -half_depth_m),
                (x_end_m, -half_depth_m),
                (x_end_m, half_depth_m),
                (x0_m, half_depth_m),
            ],
            outer,
        )
    )
    # Each section's west wall with its doorway: from the corridor, or at a drawn height.
    keep: list[Box] = []
    for k, xa_m in enumerate(edges[:-1]):
        if k == 0:
            door_w_m = _r(rng.uniform(0.8, min(1.4, entry_w_m - 0.2)))
            door_y_m = _r(rng.uniform(-entry_w_m / 2 + 0.1, entry_w_m / 2 - 0.1 - door_w_m))
        else:
            door_w_m = _r(rng.uniform(0.8, 1.4))
            door_y_m = _r(rng.uniform(-half_depth_m + 2.0, half_depth_m - 2.0 - door_w_m))
        material = outer if k == 0 else inner
        walls.append(([(xa_m, -half_depth_m), (xa_m, door_y_m)], material))
        walls.append(([(xa_m, _r(door_y_m + door_w_m)), (xa_m, half_depth_m)], material))
        doors.append(((xa_m, door_y_m), (xa_m, _r(door_y_m + door_w_m))))
        # No furniture in front of a doorway, on either side.
        keep.append(
            ((_r(xa_m - 2.5), _r(door_y_m - 0.5)), (_r(xa_m + 2.5), _r(door_y_m + door_w_m + 0.5)))
        )
    boxes: list[Box] = list(keep)
    goal: Point = (0.0, 0.0)
    for kind, xa_m, xb_m in zip(sections, edges[:-1], edges[1:], strict=True):
        if kind == "hall":
            _pillars(rng, xa_m, xb_m, half_depth_m, boxes)
            _furniture(rng, xa_m, xb_m, half_depth_m, boxes, rng.randint(3, 7))
            goal = (
                _r(xb_m - rng.uniform(2.0, 4.0)),
                _r(rng.uniform(-half_depth_m + 2.0, half_depth_m - 2.0)),
            )
        elif kind == "room":
            goal = (
                _r((xa_m + xb_m) / 2),
                _r(rng.uniform(-half_depth_m + 2.0, half_depth_m - 2.0)),
            )
        else:
            goal = _racks(rng, xa_m, xb_m, half_depth_m, boxes)
    return {
        "walls": walls,
        "doors": doors,
        "boxes": boxes[len(keep) :],
        "goal": goal,
        "loss": loss,
    }
