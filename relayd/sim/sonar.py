"""The simulated P3-AT sonar ring: what each of a relay's 16 transducers hears (World.sonar_mm).

Each sonar reports the nearest surface inside its beam (relayd.sim.geometry.cone_range,
exact, not sampled by rays) among the walls and boxes within reach, the leader and the
other relays. A range is computed when it is first read: a P3-AT's SIP carries 8 of the
16, so the FakeRobot asks for half of them each time.

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
from collections.abc import Sequence
from typing import TYPE_CHECKING, overload

from relayd.core.geometry import SONAR_POSES
from relayd.sim.geometry import Segment, cone_range, polygon_segments

if TYPE_CHECKING:
    from relayd.sim.scenario import SonarSpec
    from relayd.sim.world import World


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
        "_n_walls",
        "_rng",
        "_s",
        "_segs",
        "_theta_deg",
        "_x",
        "_y",
    )

    def __init__(
        self,
        world: World,
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
        segs = [
            s
            for s in world.obstacles
            if not (
                max(s.x1, s.x2) < x - reach
                or min(s.x1, s.x2) > x + reach
                or max(s.y1, s.y2) < y - reach
                or min(s.y1, s.y2) > y + reach
            )
        ]
        self._n_walls = len(segs)
        self._edges = _edge_points(segs) if cfg.specular else []
        circles: list[tuple[float, float, float]] = []
        # Bodies (the leader, the other relays) count only when near: a centre `reach` + 1 m
        # away leaves even a robot's far corner (0.4 m) beyond every transducer's range
        # (each within 0.25 m of this robot's centre), so no cone could report it.
        lx, ly = world.leader.x_m, world.leader.y_m
        person = world.leader_kind != "robot"
        if math.hypot(lx - x, ly - y) < reach + 1.0 + (world.leader_radius_m if person else 0.0):
            lp = world.leader_polygon()
            if lp is not None:
                segs.extend(polygon_segments(lp))
            else:
                circles.append((lx, ly, world.leader_radius_m))
        for j, other in enumerate(world.relays):
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

    def _specular_targets(
        self, heading_deg: float
    ) -> tuple[list[Segment], list[tuple[float, float, float]]]:
        """What can echo to a transducer pointing at heading_deg: walls met within the
        grazing limit of their normal, every corner and free end, and the bodies."""
        h = math.radians(heading_deg)
        dx, dy = math.cos(h), math.sin(h)
        cos_lim = math.cos(math.radians(self._cfg.grazing_limit_deg))
        walls = self._segs[: self._n_walls]
        segs = [
            w
            for w in walls
            # |axis x wall direction| / |wall| is the cosine of the angle from the normal.
            if abs(dx * (w.y2 - w.y1) - dy * (w.x2 - w.x1)) >= cos_lim * w.length_m
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
