"""The simulator's shortcuts give exactly, bit for bit, what they stand in for.

The world computes some things faster than their plain definition: relayd/sim/geometry.py's
written-out cone and bounding-box pre-tests, the radio's memo, each zone's box worked out
once, the collision check's pre-test, sonar ranges computed when read. A run must not
change by a single bit for it (bench/simspeed.py compares whole runs against another
checkout); each shortcut is checked here against its definition.
"""

from __future__ import annotations

import dataclasses
import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from relayd.core.geometry import ROBOT_LENGTH_M, ROBOT_WIDTH_M, SONAR_POSES
from relayd.runtime import vtime
from relayd.sim.geometry import (
    Segment,
    _clip_to_half_plane,
    cone_range,
    crossings,
    footprint,
    point_in_polygon,
    point_segment_distance,
    polygon_hits_circle,
    polygon_hits_segment,
    polygon_segments,
    polygons_overlap,
    ray_circle_distance,
    segments_intersect,
)
from relayd.sim.radio import MEMO_MAX_ENTRIES, Radio, RadioParams, ShadowField
from relayd.sim.scenario import load_scenario
from relayd.sim.world import CONTACT_CLEAR_M, World
from relayd.sim.zones import PATH_SAMPLES, RadioZone, path_environment


def cone_range_by_definition(
    ox: float,
    oy: float,
    heading_deg: float,
    half_width_deg: float,
    max_range_m: float,
    segments: list[Segment],
    circles: list[tuple[float, float, float]],
) -> float | None:
    """cone_range as the helpers define it (the code before it was written out)."""
    h, w = math.radians(heading_deg), math.radians(half_width_deg)
    nlx, nly = math.sin(h + w), -math.cos(h + w)
    nrx, nry = -math.sin(h - w), math.cos(h - w)
    best, hit = max_range_m, False
    for s in segments:
        part = _clip_to_half_plane((s.x1 - ox, s.y1 - oy), (s.x2 - ox, s.y2 - oy), nlx, nly)
        if part is not None:
            part = _clip_to_half_plane(part[0], part[1], nrx, nry)
        if part is None:
            continue
        d = point_segment_distance((0.0, 0.0), part[0], part[1])
        if d <= best:
            best, hit = d, True
    cos_w = math.cos(w)
    dx, dy = math.cos(h), math.sin(h)
    for cx, cy, r in circles:
        rx, ry = cx - ox, cy - oy
        dist = math.hypot(rx, ry)
        if dist <= r:
            return 0.0
        candidates = [dist - r] if (rx * dx + ry * dy) >= dist * cos_w else []
        for edge in (h + w, h - w):
            t = ray_circle_distance(0.0, 0.0, math.cos(edge), math.sin(edge), rx, ry, r)
            if t is not None:
                candidates.append(t)
        for d in candidates:
            if d <= best:
                best, hit = d, True
    return best if hit else None


# Coordinates on a coarse grid as often as not: shared end points, collinear and
# axis-parallel walls, zero-length pieces, the cases where rounding could decide.
coord = st.one_of(st.integers(-6, 6).map(float), st.floats(-6.0, 6.0, allow_nan=False))
segment = st.builds(Segment, coord, coord, coord, coord)


@settings(max_examples=150, deadline=None)
@given(
    ox=coord,
    oy=coord,
    heading=st.floats(-360.0, 360.0),
    half=st.sampled_from([15.0, 7.5, 30.0, 0.0]),
    segs=st.lists(segment, max_size=8),
    # Radius 0: a specular ring's wall corners and free ends, points it hears from any angle.
    circles=st.lists(
        st.tuples(coord, coord, st.one_of(st.just(0.0), st.floats(0.05, 1.0))), max_size=4
    ),
)
def test_cone_range_is_its_definition_bit_for_bit(
    ox: float,
    oy: float,
    heading: float,
    half: float,
    segs: list[Segment],
    circles: list[tuple[float, float, float]],
) -> None:
    got = cone_range(ox, oy, heading, half, 5.0, segs, circles)
    want = cone_range_by_definition(ox, oy, heading, half, 5.0, segs, circles)
    assert got == want


@settings(max_examples=150, deadline=None)
@given(p=st.tuples(coord, coord), q=st.tuples(coord, coord), segs=st.lists(segment, max_size=10))
def test_crossings_pretest_skips_only_walls_that_miss(
    p: tuple[float, float], q: tuple[float, float], segs: list[Segment]
) -> None:
    want = [s for s in segs if segments_intersect(p, q, (s.x1, s.y1), (s.x2, s.y2))]
    assert crossings(p, q, segs) == want


def test_crossings_counts_a_wall_the_path_only_touches() -> None:
    wall = Segment(2.0, 0.0, 2.0, 3.0)
    assert crossings((0.0, 0.0), (2.0, 0.0), [wall]) == [wall]  # ends on its end
    assert crossings((0.0, -1.0), (4.0, -1.0), [wall]) == []  # passes below it


def mean_power_by_definition(
    radio: Radio, a: tuple[float, float], b: tuple[float, float], gain_db: float
) -> float:
    """P = L0 - 10 n log10(d) - walls + shadowing + gain, from the primitives, in that order."""
    p = radio.params
    env = path_environment(
        a,
        b,
        p.zones,
        l0_dbm=p.l0_dbm,
        exponent=p.exponent,
        shadow_sigma_db=p.shadow_sigma_db,
        rician_k_db=p.rician_k_db,
    )
    d = max(p.min_distance_m, math.hypot(b[0] - a[0], b[1] - a[1]))
    loss = sum(p.wall_loss_db[w.material] for w in crossings(a, b, radio.walls))
    field = ShadowField(4, p.shadow_corr_m)
    shadow = env.shadow_sigma_db * ((field.value(*a) + field.value(*b)) / math.sqrt(2.0))
    return env.l0_dbm - 10.0 * env.exponent * math.log10(d) - loss + shadow + gain_db


def _budget(radio: Radio, a: tuple[float, float], b: tuple[float, float]) -> tuple[object, ...]:
    return (
        radio.mean_power_dbm(a, b, 1.5),
        radio.wall_loss_db(a, b),
        radio.environment(a, b),
        radio.shadowing_db(a, b),
        radio.rate_penalty_db(a, b),
    )


@pytest.mark.parametrize(
    "zones",
    [
        (),
        (
            RadioZone(
                "hall",
                ((0.0, -5.0), (6.0, -5.0), (6.0, 5.0), (0.0, 5.0)),
                exponent=3.5,
                multipath_db=4.0,
            ),
        ),
    ],
)
def test_radio_memo_answers_what_a_fresh_radio_computes(zones: tuple[RadioZone, ...]) -> None:
    walls = [Segment(3.0, -2.0, 3.0, 2.0, "brick"), Segment(5.0, -1.0, 6.0, 1.0, "light")]
    door = Segment(1.0, -1.0, 1.0, 1.0, "concrete")
    params = RadioParams(zones=zones)
    memo = Radio(params, [*walls, door], seed=4)
    memo.walls = tuple(walls)
    rng = random.Random(9)
    points = [(rng.uniform(-2, 8), rng.uniform(-3, 3)) for _ in range(12)]
    for step in range(300):
        if step == 150:
            memo.walls = (*walls, door)  # a timed door shuts: every cached path is stale
        a, b = rng.choice(points), rng.choice(points)
        fresh = Radio(params, [*walls, door], seed=4)
        fresh.walls = memo.walls
        assert _budget(memo, a, b) == _budget(fresh, a, b), (step, a, b)
        assert memo.mean_power_dbm(a, b, 1.5)[0] == mean_power_by_definition(memo, a, b, 1.5)


def test_radio_memo_is_bounded() -> None:
    radio = Radio(RadioParams(), [], seed=1)
    for k in range(3 * MEMO_MAX_ENTRIES):
        radio.mean_power_dbm((0.0, 0.0), (1.0 + k * 0.01, 0.0))
    assert len(radio._paths) <= MEMO_MAX_ENTRIES
    assert len(radio._shadow_at) <= MEMO_MAX_ENTRIES


def _world(noise_mm: float = 0.0) -> World:
    sc = load_scenario("person-in-corridor")
    if noise_mm:
        sc = sc.model_copy(update={"sonar": sc.sonar.model_copy(update={"noise_mm": noise_mm})})
    return World(sc, seed=3)


@settings(max_examples=50, deadline=None)
@given(order=st.permutations(range(16)), dx=st.floats(-500.0, 500.0), th=st.floats(-180.0, 180.0))
def test_sonar_ranges_read_in_any_order_are_the_whole_ring(
    order: list[int], dx: float, th: float
) -> None:
    world = _world()
    r = world.relays[0]
    x, y = r.x_m * 1000.0 + dx, r.y_m * 1000.0
    ring = world.sonar_ranges(0, x, y, th)
    lazy = {k: ring[k] for k in order[:8]}
    full = world.sonar_mm(0, x, y, th)
    assert all(full[k] == v for k, v in lazy.items())
    assert list(ring) == full and len(ring) == 16 and ring[2:5] == full[2:5]


def test_sonar_noise_draws_stay_in_sonar_order() -> None:
    # With noise every range is drawn at once, in sonar order, whichever the robot reads.
    a, b = _world(noise_mm=20.0), _world(noise_mm=20.0)
    r = a.relays[0]
    pose = (r.x_m * 1000.0, r.y_m * 1000.0, r.theta_deg)
    for _ in range(5):
        ring = a.sonar_ranges(0, *pose)
        assert isinstance(ring, list)
        assert ring == b.sonar_mm(0, *pose)


def test_vtime_run_returns_the_result_and_raises_the_error() -> None:
    async def ok() -> list[int]:
        return list(range(5))

    async def bad() -> None:
        raise KeyError("x")

    assert vtime.run(ok()) == [0, 1, 2, 3, 4]
    with pytest.raises(KeyError):
        vtime.run(bad())


def collides_by_definition(world: World, i: int, poly: tuple[tuple[float, float], ...]) -> bool:
    """World._collides without its bounding-box pre-test for the leader and the relays."""
    xs, ys = [p[0] for p in poly], [p[1] for p in poly]
    x0, x1, y0, y1 = min(xs), max(xs), min(ys), max(ys)
    for s in world.obstacles:
        if (
            max(s.x1, s.x2) < x0
            or min(s.x1, s.x2) > x1
            or max(s.y1, s.y2) < y0
            or min(s.y1, s.y2) > y1
        ):
            continue
        if polygon_hits_segment(poly, s):
            return True
    lp = world.leader_polygon()
    if lp is not None:
        if polygons_overlap(poly, lp):
            return True
    elif polygon_hits_circle(poly, world.leader.x_m, world.leader.y_m, world.leader_radius_m):
        return True
    return any(
        j != i and polygons_overlap(poly, other.polygon()) for j, other in enumerate(world.relays)
    )


@pytest.mark.parametrize("name", ["convoy", "corridor"])  # a robot leader, a person
@settings(max_examples=150, deadline=None)
@given(
    dx=st.floats(-1.5, 1.5),
    dy=st.floats(-1.5, 1.5),
    th=st.floats(-180.0, 180.0),
    grow=st.sampled_from([0.0, 2 * CONTACT_CLEAR_M]),
    near=st.integers(0, 2),
)
def test_collision_pretest_skips_only_bodies_that_cannot_touch(
    name: str, dx: float, dy: float, th: float, grow: float, near: int
) -> None:
    world = World(load_scenario(name).with_relays(2), seed=1)
    world.relays[1].x_m, world.relays[1].y_m = world.relays[0].x_m - 0.9, world.relays[0].y_m + 0.1
    cx, cy = world.node_pos(near)  # around the leader or either relay
    poly = footprint(cx + dx, cy + dy, th, ROBOT_LENGTH_M + grow, ROBOT_WIDTH_M + grow)
    for i in (0, 1):
        assert world._collides(i, poly) == collides_by_definition(world, i, poly)


def path_environment_by_definition(
    a: tuple[float, float], b: tuple[float, float], zones: tuple[RadioZone, ...]
) -> tuple[float, ...]:
    """zones.path_environment as first written: every zone's box worked out at each point."""
    defaults = (-15.0, 3.0, 4.0, 6.0, 0.0)
    sums = [0.0] * 5
    for i in range(PATH_SAMPLES):
        f = (i + 0.5) / PATH_SAMPLES
        pt = (a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]))
        values = defaults
        for z in zones:
            xs, ys = [p[0] for p in z.polygon], [p[1] for p in z.polygon]
            if (
                min(xs) <= pt[0] <= max(xs)
                and min(ys) <= pt[1] <= max(ys)
                and point_in_polygon(pt, z.polygon)
            ):
                values = (
                    defaults[0] if z.l0_dbm is None else z.l0_dbm,
                    defaults[1] if z.exponent is None else z.exponent,
                    defaults[2] if z.shadow_sigma_db is None else z.shadow_sigma_db,
                    defaults[3] if z.rician_k_db is None else z.rician_k_db,
                    z.multipath_db,
                )
                break
        for k, v in enumerate(values):
            sums[k] += v
    return tuple(s / float(PATH_SAMPLES) for s in sums)


maybe_db = st.one_of(st.none(), st.floats(-40.0, 10.0))
zone = st.builds(
    RadioZone,
    st.just("z"),
    st.lists(st.tuples(coord, coord), min_size=3, max_size=5).map(tuple),
    maybe_db,
    st.one_of(st.none(), st.floats(1.5, 5.0)),
    maybe_db,
    maybe_db,
    st.floats(0.0, 8.0),
)


@settings(max_examples=150, deadline=None)
@given(
    a=st.tuples(coord, coord),
    b=st.tuples(coord, coord),
    zones=st.lists(zone, max_size=3).map(tuple),
)
def test_path_environment_is_its_definition_bit_for_bit(
    a: tuple[float, float], b: tuple[float, float], zones: tuple[RadioZone, ...]
) -> None:
    env = path_environment(
        a, b, zones, l0_dbm=-15.0, exponent=3.0, shadow_sigma_db=4.0, rician_k_db=6.0
    )
    got = (env.l0_dbm, env.exponent, env.shadow_sigma_db, env.rician_k_db, env.multipath_db)
    if not zones:
        assert got == (-15.0, 3.0, 4.0, 6.0, 0.0)
    else:
        assert got == path_environment_by_definition(a, b, zones)


def sonar_by_definition(
    world: World, i: int, x_mm: float, y_mm: float, theta_deg: float
) -> list[int]:
    """World.sonar_mm as first written: every range at once, the leader always a candidate."""
    cfg = world.scenario.sonar
    x, y = x_mm / 1000.0, y_mm / 1000.0
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
    circles: list[tuple[float, float, float]] = []
    lp = world.leader_polygon()
    if lp is not None:
        segs.extend(polygon_segments(lp))
    else:
        circles.append((world.leader.x_m, world.leader.y_m, world.leader_radius_m))
    for j, other in enumerate(world.relays):
        if j != i and math.hypot(other.x_m - x, other.y_m - y) < reach + 1.0:
            segs.extend(polygon_segments(other.polygon()))
    c, s = math.cos(math.radians(theta_deg)), math.sin(math.radians(theta_deg))
    out = []
    for sx, sy, sh in ((p.x_mm, p.y_mm, p.heading_deg) for p in SONAR_POSES):
        best = cone_range(
            x + (c * sx - s * sy) / 1000.0,
            y + (s * sx + c * sy) / 1000.0,
            theta_deg + sh,
            cfg.beam_deg / 2.0,
            cfg.max_range_m,
            segs,
            circles,
        )
        max_mm = round(cfg.max_range_m * 1000)
        out.append(
            max_mm
            if best is None
            else round(min(max_mm, max(round(cfg.min_range_m * 1000), best * 1000.0)))
        )
    return out


@pytest.mark.parametrize("name", ["convoy", "corridor"])  # a robot leader, a person
@settings(max_examples=100, deadline=None)
@given(
    dist=st.floats(0.3, 9.0),
    bearing=st.floats(-180.0, 180.0),
    th=st.floats(-180.0, 180.0),
    lead_th=st.floats(-180.0, 180.0),
)
def test_sonar_is_its_definition_with_the_leader_near_or_far(
    name: str, dist: float, bearing: float, th: float, lead_th: float
) -> None:
    world = World(load_scenario(name).with_relays(1), seed=1)
    r = world.relays[0]
    b = math.radians(bearing)
    world.leader = dataclasses.replace(
        world.leader,
        x_m=r.x_m + dist * math.cos(b),
        y_m=r.y_m + dist * math.sin(b),
        heading_deg=lead_th,
    )
    pose = (r.x_m * 1000.0, r.y_m * 1000.0, th)
    assert world.sonar_mm(0, *pose) == sonar_by_definition(world, 0, *pose)
