"""Per-zone radio environments: L0, n, shadowing, fading and multipath that change with the place.

A scenario may split its plane into polygons (`[[radio.zones]]`, docs/SIMULATOR.md),
each with its own path-loss intercept and exponent, shadowing sigma, Rician K and a
multipath penalty; outside every zone the scenario's `[radio]` values hold. The
paper's conclusion asks for exactly this: a relay in a dense space, with more fading,
shadowing and multipath, should keep a smaller disk than one in open space.

Decisions:
- **A link takes the environment of the ground it crosses**: its parameters are the
  average over `PATH_SAMPLES` evenly spaced points of the straight path (each point
  the first zone containing it, or the defaults), i.e. weighted by the share of the
  path in each zone. A hall-to-corridor hop is part hall, part corridor; the value
  changes continuously as either end moves, and the link stays symmetric.
- **Multipath** (`multipath_db`) is a loss of *rate*, not of signal: a long delay
  spread costs the receiver SNR margin (inter-symbol interference, retries) that
  RSSI does not show. The hop's rate is chosen from the local mean minus this
  penalty; the RSSI reported is not lowered. This is what a relay can only learn
  from its radio's rates (relayd/core/link/model.py), never from RSSI alone.
- **Fading** per zone is the Rician K on a line-of-sight path (lower K: deeper
  fades); a path through walls is Rayleigh everywhere, as before.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from relayd.sim.geometry import Point, point_in_polygon

#: Points along a link's path that decide its environment.
PATH_SAMPLES = 32


@dataclass(frozen=True, slots=True)
class RadioZone:
    """One polygon's radio environment; None keeps the scenario's `[radio]` value."""

    name: str
    polygon: tuple[Point, ...]
    l0_dbm: float | None = None
    exponent: float | None = None
    shadow_sigma_db: float | None = None
    rician_k_db: float | None = None
    multipath_db: float = 0.0
    #: The polygon's bounding box (x_min, y_min, x_max, y_max): the cheap test before the exact one.
    bbox: tuple[float, float, float, float] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        xs = [p[0] for p in self.polygon]
        ys = [p[1] for p in self.polygon]
        object.__setattr__(self, "bbox", (min(xs), min(ys), max(xs), max(ys)))


@dataclass(frozen=True, slots=True)
class PathEnvironment:
    """The environment a link sees: averaged over its path."""

    l0_dbm: float
    exponent: float
    shadow_sigma_db: float
    rician_k_db: float
    multipath_db: float


def zone_at(point: Point, zones: Sequence[RadioZone]) -> RadioZone | None:
    """The first zone containing the point (scenario order decides overlaps), or None."""
    x, y = point
    for z in zones:
        x0, y0, x1, y1 = z.bbox
        if x0 <= x <= x1 and y0 <= y <= y1 and point_in_polygon(point, z.polygon):
            return z
    return None


def path_environment(
    a: Point,
    b: Point,
    zones: Sequence[RadioZone],
    *,
    l0_dbm: float,
    exponent: float,
    shadow_sigma_db: float,
    rician_k_db: float,
) -> PathEnvironment:
    """The defaults, or the share-weighted average of the zones along the path a-b."""
    if not zones:
        return PathEnvironment(l0_dbm, exponent, shadow_sigma_db, rician_k_db, 0.0)
    outside = (l0_dbm, exponent, shadow_sigma_db, rician_k_db, 0.0)
    # Each zone's five values worked out once per call, not per sample point.
    inside = {
        id(z): (
            l0_dbm if z.l0_dbm is None else z.l0_dbm,
            exponent if z.exponent is None else z.exponent,
            shadow_sigma_db if z.shadow_sigma_db is None else z.shadow_sigma_db,
            rician_k_db if z.rician_k_db is None else z.rician_k_db,
            z.multipath_db,
        )
        for z in zones
    }
    s0 = s1 = s2 = s3 = s4 = 0.0
    for i in range(PATH_SAMPLES):
        f = (i + 0.5) / PATH_SAMPLES
        z = zone_at((a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])), zones)
        v0, v1, v2, v3, v4 = outside if z is None else inside[id(z)]
        # Summed sample by sample, in path order, as a running total per value.
        s0 += v0
        s1 += v1
        s2 += v2
        s3 += v3
        s4 += v4
    n = float(PATH_SAMPLES)
    return PathEnvironment(s0 / n, s1 / n, s2 / n, s3 / n, s4 / n)
