"""Per-zone radio environments (relayd/sim/zones.py) and the `mixed` scenario."""

from __future__ import annotations

import math
import statistics
from dataclasses import replace

import pytest

from relayd.sim.radio import Radio, RadioParams
from relayd.sim.scenario import ScenarioError, load_scenario, parse_scenario
from relayd.sim.world import World
from relayd.sim.zones import RadioZone, path_environment, zone_at

HALL = RadioZone(
    "hall",
    ((0.0, -5.0), (10.0, -5.0), (10.0, 5.0), (0.0, 5.0)),
    exponent=2.0,
    shadow_sigma_db=2.0,
    rician_k_db=10.0,
)
CORRIDOR = RadioZone(
    "corridor",
    ((10.0, -1.0), (30.0, -1.0), (30.0, 1.0), (10.0, 1.0)),
    exponent=4.0,
    shadow_sigma_db=6.0,
    rician_k_db=0.0,
    multipath_db=5.0,
)
DEFAULTS = {"l0_dbm": -20.0, "exponent": 3.0, "shadow_sigma_db": 4.0, "rician_k_db": 6.0}


def test_a_link_takes_the_environment_of_the_ground_it_crosses() -> None:
    zones = (HALL, CORRIDOR)
    assert path_environment((1, 0), (9, 0), (), **DEFAULTS).exponent == 3.0
    inside = path_environment((1, 0), (9, 0), zones, **DEFAULTS)
    assert (inside.exponent, inside.shadow_sigma_db, inside.multipath_db, inside.l0_dbm) == (
        2.0,
        2.0,
        0.0,
        -20.0,
    )
    half = path_environment((0, 0), (20, 0), zones, **DEFAULTS)
    assert half.exponent == pytest.approx(3.0) and half.multipath_db == pytest.approx(2.5)
    assert half == path_environment((20, 0), (0, 0), zones, **DEFAULTS)  # symmetric
    outside = path_environment((0, 20), (10, 20), zones, **DEFAULTS)
    assert outside.exponent == 3.0 and outside.multipath_db == 0.0
    assert (
        zone_at((5, 0), zones) is HALL
        and zone_at((20, 0), zones) is CORRIDOR
        and zone_at((5, 9), zones) is None
    )


def test_multipath_costs_rate_not_signal() -> None:
    clean = Radio(RadioParams(fading=False, shadow_sigma_db=0.0, zones=(HALL,)), [], seed=1)
    dense = Radio(
        RadioParams(fading=False, shadow_sigma_db=0.0, zones=(replace(HALL, multipath_db=5.0),)),
        [],
        seed=1,
    )
    a, b = (1.0, 0.0), (9.0, 0.0)
    assert clean.mean_power_dbm(a, b) == dense.mean_power_dbm(a, b)
    assert clean.rate_penalty_db(a, b) == 0.0 and dense.rate_penalty_db(a, b) == 5.0


def test_fading_is_deeper_in_the_corridor() -> None:
    radio = Radio(RadioParams(shadow_sigma_db=0.0, zones=(HALL, CORRIDOR)), [], seed=3)
    hall = [
        radio.sample_dbm((1, 0), (9, 0)) - radio.mean_power_dbm((1, 0), (9, 0))[0]
        for _ in range(2000)
    ]
    cor = [
        radio.sample_dbm((12, 0), (28, 0)) - radio.mean_power_dbm((12, 0), (28, 0))[0]
        for _ in range(2000)
    ]
    assert statistics.pstdev(cor) > 1.5 * statistics.pstdev(hall)


def test_mixed_scenario_hall_is_open_and_corridor_is_dense() -> None:
    sc = load_scenario("mixed")
    names = [z.name for z in sc.radio.zones]
    assert names == ["hall", "corridor"]
    world = World(sc, seed=1)
    radio = world.radio
    env_hall = radio.environment((5.0, 0.0), (25.0, 0.0))
    env_cor = radio.environment((55.0, 0.0), (75.0, 0.0))
    assert (
        env_cor.exponent > env_hall.exponent and env_cor.shadow_sigma_db > env_hall.shadow_sigma_db
    )
    assert env_cor.multipath_db > 0.0 == env_hall.multipath_db
    # The same 20 m hop loses far more in the corridor (median, shadowing aside).
    loss_hall = 10 * env_hall.exponent * math.log10(20.0)
    loss_cor = 10 * env_cor.exponent * math.log10(20.0) + env_cor.multipath_db
    assert loss_cor - loss_hall > 15.0
    assert sc.control["target_hop_mbps"] == 10 and sc.control["threshold_b_dbm"] == -66


def test_a_hop_with_no_rate_is_down() -> None:
    sc = load_scenario("mixed")
    world = World(sc, seed=1)
    world.advance(0.0)
    world.set_pose(0, 75_000.0, 0.0, 0.0)
    world.set_pose(1, 60_000.0, 0.0, 0.0)
    hops = world.links().hops
    for h in hops:
        assert h.up == (h.rate_mbps > 0)


def test_zone_errors_name_their_key() -> None:
    doc = load_scenario("mixed").model_dump()
    doc["radio"]["zones"][0]["polygon"] = [[0, 0], [1, 1]]
    doc["radio"]["zones"][1]["multipath"] = 3
    with pytest.raises(ScenarioError) as err:
        parse_scenario(doc)
    text = str(err.value)
    assert "radio.zones.0.polygon" in text and "radio.zones.1.multipath" in text


def test_adaptive_relays_learn_in_the_simulator() -> None:
    """Real daemons on virtual time: the rear AP's rates reach the model, /status shows it,
    and the limit in force (the trace's threshold_b_dbm) is the model's, within the bounds."""
    import sys

    from relayd.runtime import vtime
    from relayd.sim.runner import SimRunner

    sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[2]))
    from bench.adaptive import scenario_with

    sc = scenario_with("mixed", {"link_policy": "adaptive"}).with_relays(1)
    runner = SimRunner(sc, speed=None, seed=1, seconds=45.0)
    result = vtime.run(runner.run())
    model = runner.relays[0].daemon.state.link_model
    assert model is not None and model.policy == "adaptive" and model.samples >= 30
    limits = {r["relays"][0]["threshold_b_dbm"] for r in result.records}
    assert all(-78.0 <= v <= -55.0 for v in limits) and len(limits) > 1
    assert result.records[-1]["relays"][0]["threshold_b_dbm"] == model.threshold_b_dbm
