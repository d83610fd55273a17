"""The simulated P3-AT sonar ring: what each of a relay's 16 transducers hears (World.sonar_mm).

Each sonar reports the nearest surface inside its beam (relayd.sim.geometry.cone_range,
exact, not sampled by rays) among the walls and boxes within reach, the leader and the
other relays. A range is computed when it is first read: a P3-AT's SIP carries 8 of the
16, so the FakeRobot asks for half of them each time. The world hands the ring a
`SonarScene`, plain values of that instant; this module knows nothing of the World.

With `[sonar] specular = true` the ring misses things as a real one does (docs/
SIMULATOR.md, "Specular sonar"): a smooth wall or box side echoes only when the
transducer's axis is within `grazing_limit_deg` of the wall's normal; beyond it the
ping glances off and the wall is silent, though its corners and free ends (which send
sound back from any angle) still echo. And with probability `crosstalk_prob` a reading
is the nearer of its own echo and a neighbouring transducer's (seeded, the world's
sonar random stream). Bodies (the person, the other robots) echo as before.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypeVar, overload

from relayd.core.geometry import ROBOT_LENGTH_M, ROBOT_WIDTH_M, SONAR_POSES
from relayd.sim.geometry import Polygon, Segment, cone_range, footprint, polygon_segments

if TYPE_CHECKING:
    from relayd.sim.scenario import SonarSpec

T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class Body:
    """A P3-AT's body at one instant: its centre and heading."""

    x_m: float
    y_m: float
    theta_deg: float

    def polygon(self) -> Polygon:
        return footprint(self.x_m, self.y_m, self.theta_deg, ROBOT_LENGTH_M, ROBOT_WIDTH_M)


#: A box query (x0, y0, x1, y1) answered from the world's spatial index.
BoxQuery = Callable[[float, float, float, float], Sequence[T]]


@dataclass(frozen=True, slots=True)
class SonarScene:
    """What could echo at one instant (World.sonar_scene): the walls, boxes and timed
    obstacles present, a map's scan points, the leader (a robot's footprint, or a person's
    disc) and every relay. The fixed parts come as box queries on the world's index, so a
    map of thousands of lines costs a sonar only what lies near it."""

    #: The obstacles that may meet a box, in the world's order (every one, unindexed).
    obstacles_near: BoxQuery[Segment]
    #: The map points (x, y, radius) that may meet a box; None: the map has none.
    points_near: BoxQuery[tuple[float, float, float]] | None
    #: Every map point's radius (the query's box is padded by it).
    point_radius_m: float
    leader_x_m: float
    leader_y_m: float
    leader_radius_m: float
    #: The leader's footprint when it is a robot; None: a person, a disc of leader_radius_m.
    leader_body: Body | None
    relays: tuple[Body, ...]


class SonarReadings(Sequence[int]):
    """Relay i's 16 sonar ranges at one pose (World.sonar_mm), each computed when read.

    What could echo (walls and boxes within reach, the leader, the other relays) is
    gathered when it is made, so every range is of the world at that instant.
    """

    __slots__ = (
        "_c",
        "_cfg",
        "_circles",
        "_echo",
        "_edges",
        "_got",
        "_grazing",
        "_n_walls",
        "_point_radius_m",
        "_points",  # the scene's point query, when the map has points
        "_rng",
        "_s",
        "_segs",
        "_theta_deg",
        "_x",
        "_y",
    )

    def __init__(
        self,
        scene: SonarScene,
        i: int,
        x_mm: float,
        y_mm: float,
        theta_deg: float,
        *,
        cfg: SonarSpec,
        rng: random.Random,
    ) -> None:
        self._cfg = cfg
        x, y = self._x, self._y = x_mm / 1000.0, y_mm / 1000.0
        reach = cfg.max_range_m + 0.5
        x0, y0, x1, y1 = x - reach, y - reach, x + reach, y + reach
        # A wall wholly on one side of the reach box cannot echo (both ends beyond it:
        # the same test as max(ends) < x0 and its kin, without the calls).
        segs = [
            s
            for s in scene.obstacles_near(x0, y0, x1, y1)
            if not (
                (s.x1 < x0 and s.x2 < x0)
                or (s.x1 > x1 and s.x2 > x1)
                or (s.y1 < y0 and s.y2 < y0)
                or (s.y1 > y1 and s.y2 > y1)
            )
        ]
        self._n_walls = len(segs)
        self._edges = _edge_points(segs) if cfg.specular else []
        # Each wall's direction and its grazing threshold (the limit's cosine times its
        # length), worked out once per ring rather than once per transducer (the same
        # floats: _specular_targets).
        cos_lim = math.cos(math.radians(cfg.grazing_limit_deg))
        self._grazing = (
            [(s, s.y2 - s.y1, s.x2 - s.x1, cos_lim * s.length_m) for s in segs]
            if cfg.specular
            else []
        )
        # A map's scan points within reach echo as small discs (each sonar keeps those
        # that can meet its cone: _range_mm).
        self._points = scene.points_near
        self._point_radius_m = scene.point_radius_m
        circles: list[tuple[float, float, float]] = []
        # Bodies (the leader, the other relays) count only when near: a centre `reach` + 1 m
        # away leaves even a robot's far corner (0.4 m) beyond every transducer's range
        # (each within 0.25 m of this robot's centre), so no cone could report it.
        lx, ly = scene.leader_x_m, scene.leader_y_m
        body = scene.leader_body
        if math.hypot(lx - x, ly - y) < reach + 1.0 + (
            scene.leader_radius_m if body is None else 0.0
        ):
            if body is not None:
                segs.extend(polygon_segments(body.polygon()))
            else:
                circles.append((lx, ly, scene.leader_radius_m))
        for j, other in enumerate(scene.relays):
            if j != i and math.hypot(other.x_m - x, other.y_m - y) < reach + 1.0:
                segs.extend(polygon_segments(other.polygon()))
        self._segs, self._circles = segs, circles
        self._theta_deg = theta_deg
        a = math.radians(theta_deg)
        self._c, self._s = math.cos(a), math.sin(a)
        self._rng = rng
        self._got: list[int | None] = [None] * len(SONAR_POSES)
        self._echo: list[int | None] = [None] * len(SONAR_POSES)

    def __len__(self) -> int:
        return len(SONAR_POSES)

    @overload
    def __getitem__(self, k: int) -> int: ...
    @overload
    def __getitem__(self, k: slice) -> list[int]: ...

    def __getitem__(self, k: int | slice) -> int | list[int]:
        if isinstance(k, slice):
            return [self[j] for j in range(len(SONAR_POSES))[k]]
        got = self._got[k]
        if got is None:
            got = self._got[k] = self._range_mm(k)
        return got

    def _range_mm(self, k: int) -> int:
        cfg = self._cfg
        if not cfg.specular:
            return self._plain_mm(k)
        got = self._specular_mm(k)
        if cfg.crosstalk_prob > 0 and self._rng.random() < cfg.crosstalk_prob:
            # The neighbour's ping, glanced off a wall, reaches this transducer first.
            n = len(SONAR_POSES)
            other = self._specular_mm((k + self._rng.choice((-1, 1))) % n)
            got = min(got, other)
        return got

    def _specular_mm(self, k: int) -> int:
        got = self._echo[k]
        if got is None:
            got = self._echo[k] = self._plain_mm(k, specular=True)
        return got

    def _plain_mm(self, k: int, specular: bool = False) -> int:
        cfg, c, s = self._cfg, self._c, self._s
        pose = SONAR_POSES[k]
        sx, sy, sh = pose.x_mm, pose.y_mm, pose.heading_deg
        ox = self._x + (c * sx - s * sy) / 1000.0
        oy = self._y + (s * sx + c * sy) / 1000.0
        segs, circles = self._segs, self._circles
        if specular:
            segs, circles = self._specular_targets(self._theta_deg + sh)
        if self._points is not None:
            circles = self._cone_points(ox, oy, self._theta_deg + sh) + circles
        best = cone_range(
            ox, oy, self._theta_deg + sh, cfg.beam_deg / 2.0, cfg.max_range_m, segs, circles
        )
        max_mm = round(cfg.max_range_m * 1000)
        if best is None:
            return max_mm
        mm = best * 1000.0
        if cfg.noise_mm > 0:
            mm += self._rng.gauss(0.0, cfg.noise_mm)
        return round(min(max_mm, max(round(cfg.min_range_m * 1000), mm)))

    def _cone_points(
        self, ox: float, oy: float, heading_deg: float
    ) -> list[tuple[float, float, float]]:
        """The map points that can meet this sonar's cone: a disc wholly outside either
        edge's half-plane, or farther than the range, cannot give cone_range a hit (its
        centre is outside the cone and neither edge ray reaches it), so leaving it out
        changes no range; a disc over the transducer is kept (a hit at 0)."""
        h = math.radians(heading_deg)
        w = math.radians(self._cfg.beam_deg / 2.0)
        # The inward normals of cone_range's two edges.
        nlx, nly = math.sin(h + w), -math.cos(h + w)
        nrx, nry = -math.sin(h - w), math.cos(h - w)
        far = self._cfg.max_range_m
        hypot = math.hypot
        # The sector lies inside the quadrilateral apex, both range ends, and the point
        # where the two range ends' tangents meet (far / cos w along the heading).
        xs = [ox, ox + far * math.cos(h - w), ox + far * math.cos(h + w)]
        ys = [oy, oy + far * math.sin(h - w), oy + far * math.sin(h + w)]
        tip = far / math.cos(w)
        xs.append(ox + tip * math.cos(h))
        ys.append(oy + tip * math.sin(h))
        assert self._points is not None
        pad = self._point_radius_m
        near = self._points(min(xs) - pad, min(ys) - pad, max(xs) + pad, max(ys) + pad)
        return [
            c
            for c in near
            if nlx * (c[0] - ox) + nly * (c[1] - oy) >= -c[2]
            and nrx * (c[0] - ox) + nry * (c[1] - oy) >= -c[2]
            and hypot(c[0] - ox, c[1] - oy) - c[2] <= far
        ]

    def _specular_targets(
        self, heading_deg: float
    ) -> tuple[list[Segment], list[tuple[float, float, float]]]:
        """What can echo to a transducer pointing at heading_deg: walls met within the
        grazing limit of their normal, every corner and free end, and the bodies."""
        h = math.radians(heading_deg)
        dx, dy = math.cos(h), math.sin(h)
        segs = [
            w
            for w, wy, wx, limit in self._grazing
            # |axis x wall direction| / |wall| is the cosine of the angle from the normal.
            if abs(dx * wy - dy * wx) >= limit
        ]
        segs.extend(self._segs[self._n_walls :])
        return segs, self._circles + self._edges


def _edge_points(segs: Sequence[Segment]) -> list[tuple[float, float, float]]:
    """Corners and free ends of the walls (as points, radius 0): every segment end except
    where exactly two segments continue one another in a straight line."""
    ends: dict[tuple[float, float], list[Segment]] = {}
    for w in segs:
        ends.setdefault((w.x1, w.y1), []).append(w)
        ends.setdefault((w.x2, w.y2), []).append(w)
    out = []
    for (x, y), ws in ends.items():
        if len(ws) == 2:
            a, b = ws
            if abs((a.x2 - a.x1) * (b.y2 - b.y1) - (a.y2 - a.y1) * (b.x2 - b.x1)) < 1e-9 * (
                a.length_m * b.length_m
            ):
                continue
        out.append((x, y, 0.0))
    return out
