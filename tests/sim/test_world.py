"""Unit and property tests of the simulator's pure parts: geometry, radio, leader, scenarios."""

from __future__ import annotations

import math
import statistics

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from relayd.core.geometry import wrap_deg
from relayd.sim.geometry import (
    Box,
    Segment,
    cast_ray,
    crossings,
    footprint,
    polygon_hits_segment,
    polygons_overlap,
    ray_circle_distance,
)
from relayd.sim.leader_script import LeaderScript
from relayd.sim.radio import (
    HOP_DOWN_DBM,
    Radio,
    RadioParams,
    ShadowField,
    phy_rate_mbps,
    throughput_mbps,
    yagi_gain_db,
)
from relayd.sim.scenario import ScenarioError, builtin_names, load_scenario, parse_scenario
from relayd.sim.world import World

# --- geometry -----------------------------------------------------------------------


def test_ray_hits_wall_at_the_right_distance() -> None:
    wall = Segment(3.0, -1.0, 3.0, 1.0)
    assert cast_ray(0.0, 0.0, 0.0, 5.0, [wall]) == pytest.approx(3.0)
    # 45 degrees: hits x=3 at y=3, beyond the wall's end
    assert cast_ray(0.0, 0.0, 45.0, 5.0, [wall]) is None
    # pointing away
    assert cast_ray(0.0, 0.0, 180.0, 5.0, [wall]) is None
    # beyond max range
    assert cast_ray(0.0, 0.0, 0.0, 2.5, [wall]) is None


def test_ray_takes_the_nearest_of_several_hits() -> None:
    walls = [Segment(4.0, -1, 4.0, 1), Segment(2.0, -1, 2.0, 1), Segment(3.0, -1, 3.0, 1)]
    assert cast_ray(0, 0, 0, 5, walls) == pytest.approx(2.0)
    assert cast_ray(0, 0, 0, 5, walls, circles=[(1.0, 0.0, 0.25)]) == pytest.approx(0.75)


def test_ray_circle_from_inside_is_zero() -> None:
    assert ray_circle_distance(0, 0, 1, 0, 0, 0, 1) == 0.0
    assert ray_circle_distance(0, 0, 1, 0, 5, 3, 1) is None


def test_wall_crossings_are_counted() -> None:
    walls = [Segment(1, -5, 1, 5, "brick"), Segment(2, -5, 2, 5, "light"), Segment(10, -5, 10, 5)]
    hit = crossings((0, 0), (5, 0), walls)
    assert [w.material for w in hit] == ["brick", "light"]
    assert crossings((0, 0), (0.5, 3), walls) == []


def test_footprint_collision_with_wall_box_and_robot() -> None:
    body = footprint(0, 0, 0, 0.626, 0.505)
    assert polygon_hits_segment(body, Segment(0.3, -1, 0.3, 1))  # front bumper touches
    assert not polygon_hits_segment(body, Segment(0.32, -1, 0.32, 1))
    turned = footprint(0, 0, 90, 0.626, 0.505)  # long axis now along y
    assert not polygon_hits_segment(turned, Segment(0.3, -1, 0.3, 1))
    box = Box(0.2, 0.2, 0.7, 0.7)
    assert any(polygon_hits_segment(body, s) for s in box.segments())
    assert polygons_overlap(body, footprint(0.6, 0, 0, 0.626, 0.505))
    assert not polygons_overlap(body, footprint(0.7, 0, 0, 0.626, 0.505))
    # one inside the other, no edge crossing
    assert polygons_overlap(footprint(0, 0, 0, 2, 2), body)


def test_box_rejects_inverted_corners() -> None:
    with pytest.raises(ValueError, match="x_min"):
        Box(1, 0, 0, 1)


@given(st.floats(-1000, 1000, allow_nan=False))
def test_wrap_deg_range(a: float) -> None:
    w = wrap_deg(a)
    assert -180 < w <= 180
    assert math.isclose(math.cos(math.radians(w)), math.cos(math.radians(a)), abs_tol=1e-9)


@given(st.floats(-50, 50), st.floats(-50, 50), st.floats(0, 360))
@settings(max_examples=50)
def test_ray_hit_point_lies_on_the_wall(ox: float, oy: float, heading: float) -> None:
    wall = Segment(-20, 60, 80, 60)
    d = cast_ray(ox, oy, heading, 500.0, [wall])
    if d is not None:
        y = oy + d * math.sin(math.radians(heading))
        assert y == pytest.approx(60.0, abs=1e-6)


# --- radio --------------------------------------------------------------------------


def _quiet(**kw: object) -> RadioParams:
    base: dict[str, object] = {"shadow_sigma_db": 0.0, "fading": False}
    base.update(kw)
    return RadioParams(**base)  # type: ignore[arg-type]


def test_path_loss_numbers_indoor_and_outdoor() -> None:
    r = Radio(_quiet(), [])
    assert r.mean_power_dbm((0, 0), (1, 0))[0] == pytest.approx(-15.0)
    assert r.mean_power_dbm((0, 0), (10, 0))[0] == pytest.approx(-45.0)
    o = Radio(RadioParams.outdoor(shadow_sigma_db=0.0, fading=False), [])
    assert o.mean_power_dbm((0, 0), (10, 0))[0] == pytest.approx(-45.0)
    assert o.mean_power_dbm((0, 0), (100, 0))[0] == pytest.approx(-70.0)


def test_wall_loss_per_material() -> None:
    walls = [Segment(1, -5, 1, 5, "brick"), Segment(2, -5, 2, 5, "light")]
    r = Radio(_quiet(), walls)
    p, los = r.mean_power_dbm((0, 0), (10, 0))
    assert p == pytest.approx(-45.0 - 13.0)
    assert not los
    assert r.mean_power_dbm((0, 0), (0, 10))[1]


def test_unknown_material_is_refused() -> None:
    with pytest.raises(ValueError, match="unobtainium"):
        Radio(_quiet(), [Segment(0, 0, 1, 1, "unobtainium")])


def test_yagi_pattern() -> None:
    assert yagi_gain_db(0.0) == 0.0
    assert yagi_gain_db(45.0) == pytest.approx(10 * math.log10(0.5))
    assert yagi_gain_db(-45.0) == yagi_gain_db(45.0)
    assert yagi_gain_db(60.0) == pytest.approx(10 * math.log10(0.25))
    assert yagi_gain_db(120.0) == -20.0
    assert yagi_gain_db(180.0) == -20.0
    assert yagi_gain_db(89.9) == -20.0  # cos^2 below the floor near 90
    assert yagi_gain_db(360.0) == 0.0


@given(st.floats(-180, 180), st.floats(-180, 180))
def test_yagi_gain_falls_off_axis(a: float, b: float) -> None:
    if abs(a) < abs(b):
        assert yagi_gain_db(a) >= yagi_gain_db(b)


@pytest.mark.parametrize(
    ("dbm", "mbps"),
    [
        (-40, 54),
        (-65, 54),
        (-65.01, 48),
        (-66, 48),
        (-70, 36),
        (-74, 24),
        (-77, 18),
        (-79, 12),
        (-81, 9),
        (-82, 6),
        (-82.01, 0),
        (-100, 0),
    ],
)
def test_rate_table_boundaries(dbm: float, mbps: float) -> None:
    assert phy_rate_mbps(dbm) == mbps
    assert throughput_mbps(dbm) == mbps * 0.5
    assert (dbm >= HOP_DOWN_DBM) == (mbps > 0)


def test_seeded_determinism() -> None:
    walls = [Segment(5, -5, 5, 5)]
    a = Radio(RadioParams(), walls, seed=7)
    b = Radio(RadioParams(), walls, seed=7)
    c = Radio(RadioParams(), walls, seed=8)
    sa = [a.sample_dbm((0, 0), (8, i * 0.1)) for i in range(20)]
    sb = [b.sample_dbm((0, 0), (8, i * 0.1)) for i in range(20)]
    sc = [c.sample_dbm((0, 0), (8, i * 0.1)) for i in range(20)]
    assert sa == sb
    assert sa != sc


def test_shadowing_is_spatially_correlated_with_the_right_spread() -> None:
    f = ShadowField(seed=3, corr_m=2.0)
    pts = [(x * 7.3, y * 7.3) for x in range(30) for y in range(30)]
    vals = [f.value(*p) for p in pts]
    assert 0.6 < statistics.pstdev(vals) < 1.4

    def corr(dist: float) -> float:
        a = vals
        b = [f.value(p[0] + dist, p[1]) for p in pts]
        return statistics.correlation(a, b)

    assert corr(0.2) > 0.9  # smooth over short moves
    assert 0.35 < corr(2.0) < 0.85  # exp(-1/2) = 0.61 at the correlation length
    assert abs(corr(8.0)) < 0.25  # independent far apart


def test_fading_rayleigh_deeper_than_rician() -> None:
    r = Radio(RadioParams(fading_avg_frames=1), [], seed=1)
    nlos = [r.fading_db(False) for _ in range(4000)]
    los = [r.fading_db(True) for _ in range(4000)]
    assert statistics.pstdev(nlos) > statistics.pstdev(los)
    # Rayleigh power is exponential with mean 1: mean of linear power ~ 1
    assert statistics.mean(10 ** (x / 10) for x in nlos) == pytest.approx(1.0, rel=0.1)


# --- leader script ------------------------------------------------------------------


def test_leader_walks_pauses_and_stops() -> None:
    s = LeaderScript([(0, 0, 0), (2, 0, 5.0), (2, 2, 0)], speed_m_s=0.5, start_s=1.0)
    assert s.end_s == pytest.approx(1 + 4 + 5 + 4)
    p = s.pose(0.5)
    assert (p.x_m, p.y_m, p.moving) == (0, 0, False)
    p = s.pose(3.0)
    assert p.x_m == pytest.approx(1.0) and p.moving and p.heading_deg == pytest.approx(0)
    p = s.pose(7.0)
    assert (p.x_m, p.y_m, p.moving) == (2, 0, False)
    p = s.pose(12.0)
    assert p.y_m == pytest.approx(1.0) and p.heading_deg == pytest.approx(90)
    p = s.pose(100.0)
    assert p.done and (p.x_m, p.y_m) == (2, 2)
    assert s.goal == (2, 2)


@given(st.floats(0, 50))
def test_leader_never_exceeds_its_speed(t: float) -> None:
    s = LeaderScript([(0, 0, 0), (3, 4, 2.0), (3, -1, 0)], speed_m_s=0.2)
    a, b = s.pose(t), s.pose(t + 0.1)
    assert math.hypot(b.x_m - a.x_m, b.y_m - a.y_m) <= 0.2 * 0.1 + 1e-9


def test_leader_script_needs_waypoints() -> None:
    with pytest.raises(ValueError):
        LeaderScript([], 0.2)


# --- scenarios ----------------------------------------------------------------------


def test_builtin_scenarios_load() -> None:
    assert {"convoy", "obstacle", "corridor", "parking"} <= set(builtin_names())
    for name in builtin_names():
        sc = load_scenario(name)
        World(sc, seed=1)


def _minimal() -> dict:
    return {
        "name": "t",
        "command_center": {"x": 0, "y": 0},
        "leader": {"waypoints": [{"x": 1, "y": 0}]},
        "relays": 0,
    }


def test_scenario_errors_name_the_key() -> None:
    d = _minimal()
    d["leader"]["waypoints"].append({"x": "far", "y": 0})
    d["walls"] = [{"points": [[0, 0], [1, 1]], "material": "cheese"}]
    d["bogus"] = 1
    with pytest.raises(ScenarioError) as ei:
        parse_scenario(d)
    text = "\n".join(ei.value.errors)
    assert "leader.waypoints.1.x" in text
    assert "bogus" in text


def test_scenario_unknown_material_and_too_many_relays() -> None:
    d = _minimal()
    d["walls"] = [{"points": [[0, 0], [1, 1]], "material": "cheese"}]
    with pytest.raises(ScenarioError, match=r"walls\.0\.material"):
        parse_scenario(d)
    d = _minimal()
    d["relays"] = 2
    with pytest.raises(ScenarioError, match="relays"):
        parse_scenario(d)
    with pytest.raises(ScenarioError, match="relays"):
        load_scenario("corridor").with_relays(5)


def test_unknown_scenario_name_lists_the_shipped_ones(tmp_path) -> None:
    with pytest.raises(ScenarioError, match="corridor"):
        load_scenario("atlantis")
    bad = tmp_path / "bad.toml"
    bad.write_text("name = [")
    with pytest.raises(ScenarioError, match="TOML"):
        load_scenario(bad)


# --- the world ----------------------------------------------------------------------


def test_sonar_sees_a_wall_ahead_and_nothing_behind() -> None:
    d = _minimal()
    d["relays"] = 1
    d["relay"] = [{"name": "r", "x": 0, "y": 0}]
    d["walls"] = [{"points": [[2.245, -3], [2.245, 3]]}]
    d["leader"] = {"waypoints": [{"x": -4, "y": 6}]}  # out of every beam's reach
    w = World(parse_scenario(d), seed=0)
    r = w.sonar_mm(0, 0, 0, 0)
    assert r[3] == pytest.approx(2000, abs=15)  # sonar 3 at x=245 looks ahead at +10 deg
    assert r[4] == pytest.approx(2000, abs=15)
    assert r[0] == 5000  # left side: no echo -> max range
    # turned around, the rear sonars see the wall
    r = w.sonar_mm(0, 0, 0, 180)
    assert r[11] == pytest.approx(2000, abs=15) and r[12] == pytest.approx(2000, abs=15)
    assert min(r[:8]) == 5000


def _one_relay(**extra: object) -> dict:
    d = _minimal()
    d["relays"] = 1
    d["relay"] = [{"name": "r", "x": 0, "y": 0}]
    d["leader"] = {"waypoints": [{"x": -4, "y": 6}]}  # out of every beam's reach
    d.update(extra)
    return d


def test_sonar_is_exactly_mirror_symmetric() -> None:
    # The box-dead-ahead case: 0.5 m, centred on the heading. A real ring sees it symmetrically,
    # and so must the simulated one (no rays or noise to break the tie for the robot).
    w = World(
        parse_scenario(_one_relay(boxes=[{"min": [2.25, -0.25], "max": [2.75, 0.25]}])), seed=0
    )
    for x_mm in (0.0, 1200.0, 1704.0):
        r = w.sonar_mm(0, x_mm, 0, 0)
        assert (r[0], r[1], r[2], r[3]) == (r[7], r[6], r[5], r[4])
        assert r[3] < 5000


def test_sonar_reports_the_nearest_echo_anywhere_in_its_beam() -> None:
    # A 2 cm post 14 degrees off sonar 3's axis (heading 10) is inside its +-15 degree
    # beam: seen at its true distance; at 20 degrees off it is outside.
    sx, sy = 0.245, 0.027
    for off_deg, seen in ((14.0, True), (-14.0, True), (20.0, False)):
        a = math.radians(10.0 + off_deg)
        px, py = sx + 1.5 * math.cos(a), sy + 1.5 * math.sin(a)
        box = {"min": [px - 0.01, py - 0.01], "max": [px + 0.01, py + 0.01]}
        r = World(parse_scenario(_one_relay(boxes=[box])), seed=0).sonar_mm(0, 0, 0, 0)
        assert (abs(r[3] - 1490) <= 15) is seen, (off_deg, r[3])


def test_sonar_ranges_are_clipped_like_the_hardware() -> None:
    near = _one_relay(walls=[{"points": [[0.29, -3], [0.29, 3]]}])  # 45 mm off the front face
    r = World(parse_scenario(near), seed=0).sonar_mm(0, 0, 0, 0)
    assert r[3] == 100 and r[4] == 100  # below the minimum range: the minimum
    far = _one_relay(walls=[{"points": [[6.0, -3], [6.0, 3]]}])
    r = World(parse_scenario(far), seed=0).sonar_mm(0, 0, 0, 0)
    assert all(v == 5000 for v in r)  # nothing within 5 m: the maximum, as ARIA reads "no echo"
    assert all(isinstance(v, int) for v in r)


def test_sonar_noise_only_when_the_scenario_asks() -> None:
    d = _one_relay(walls=[{"points": [[2.245, -3], [2.245, 3]]}])
    clean = [World(parse_scenario(d), seed=s).sonar_mm(0, 0, 0, 0) for s in (0, 1)]
    assert clean[0] == clean[1]
    d["sonar"] = {"noise_mm": 20.0}
    noisy = [World(parse_scenario(d), seed=s).sonar_mm(0, 0, 0, 0) for s in (0, 1)]
    assert noisy[0] != noisy[1]


@pytest.mark.parametrize(
    "name", ["box-dead-ahead", "box-dead-ahead-offset", "u-trap", "doorway", "person-in-corridor"]
)
def test_obstacle_scenarios_ship_and_start_clear(name: str) -> None:
    sc = load_scenario(name)
    w = World(sc, seed=0)
    assert not w._collides(0, w.relays[0].polygon())
    assert w.gap_m(0) >= 8.0  # the leader is far beyond the obstacle


def test_motion_guard_rejects_and_counts_contact() -> None:
    d = _minimal()
    d["relays"] = 1
    d["relay"] = [{"name": "r", "x": 0, "y": 0}]
    d["walls"] = [{"points": [[1.0, -3], [1.0, 3]]}]
    d["leader"] = {"waypoints": [{"x": -4, "y": 0}]}
    w = World(parse_scenario(d), seed=0)
    assert w.motion_ok(0, 600, 0, 0)
    w.set_pose(0, 600, 0, 0)
    assert not w.motion_ok(0, 700, 0, 0)
    assert not w.motion_ok(0, 710, 0, 0)  # still pushing: one contact, not two
    assert w.collisions() == 1
    assert w.motion_ok(0, 680, 0, 0)  # creeping up to the wall: the same contact
    assert not w.motion_ok(0, 700, 0, 0, old=(680, 0, 0))
    assert w.collisions() == 1
    assert w.motion_ok(0, 500, 0, 0)  # backing off clear of the wall ends it
    assert not w.motion_ok(0, 720, 0, 0)
    assert w.collisions() == 2


def test_yagi_hears_best_towards_the_leader() -> None:
    d = _minimal()
    d["relays"] = 1
    d["relay"] = [{"name": "r", "x": 0, "y": 0, "theta_deg": 90}]
    d["leader"] = {"waypoints": [{"x": 5, "y": 5}]}
    d["radio"] = {"fading": False, "shadow_sigma_db": 0}
    w = World(parse_scenario(d), seed=0)
    # leader at world 45 deg; robot faces 90: leader is 45 deg to the right (-45)
    assert w.true_bearing_deg(0) == pytest.approx(-45)
    levels = {a: w.yagi_rssi_dbm(0, a) for a in range(-90, 91, 15)}
    assert max(levels, key=lambda a: levels[a]) == -45
    assert levels[-45] == pytest.approx(-15 - 30 * math.log10(math.hypot(5, 5)))


def test_corridor_without_relays_breaks_before_the_goal() -> None:
    w = World(load_scenario("corridor").with_relays(0), seed=1)
    broke = None
    for t in range(int(w.leader_script.end_s) + 1):
        w.advance(float(t))
        if w.links().broken:
            broke = t
            break
    assert broke is not None and broke < w.leader_script.end_s


def test_turning_in_place_against_a_wall_is_one_contact() -> None:
    d = _minimal()
    d["relays"] = 1
    d["relay"] = [{"name": "r", "x": 0, "y": 0}]
    d["walls"] = [{"points": [[1.0, -3], [1.0, 3]]}]
    d["leader"] = {"waypoints": [{"x": -4, "y": 0}]}
    w = World(parse_scenario(d), seed=0)
    old = (680.0, 0.0, 0.0)  # front bumper 7 mm from the wall
    for _ in range(5):
        # the FakeRobot's pattern: translation rejected, then rotation in place accepted
        assert not w.motion_ok(0, 780, 0, 0, old=old)
        assert w.motion_ok(0, 680, 0, 1, old=old)
    assert w.collisions() == 1
    assert w.relays[0].rejected_steps == 5


def test_a_robot_already_touching_may_move_away() -> None:
    d = _minimal()
    d["relays"] = 2
    d["relay"] = [{"name": "a", "x": 0, "y": 0}, {"name": "b", "x": 0.5, "y": 0}]
    d["leader"] = {"waypoints": [{"x": -4, "y": 0}]}
    w = World(parse_scenario(d), seed=0)
    # b was placed overlapping a: it is allowed to move (and the contact is counted)
    assert w.motion_ok(1, 600, 0, 0, old=(500, 0, 0))
    assert w.collisions() == 1


def test_scenario_errors_all_in_one_pass() -> None:
    d = _minimal()
    d["leader"]["waypoints"].append({"x": "far", "y": 0})
    d["walls"] = [{"points": [[0, 0], [1, 1]], "material": "cheese"}]
    d["boxes"] = [{"min": [0, 0], "max": [1, 1], "material": "jelly"}]
    d["relays"] = 2
    d["control"] = {"kp": "fast", "threshold_l_dbm": 5}
    d["scan"] = {"samples": 1}
    d["relay"] = [{"name": "r1", "x": 0, "y": 0, "control": {"kd": -1}}]
    with pytest.raises(ScenarioError) as ei:
        parse_scenario(d)
    errors = ei.value.errors
    for key in (
        "leader.waypoints.1.x",
        "walls.0.material",
        "boxes.0.material",
        "relays:",
        "control.kp",
        "control.threshold_l_dbm",
        "scan.samples",
        "relay.0.control.kd",
    ):
        assert any(e.startswith(key) for e in errors), (key, errors)
    # The shared control table's errors are not repeated for each relay.
    assert not any(e.startswith("relay.0.control.kp") for e in errors), errors
    assert len(errors) == len(set(errors))


def test_non_utf8_scenario_is_an_error_naming_the_key(tmp_path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_bytes('name = "t"\ndescription = "caf\u00e9"\n'.encode("latin-1"))
    with pytest.raises(ScenarioError, match=r"description \(line 2\): not UTF-8"):
        load_scenario(bad)
