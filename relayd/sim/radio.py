"""Radio propagation of the simulated world: path loss, walls, shadowing, fading, antennas.

Received power of a link (docs/SIMULATOR.md; numbers from the paper, section IV-E, and the
802.11g standard's receiver sensitivity table):

    P = L0 - 10 n log10(d) - sum(wall losses) + shadowing + fading + antenna gains

L0 is the power at 1 m between two antennas at boresight (-15 dBm indoors, -20 dBm
outdoors, the paper's own measurements); antenna gains here are *relative* to that
reference (0 dB at boresight, the Yagi's cos^2 pattern off axis, omni APs 0 dB).
Shadowing is a seeded, smooth random field over the plane (a sum of random plane
waves, so its spatial correlation is Gaussian with the configured length and it costs
O(K) per query with no grid); fast fading is a seeded random draw per sample,
Rician when the direct path crosses no wall, Rayleigh otherwise. Rates and link
state are computed from the local-mean power (without fast fading), as 802.11 rate
adaptation averages over fades; the RSSI the Wi-Fi adapter and the APs report includes
fading averaged over a few frames (`fading_avg_frames`).

With `model = "dominant-path"` a link whose straight path crosses walls may instead take
the best path round corners and through openings (relayd/sim/dominant.py), whichever is
stronger; the antennas then hear it from that path's direction (`arrival_deg`).
"""

from __future__ import annotations

import math
import random
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from relayd.core.link.rates import RATE_TABLE_80211G, RATE_TABLE_80211N_1X1, RATE_TABLES  # noqa: F401 (re-exported)
from relayd.sim.dominant import CornerGraph
from relayd.sim.geometry import Point, Segment, crossings
from relayd.sim.zones import PathEnvironment, RadioZone, path_environment

MAC_EFFICIENCY = 0.5
#: Below this a hop is down (the slowest rate's sensitivity; -82 dBm in both tables).
HOP_DOWN_DBM = RATE_TABLE_80211G[-1][0]

DEFAULT_WALL_LOSS_DB: Mapping[str, float] = {
    "brick": 10.0,
    "light": 3.0,
    "concrete": 15.0,
    "glass": 2.0,
    "box": 3.0,
}
#: Airtime coupling of neighbouring hops (docs/SIMULATOR.md, "Multi-hop throughput").
DEFAULT_HOP_COUPLING = 0.2


def phy_rate_mbps(
    power_dbm: float, table: Sequence[tuple[float, float]] = RATE_TABLE_80211G
) -> float:
    """The fastest rate of `table` whose sensitivity `power_dbm` meets; 0 when the hop is down."""
    for sens, rate in table:
        if power_dbm >= sens:
            return rate
    return 0.0


def throughput_mbps(
    power_dbm: float, table: Sequence[tuple[float, float]] = RATE_TABLE_80211G
) -> float:
    """Application throughput of one hop alone: PHY rate times the MAC efficiency."""
    return phy_rate_mbps(power_dbm, table) * MAC_EFFICIENCY


def chain_throughput_mbps(
    hop_mbps: Sequence[float], coupling: float = DEFAULT_HOP_COUPLING
) -> float:
    """End-to-end throughput of a relay chain whose neighbouring hops share airtime.

    Carrying x Mbps end to end, hop k is busy x/T_k of the time (T_k: its throughput
    alone). Each relay's two radios sit a few decimetres apart in the 2.4 GHz band, so
    a hop also loses `coupling` of the airtime its neighbours use (0: independent
    channels, 1: one shared channel, where a two-hop chain halves the throughput).
    Hops further apart reuse the air. The largest x that keeps every hop within its
    airtime is

        x = min_k 1 / (1/T_k + coupling * sum_{j = k-1, k+1} 1/T_j)

    which is the weakest hop (T_k) with no relays and 0 when any hop is down.
    """
    n = len(hop_mbps)
    if n == 0 or any(t <= 0 for t in hop_mbps):
        return 0.0
    best = math.inf
    for k, t in enumerate(hop_mbps):
        load = 1.0 / t + coupling * sum(1.0 / hop_mbps[j] for j in (k - 1, k + 1) if 0 <= j < n)
        best = min(best, 1.0 / load)
    return round(best, 3)


def yagi_gain_db(off_axis_deg: float, floor_db: float = -20.0) -> float:
    """The Yagi's relative gain: 10 log10(cos^2) of the off-axis angle, floored (back lobe)."""
    a = abs(math.remainder(off_axis_deg, 360.0))
    if a >= 90.0:
        return floor_db
    c = math.cos(math.radians(a))
    if c <= 0.0:
        return floor_db
    return max(floor_db, 20.0 * math.log10(c))


def patch_gain_db(off_axis_deg: float, floor_db: float = -10.0) -> float:
    """The NanoStation's relative gain: the same cos^2 law with a shallower floor.

    A NanoStation loco M2 is an 8 dBi patch with a ~60 degree beam and a real back lobe;
    for the data link only its pointing error matters, so a modest pattern suffices.
    """
    return yagi_gain_db(off_axis_deg, floor_db)


@dataclass(frozen=True, slots=True)
class RadioParams:
    """Everything configurable about propagation (scenario `[radio]`)."""

    l0_dbm: float = -15.0
    exponent: float = 3.0
    wall_loss_db: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_WALL_LOSS_DB))
    shadow_sigma_db: float = 4.0
    shadow_corr_m: float = 2.0
    rician_k_db: float = 6.0
    fading: bool = True
    fading_avg_frames: int = 4
    noise_floor_dbm: float = -95.0
    yagi_floor_db: float = -20.0
    patch_floor_db: float = -10.0
    min_distance_m: float = 0.5
    phy: str = "802.11g"
    hop_coupling: float = DEFAULT_HOP_COUPLING

    @property
    def rate_table(self) -> tuple[tuple[float, float], ...]:
        return RATE_TABLES[self.phy]

    #: Per-zone environments (relayd/sim/zones.py); outside them the values above hold.
    zones: tuple[RadioZone, ...] = ()
    #: "wall-count" (the straight path, every wall on it charged) or "dominant-path" (the
    #: stronger of that and the best path round corners; relayd/sim/dominant.py).
    model: str = "wall-count"
    #: Dominant path: loss of one bend of 90 degrees (proportional to the turning angle).
    turn_loss_db: float = 10.0

    @classmethod
    def indoor(cls, **kw: object) -> RadioParams:
        return cls(**kw)  # type: ignore[arg-type]

    @classmethod
    def outdoor(cls, **kw: object) -> RadioParams:
        base: dict[str, object] = {"l0_dbm": -20.0, "exponent": 2.5}
        base.update(kw)
        return cls(**base)  # type: ignore[arg-type]


class ShadowField:
    """A smooth zero-mean, unit-variance Gaussian-like random field over the plane.

    Sum of K plane waves with wave vectors drawn from N(0, 1/corr^2) per axis and uniform
    phases: its autocorrelation is exp(-d^2 / (2 corr^2)), so two points `corr_m` apart
    are correlated 0.61 and points 2*corr apart 0.14.
    """

    __slots__ = ("_waves",)

    def __init__(self, seed: int, corr_m: float, waves: int = 48) -> None:
        rng = random.Random(seed)
        k = 1.0 / max(corr_m, 1e-6)
        amp = math.sqrt(2.0 / waves)
        self._waves = tuple(
            (rng.gauss(0.0, k), rng.gauss(0.0, k), rng.uniform(0.0, 2 * math.pi), amp)
            for _ in range(waves)
        )

    def value(self, x_m: float, y_m: float) -> float:
        cos = math.cos
        # A list, not a generator, for sum(): the same terms added in the same order, faster.
        return sum([a * cos(kx * x_m + ky * y_m + ph) for kx, ky, ph, a in self._waves])


#: Entries a Radio memo holds before it is emptied (a few seconds of a moving chain).
MEMO_MAX_ENTRIES = 512
#: Corner graphs a Radio keeps (one per set of walls: a timed door open or shut).
GRAPHS_KEPT = 4

#: A path's memo entry: gain-free local-mean power, wall loss (or turn loss of a bent
#: path), walls crossed, environment, and for a bent path its first and last bend.
PathInfo = tuple[float, float, int, PathEnvironment, tuple[Point, Point] | None]


class Radio:
    """Link budgets in one world: deterministic for a given seed and geometry.

    Memoised. Within one world tick the simulator asks about the same few links several
    times (the Yagi's sample, each hop's rate and reported level, the trace record) and
    nodes that stand still (the command center, a pausing leader, a stopped relay) give
    the same links tick after tick. Everything but the fading draw is a pure function of
    the two end points, the walls and the parameters, so it is kept per exact pair of
    points (and the shadowing per exact point): the same floats in, the same floats out,
    computed once. The memos are emptied when the walls change (a timed door) or the
    parameters are replaced, and when they reach MEMO_MAX_ENTRIES.
    """

    def __init__(self, params: RadioParams, walls: Iterable[Segment], seed: int = 0) -> None:
        self.params = params
        self._walls: tuple[Segment, ...] = tuple(walls)
        self._shadow = ShadowField(seed, params.shadow_corr_m)
        self._rng = random.Random(seed ^ 0x5EED)
        for w in self._walls:
            if w.material not in params.wall_loss_db:
                raise ValueError(f"wall material {w.material!r} has no loss in radio.wall_loss_db")
        #: (ax, ay, bx, by) -> PathInfo
        self._paths: dict[tuple[float, float, float, float], PathInfo] = {}
        self._shadow_at: dict[tuple[float, float], float] = {}
        self._memo_params = params
        if params.model not in ("wall-count", "dominant-path"):
            raise ValueError(f"radio.model {params.model!r}: wall-count or dominant-path")
        self._graphs: dict[tuple[Segment, ...], CornerGraph] = {}
        self._sees: dict[tuple[float, float], list[int]] = {}

    @property
    def walls(self) -> tuple[Segment, ...]:
        """What the radio paths cross now (the world swaps them when a timed door moves)."""
        return self._walls

    @walls.setter
    def walls(self, walls: Iterable[Segment]) -> None:
        self._walls = tuple(walls)
        self._paths.clear()
        self._sees.clear()

    def corner_graph(self) -> CornerGraph:
        """The bend points of the present walls and the chains between them (built once per
        set of walls: a timed door that opens and shuts again reuses the graph it had)."""
        g = self._graphs.get(self._walls)
        if g is None or g.per_90_db != self.params.turn_loss_db:
            if len(self._graphs) >= GRAPHS_KEPT:
                self._graphs.clear()
            g = self._graphs[self._walls] = CornerGraph(
                self._walls, self.params.turn_loss_db, self.params.exponent
            )
        return g

    def _seen(self, g: CornerGraph, p: Point) -> list[int]:
        key = (p[0], p[1])
        v = self._sees.get(key)
        if v is None:
            if len(self._sees) >= MEMO_MAX_ENTRIES:
                self._sees.clear()
            v = self._sees[key] = g.visible(key)
        return v

    def _bent(
        self, a: Point, b: Point, direct_db: float, exponent: float
    ) -> tuple[float, float, tuple[Point, Point]] | None:
        """The best path round corners if it beats the straight one's `direct_db` (its
        distance term plus its walls): (distance term, turn loss, first and last bend)."""
        g = self.corner_graph()
        if not g.nodes:
            return None
        bent = g.best(a, b, self._seen(g, a), self._seen(g, b))
        if bent is None:
            return None
        dist_db = 10.0 * exponent * math.log10(max(self.params.min_distance_m, bent.length_m))
        if dist_db + bent.turns_db >= direct_db:
            return None
        return dist_db, bent.turns_db, (bent.first, bent.last)

    def _path(self, a: Point, b: Point) -> PathInfo:
        """The link a-b's gain-free local-mean power, wall loss, walls crossed, environment,
        and (dominant path model, when a bent path wins) its first and last bend."""
        if self.params.model == "dominant-path" and (b[0], b[1]) < (a[0], a[1]):
            # One entry per link, whichever end asks (the Yagi asks relay first, the hop
            # front first): the same path, walked the other way.
            base, loss, n_walls, env, back = self._path(b, a)
            return base, loss, n_walls, env, None if back is None else (back[1], back[0])
        key = (a[0], a[1], b[0], b[1])
        if self.params is not self._memo_params:
            self._paths.clear()
            self._shadow_at.clear()
            self._memo_params = self.params
        hit = self._paths.get(key)
        if hit is not None:
            return hit
        p = self.params
        env = path_environment(
            a,
            b,
            p.zones,
            l0_dbm=p.l0_dbm,
            exponent=p.exponent,
            shadow_sigma_db=p.shadow_sigma_db,
            rician_k_db=p.rician_k_db,
        )
        hit_walls = crossings(a, b, self._walls)
        loss, n_walls = sum(p.wall_loss_db[w.material] for w in hit_walls), len(hit_walls)
        d = max(p.min_distance_m, math.hypot(b[0] - a[0], b[1] - a[1]))
        via: tuple[Point, Point] | None = None
        if n_walls and p.model == "dominant-path":
            dist_db = 10.0 * env.exponent * math.log10(d)
            bent = self._bent(a, b, dist_db + loss, env.exponent)
            if bent is not None:
                dist_db, loss, via = bent
                n_walls = 0
            base = env.l0_dbm - dist_db - loss + self.shadowing_db(a, b, env.shadow_sigma_db)
        else:
            # Summed in the order of the budget P = L0 - 10 n log10(d) - walls + shadowing (+ gain).
            base = (
                env.l0_dbm
                - 10.0 * env.exponent * math.log10(d)
                - loss
                + self.shadowing_db(a, b, env.shadow_sigma_db)
            )
        if len(self._paths) >= MEMO_MAX_ENTRIES:
            self._paths.clear()
        out = self._paths[key] = (base, loss, n_walls, env, via)
        return out

    def arrival_deg(self, at: Point, frm: Point) -> float:
        """World bearing, seen from `at`, of the way the signal from `frm` arrives: straight
        at `frm`, or at the last bend of a dominant path round corners (a signal that comes
        through a doorway points at the doorway)."""
        via = self._path(at, frm)[4]
        tx, ty = frm if via is None else via[0]
        return math.degrees(math.atan2(ty - at[1], tx - at[0]))

    def _shadow_value(self, pt: Point) -> float:
        v = self._shadow_at.get(pt)
        if v is None:
            if len(self._shadow_at) >= MEMO_MAX_ENTRIES:
                self._shadow_at.clear()
            v = self._shadow_at[pt] = self._shadow.value(pt[0], pt[1])
        return v

    def wall_loss_db(self, a: Point, b: Point) -> tuple[float, int]:
        """Total loss of the walls the direct path crosses, and how many it crosses (with the
        dominant-path model, when a path round corners wins: its turn loss and 0 walls)."""
        _, loss, n_walls, _, _ = self._path(a, b)
        return loss, n_walls

    def environment(self, a: Point, b: Point) -> PathEnvironment:
        """L0, n, sigma, K and the multipath penalty of the link a-b (per zone, else [radio]'s)."""
        return self._path(a, b)[3]

    def shadowing_db(self, a: Point, b: Point, sigma_db: float | None = None) -> float:
        """Slow shadowing of the link a-b: symmetric, smooth as either end moves."""
        s = (self._shadow_value((a[0], a[1])) + self._shadow_value((b[0], b[1]))) / math.sqrt(2.0)
        return (self.params.shadow_sigma_db if sigma_db is None else sigma_db) * s

    def mean_power_dbm(self, a: Point, b: Point, gain_db: float = 0.0) -> tuple[float, bool]:
        """Local-mean received power (no fast fading) and whether the path is line of sight."""
        base, _, n_walls, _, via = self._path(a, b)
        return base + gain_db, n_walls == 0 and via is None

    def rate_penalty_db(self, a: Point, b: Point) -> float:
        """SNR margin the link's multipath costs its rate (0 outside zones that set it)."""
        return self.environment(a, b).multipath_db if self.params.zones else 0.0

    def fading_db(self, los: bool, rician_k_db: float | None = None) -> float:
        """One fast-fading draw: Rician (K = rician_k_db) on LOS, Rayleigh otherwise, averaged
        over `fading_avg_frames` frames in linear power as an adapter's signal average is."""
        p = self.params
        if not p.fading:
            return 0.0
        k_db = p.rician_k_db if rician_k_db is None else rician_k_db
        k = 10.0 ** (k_db / 10.0) if los else 0.0
        los_amp = math.sqrt(k / (k + 1.0))
        sc = math.sqrt(1.0 / (2.0 * (k + 1.0)))
        frames = max(1, p.fading_avg_frames)
        total = 0.0
        g = self._rng.gauss
        for _ in range(frames):
            re = los_amp + sc * g(0.0, 1.0)
            im = sc * g(0.0, 1.0)
            total += re * re + im * im
        return 10.0 * math.log10(max(total / frames, 1e-9))

    def sample_dbm(self, a: Point, b: Point, gain_db: float = 0.0) -> float:
        """A reported RSSI: local mean plus a fast-fading draw, never below the noise floor."""
        mean, los = self.mean_power_dbm(a, b, gain_db)
        k_db = self.environment(a, b).rician_k_db if self.params.zones else None
        return max(self.params.noise_floor_dbm, mean + self.fading_db(los, k_db))


@dataclass(frozen=True, slots=True)
class Hop:
    """One hop of the chain, between node `front` and node `front + 1`."""

    front: int
    power_dbm: float
    rate_mbps: float  # the hop's throughput alone (PHY rate x MAC efficiency)
    walls: int
    phy_mbps: float = 0.0

    @property
    def up(self) -> bool:
        # A hop whose multipath leaves no rate is down even above the weakest sensitivity.
        return self.power_dbm >= HOP_DOWN_DBM and self.rate_mbps > 0


@dataclass(slots=True)
class LinkBudget:
    hops: list[Hop] = field(default_factory=list)
    #: airtime coupling of neighbouring hops (chain_throughput_mbps)
    coupling: float = DEFAULT_HOP_COUPLING

    @property
    def e2e_mbps(self) -> float:
        return chain_throughput_mbps([h.rate_mbps for h in self.hops], self.coupling)

    @property
    def broken(self) -> bool:
        return any(not h.up for h in self.hops)
