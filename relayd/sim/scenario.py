"""Scenario files: the TOML format of a simulated world, its loader and its validation.

A scenario names the geometry (walls as polylines with a material, boxes), the radio
environment, the command center, a scripted leader and the start pose of every relay.
The format is documented in docs/SIMULATOR.md; shipped scenarios live in
relayd/sim/scenarios/. Every validation error names the offending key
(`leader.waypoints.2.x: ...`), the same way `relayd check-config` does.
"""

from __future__ import annotations

import itertools
import tomllib
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from relayd.config.checks import loads_toml
from relayd.sim.geometry import Box, Segment, polygon_segments
from relayd.sim.radio import DEFAULT_HOP_COUPLING, DEFAULT_WALL_LOSS_DB, RadioParams
from relayd.sim.zones import RadioZone

Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]


class ScenarioError(Exception):
    """A scenario that cannot be loaded; `errors` lists every problem, each naming its key."""

    def __init__(self, errors: list[str]) -> None:
        super().__init__("; ".join(errors))
        self.errors = errors


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Waypoint(_Model):
    x: Finite
    y: Finite
    pause_s: NonNeg = 0.0


class SpeedChange(_Model):
    """From clock second `at_s` on, walk at `speed_m_s` (a leader's speed profile)."""

    at_s: NonNeg
    speed_m_s: Positive


def _profile_sorted(v: list[SpeedChange]) -> list[SpeedChange]:
    times = [c.at_s for c in v]
    if times != sorted(times):
        raise ValueError("speed_profile entries must be in time order")
    return v


class LeaderSpec(_Model):
    kind: Literal["person", "robot"] = "person"
    speed_m_s: Positive = 0.2
    start_s: NonNeg = 0.0
    radius_m: Positive = 0.25
    waypoints: list[Waypoint] = Field(min_length=1)
    #: Speed changes along the walk (clock time); speed_m_s holds until the first.
    speed_profile: list[SpeedChange] = Field(default_factory=list)

    _profile = field_validator("speed_profile")(_profile_sorted)


class NodeSpec(_Model):
    """The command center: a fixed node, or one carried along waypoints (`drift`)."""

    x: Finite
    y: Finite
    #: Carried from (x, y) through these at speed_m_s, starting at start_s; empty: fixed.
    waypoints: list[Waypoint] = Field(default_factory=list)
    speed_m_s: Positive = 0.05
    start_s: NonNeg = 0.0


class _Timed(_Model):
    """A timed world event: present from appear_s (default: from the start) until disappear_s."""

    appear_s: NonNeg = 0.0
    disappear_s: NonNeg | None = None

    @model_validator(mode="after")
    def _window(self) -> _Timed:
        if self.disappear_s is not None and self.disappear_s <= self.appear_s:
            raise ValueError("disappear_s must be after appear_s")
        return self

    @property
    def timed(self) -> bool:
        return self.appear_s > 0 or self.disappear_s is not None


class WallSpec(_Timed):
    points: list[tuple[Finite, Finite]] = Field(min_length=2)
    material: str = "brick"
    closed: bool = False


class BoxSpec(_Timed):
    min: tuple[Finite, Finite]
    max: tuple[Finite, Finite]
    material: str = "box"

    @model_validator(mode="after")
    def _ordered(self) -> BoxSpec:
        if not (self.min[0] < self.max[0] and self.min[1] < self.max[1]):
            raise ValueError("box min must be below and left of max")
        return self


class RelaySpec(_Model):
    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_-]+$")
    x: Finite
    y: Finite
    theta_deg: Finite = 0.0
    control: dict[str, Any] = Field(default_factory=dict)
    #: This relay's scan antenna (relayd/sim/antennas.py); unset: the scenario's `[scan] pattern`.
    pattern: str | None = None


class ZoneSpec(_Model):
    """One polygon with its own radio environment (relayd/sim/zones.py)."""

    name: str = Field(min_length=1)
    polygon: list[tuple[Finite, Finite]] = Field(min_length=3)
    l0_dbm: Finite | None = None
    exponent: Positive | None = None
    shadow_sigma_db: NonNeg | None = None
    rician_k_db: Finite | None = None
    multipath_db: NonNeg = 0.0


class RadioSpec(_Model):
    l0_dbm: Finite | None = None
    exponent: Positive | None = None
    wall_loss_db: dict[str, NonNeg] = Field(default_factory=dict)
    shadow_sigma_db: NonNeg = 4.0
    shadow_corr_m: Positive = 2.0
    rician_k_db: Finite = 6.0
    fading: bool = True
    fading_avg_frames: Annotated[int, Field(ge=1, le=1000)] = 4
    noise_floor_dbm: Finite = -95.0
    yagi_floor_db: Annotated[float, Field(le=0)] = -20.0
    patch_floor_db: Annotated[float, Field(le=0)] = -10.0
    phy: Literal["802.11g", "802.11n-1x1"] = "802.11g"
    hop_coupling: Annotated[float, Field(ge=0, le=1)] = DEFAULT_HOP_COUPLING
    zones: list[ZoneSpec] = Field(default_factory=list)
    #: The straight path through the walls, or the stronger of that and the best path round
    #: corners and through doorways (relayd/sim/dominant.py).
    model: Literal["wall-count", "dominant-path"] = "wall-count"
    #: Dominant path: the loss of one 90-degree bend (proportional to the turning angle).
    turn_loss_db: Annotated[float, Field(ge=0, le=60)] = 10.0


class MapWallOverride(_Model):
    """A different material for one LINES entry of the map (its line number in the file)."""

    line: Annotated[int, Field(ge=1)]
    material: str


class SonarSpec(_Model):
    """The simulated sonar ring: one exact range per sonar (see `World.sonar_mm`)."""

    beam_deg: Annotated[float, Field(gt=0, le=60)] = 30.0
    noise_mm: NonNeg = 0.0
    max_range_m: Positive = 5.0
    min_range_m: NonNeg = 0.1
    #: Smooth walls echo only near normal incidence; corners and wall ends always echo;
    #: now and then a transducer hears its neighbour's echo (relayd/sim/sonar.py).
    specular: bool = False
    grazing_limit_deg: Annotated[float, Field(gt=0, lt=90)] = 35.0
    crosstalk_prob: Annotated[float, Field(ge=0, le=1)] = 0.02


class Scenario(_Model):
    """A validated scenario."""

    name: str = Field(min_length=1)
    description: str = ""
    environment: Literal["indoor", "outdoor"] = "indoor"
    duration_s: Positive = 300.0
    relays: Annotated[int, Field(ge=0, le=8)] = 1
    goal_radius_m: Positive = 0.5
    #: keep running this long (clock s) after the leader reaches its goal, so relays settle
    settle_after_goal_s: NonNeg = 10.0
    tick_hz: Annotated[float, Field(gt=0, le=100)] = 20.0
    command_center: NodeSpec
    leader: LeaderSpec
    relay: list[RelaySpec] = Field(default_factory=list)
    walls: list[WallSpec] = Field(default_factory=list)
    boxes: list[BoxSpec] = Field(default_factory=list)
    radio: RadioSpec = RadioSpec()
    sonar: SonarSpec = SonarSpec()
    control: dict[str, Any] = Field(default_factory=dict)
    scan: dict[str, Any] = Field(default_factory=dict)
    #: Keys of the daemon's [recovery] section for every relay (the bench overrides enabled).
    recovery: dict[str, Any] = Field(default_factory=dict)
    #: Keys of the daemon's [avoidance] section for every relay (unset: its defaults).
    avoidance: dict[str, Any] = Field(default_factory=dict)
    #: An ARIA map the world was read from (relayd/sim/mapscenario.py; the resolved path).
    map: str | None = None
    #: The material of the map's LINES, and per-line exceptions.
    map_material: str = "brick"
    map_walls: list[MapWallOverride] = Field(default_factory=list)
    #: The map's DATA points: sonar-visible solid discs ("points") or left out ("off").
    map_points: Literal["points", "off"] = "points"
    #: Leader waypoints joined by the A* planner through the map ("plan") or as given.
    map_route: Literal["plan", "straight"] = "plan"
    #: How far a planned route keeps from the map's walls and points (m).
    map_clearance_m: Annotated[float, Field(gt=0, le=2, allow_inf_nan=False)] = 0.4
    #: Point obstacles (x, y) of radius point_radius_m (a map's DATA; none by default).
    points: list[tuple[Finite, Finite]] = Field(default_factory=list)
    point_radius_m: Positive = 0.01

    @field_validator("relay")
    @classmethod
    def _unique_names(cls, v: list[RelaySpec]) -> list[RelaySpec]:
        names = [r.name for r in v]
        if len(set(names)) != len(names):
            raise ValueError("relay names must be unique")
        return v

    @model_validator(mode="after")
    def _consistent(self) -> Scenario:
        for problem in scenario_problems(self.model_dump()):
            raise ValueError(problem)
        return self

    def daemon_scan(self) -> dict[str, Any]:
        """The `[scan]` table the relays' daemons get: without `pattern`, which is the
        simulated antenna's (relayd/sim/antennas.py), not a daemon key."""
        return {k: v for k, v in self.scan.items() if k != "pattern"}

    def relay_pattern(self, i: int) -> str | None:
        """The family pattern relay i scans with (None: the simulator's own Yagi)."""
        own = self.relay[i].pattern if i < len(self.relay) else None
        shared = self.scan.get("pattern")
        return own if own is not None else (shared if isinstance(shared, str) else None)

    def wall_losses(self) -> dict[str, float]:
        out = dict(DEFAULT_WALL_LOSS_DB)
        out.update(self.radio.wall_loss_db)
        return out

    def radio_params(self) -> RadioParams:
        r = self.radio
        indoor = self.environment == "indoor"
        return RadioParams(
            l0_dbm=r.l0_dbm if r.l0_dbm is not None else (-15.0 if indoor else -20.0),
            exponent=r.exponent if r.exponent is not None else (3.0 if indoor else 2.5),
            wall_loss_db=self.wall_losses(),
            shadow_sigma_db=r.shadow_sigma_db,
            shadow_corr_m=r.shadow_corr_m,
            rician_k_db=r.rician_k_db,
            fading=r.fading,
            fading_avg_frames=r.fading_avg_frames,
            noise_floor_dbm=r.noise_floor_dbm,
            yagi_floor_db=r.yagi_floor_db,
            patch_floor_db=r.patch_floor_db,
            phy=r.phy,
            hop_coupling=r.hop_coupling,
            model=r.model,
            turn_loss_db=r.turn_loss_db,
            zones=tuple(
                RadioZone(
                    z.name,
                    tuple(z.polygon),
                    z.l0_dbm,
                    z.exponent,
                    z.shadow_sigma_db,
                    z.rician_k_db,
                    z.multipath_db,
                )
                for z in r.zones
            ),
        )

    def wall_segments(self) -> list[Segment]:
        """The walls present the whole run (timed ones: `timed_obstacles`)."""
        out: list[Segment] = []
        for w in self.walls:
            if not w.timed:
                out.extend(_wall_segments(w))
        return out

    def box_shapes(self) -> list[Box]:
        """The boxes present the whole run (timed ones: `timed_obstacles`)."""
        return [_box(b) for b in self.boxes if not b.timed]

    def static_segments(self) -> list[Segment]:
        """Every wall and box outline present the whole run, walls first: what the radio
        and the sonar meet (timed ones: `timed_obstacles`)."""
        return self.wall_segments() + [s for b in self.box_shapes() for s in b.segments()]

    def timed_obstacles(self) -> list[tuple[float, float | None, tuple[Segment, ...]]]:
        """(appear_s, disappear_s, outline) of every timed wall and box: doors and the like."""
        out: list[tuple[float, float | None, tuple[Segment, ...]]] = []
        for w in self.walls:
            if w.timed:
                out.append((w.appear_s, w.disappear_s, tuple(_wall_segments(w))))
        for b in self.boxes:
            if b.timed:
                out.append((b.appear_s, b.disappear_s, _box(b).segments()))
        return out

    def with_relays(self, n: int) -> Scenario:
        """The same world with the first `n` relays (counted from the leader backwards)."""
        if not 0 <= n <= len(self.relay):
            raise ScenarioError(
                [f"relays: {n} asked, scenario {self.name!r} has {len(self.relay)} start poses"]
            )
        return self.model_copy(update={"relays": n})


def _wall_segments(w: WallSpec) -> list[Segment]:
    pts = list(w.points)
    if w.closed:
        return list(polygon_segments(pts, w.material))
    return [Segment(a[0], a[1], b[0], b[1], w.material) for a, b in itertools.pairwise(pts)]


def _box(b: BoxSpec) -> Box:
    return Box(b.min[0], b.min[1], b.max[0], b.max[1], b.material)


def _messages(exc: ValidationError, prefix: str = "") -> list[str]:
    out = []
    for e in exc.errors():
        loc = ".".join(str(p) for p in (prefix, *e["loc"]) if p != "")
        msg = e["msg"].removeprefix("Value error, ")
        out.append(f"{loc}: {msg}" if loc else msg)
    return out


def _list(v: Any) -> list[Any]:
    return v if isinstance(v, list) else []


def _dict(v: Any) -> dict[str, Any]:
    return v if isinstance(v, dict) else {}


def scenario_problems(data: dict[str, Any]) -> list[str]:
    """The rules between keys, on the raw document, so they are reported with the schema errors."""
    out: list[str] = []
    losses = set(DEFAULT_WALL_LOSS_DB) | set(_dict(_dict(data.get("radio")).get("wall_loss_db")))
    for group in ("walls", "boxes"):
        for i, item in enumerate(_list(data.get(group))):
            material = _dict(item).get("material")
            if isinstance(material, str) and material not in losses:
                out.append(
                    f"{group}.{i}.material: unknown material {material!r} (known: {', '.join(sorted(losses))})"
                )
    for key, material in [("map_material", data.get("map_material"))] + [
        (f"map_walls.{i}.material", _dict(o).get("material"))
        for i, o in enumerate(_list(data.get("map_walls")))
    ]:
        if isinstance(material, str) and material not in losses:
            out.append(f"{key}: unknown material {material!r} (known: {', '.join(sorted(losses))})")
    out += _pattern_problems(data)
    relays, starts = data.get("relays", 1), _list(data.get("relay"))
    if isinstance(relays, int) and not isinstance(relays, bool) and relays > len(starts):
        out.append(f"relays: relays = {relays} but only {len(starts)} [[relay]] start poses")
    return out


def _pattern_problems(data: dict[str, Any]) -> list[str]:
    """`[scan] pattern` and each relay's `pattern` must name one of the simulator's antennas."""
    from relayd.sim.antennas import FAMILY

    named = [("scan.pattern", _dict(data.get("scan")).get("pattern"))]
    named += [
        (f"relay.{i}.pattern", _dict(r).get("pattern"))
        for i, r in enumerate(_list(data.get("relay")))
    ]
    return [
        f"{key}: unknown antenna pattern {name!r} (known: {', '.join(FAMILY)})"
        for key, name in named
        if name is not None and name not in FAMILY
    ]


def _daemon_sections(data: dict[str, Any]) -> list[str]:
    """`control`, `scan`, `recovery` and `avoidance` tables (and each relay's `control`)
    checked as the daemon will check them."""
    from relayd.config.model import (
        AvoidanceSettings,
        ControlSettings,
        RecoverySettings,
        ScanSettings,
    )

    out: list[str] = []
    base = _dict(data.get("control"))
    sections: tuple[tuple[str, Any, dict[str, Any]], ...] = (
        ("control", ControlSettings, base),
        (
            "scan",
            ScanSettings,
            {k: v for k, v in _dict(data.get("scan")).items() if k != "pattern"},
        ),
        ("recovery", RecoverySettings, _dict(data.get("recovery"))),
        ("avoidance", AvoidanceSettings, _dict(data.get("avoidance"))),
    )
    for key, model, doc in sections:
        try:
            model.model_validate(doc)
        except ValidationError as exc:
            out += _messages(exc, key)
    for i, relay in enumerate(_list(data.get("relay"))):
        own = _dict(_dict(relay).get("control"))
        if not own:
            continue
        try:
            ControlSettings.model_validate({**base, **own})
        except ValidationError as exc:
            # Only what this relay adds: errors of the shared table are reported once, above.
            inherited = tuple(f"relay.{i}.control.{k}:" for k in base if k not in own)
            out += [m for m in _messages(exc, f"relay.{i}.control") if not m.startswith(inherited)]
    return out


def parse_scenario(data: dict[str, Any]) -> Scenario:
    """Validate a scenario document: every error at once, each naming its key."""
    problems = scenario_problems(data) + _daemon_sections(data)
    try:
        scenario = Scenario.model_validate(data)
        schema: list[str] = []
    except ValidationError as exc:
        schema = _messages(exc)
    errors = [m for m in schema if m not in problems] + problems
    if errors:
        raise ScenarioError(errors)
    return scenario


def builtin_names() -> list[str]:
    folder = resources.files("relayd.sim") / "scenarios"
    return sorted(
        p.name.removesuffix(".toml") for p in folder.iterdir() if p.name.endswith(".toml")
    )


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load a shipped scenario by name (`corridor`) or any scenario file by path."""
    text: str
    p = Path(name_or_path)
    from relayd.sim.generate import GenerateError, generate, parse_ref

    try:
        ref = parse_ref(str(name_or_path))
        if ref is not None:
            return parse_scenario(tomllib.loads(generate(*ref)))
    except GenerateError as exc:
        raise ScenarioError([str(exc)]) from None
    if p.suffix == ".toml" or p.exists():
        try:
            raw = p.read_bytes()
        except OSError as exc:
            raise ScenarioError([f"{p}: {exc.strerror or exc}"]) from None
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            from relayd.config.checks import undecodable

            raise ScenarioError([undecodable(raw, exc)]) from None
    else:
        res = resources.files("relayd.sim") / "scenarios" / f"{name_or_path}.toml"
        if not res.is_file():
            raise ScenarioError(
                [
                    f"scenario: no scenario named {str(name_or_path)!r} "
                    f"(shipped: {', '.join(builtin_names())})"
                ]
            )
        text = res.read_text(encoding="utf-8")
    try:
        data = loads_toml(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError([f"{name_or_path}: not valid TOML: {exc}"]) from None
    if "map" in data:
        from relayd.sim.mapscenario import with_map

        base = p.parent if p.exists() else Path.cwd()
        data = with_map(data, base / str(data["map"]))
    return parse_scenario(data)
