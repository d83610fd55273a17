"""The simulator's antenna family: named patterns per scenario and per relay; the default unchanged."""

from __future__ import annotations

import math
from typing import Any

import pytest

from relayd.sim.antennas import FAMILY, family_pattern, pattern_gain
from relayd.sim.radio import yagi_gain_db
from relayd.sim.scenario import ScenarioError, parse_scenario
from relayd.sim.world import World


def _two_relays(**scan: Any) -> dict[str, Any]:
    return {
        "name": "t",
        "command_center": {"x": -5, "y": 0},
        "leader": {"waypoints": [{"x": 5, "y": 5}]},
        "relays": 2,
        "relay": [{"name": "a", "x": 0, "y": 0}, {"name": "b", "x": -2, "y": 0}],
        "radio": {"fading": False, "shadow_sigma_db": 0},
        "scan": scan,
    }


def test_the_family_has_the_shapes_it_promises() -> None:
    figures = {n: family_pattern(n) for n in FAMILY}
    assert figures["builtin"].beamwidth_deg() == pytest.approx(90.0, abs=1.0)
    assert figures["shallow"].front_to_back_db() == pytest.approx(12.0)
    assert figures["shallow"].beamwidth_deg() == pytest.approx(60.0, abs=1.0)
    assert figures["deep"].front_to_back_db() == pytest.approx(30.0)
    assert figures["yagi"].side_lobe_db() == pytest.approx(-10.0, abs=0.2)
    assert figures["yagi"].front_to_back_db() == pytest.approx(15.0, abs=0.2)
    assert figures["asymmetric"].peak_deg() == pytest.approx(8.0)
    assert figures["patch"].beamwidth_deg() == pytest.approx(70.0, abs=1.0)
    assert figures["patch"].gain_db(50.0) == pytest.approx(-12.0, abs=1.0)  # steep shoulders
    assert all(pattern_gain("builtin")(a) == yagi_gain_db(a) for a in range(-180, 181, 7))
    with pytest.raises(ValueError, match="known: builtin"):
        pattern_gain("dish")


def test_a_scenario_without_a_pattern_hears_exactly_what_it_did() -> None:
    plain = World(parse_scenario(_two_relays()), seed=3)
    named = World(parse_scenario(_two_relays(pattern="builtin")), seed=3)
    for a in range(-90, 91, 15):
        assert plain.yagi_rssi_dbm(0, a) == named.yagi_rssi_dbm(0, a)
        assert plain.yagi_rssi_dbm(0, a) == pytest.approx(
            -15.0 - 30.0 * math.log10(math.hypot(5, 5)) + yagi_gain_db(45.0 - a)
        )


def test_per_relay_patterns_and_the_daemon_never_sees_the_key() -> None:
    d = _two_relays(pattern="shallow", estimator="lobe")
    d["relay"][1]["pattern"] = "deep"
    sc = parse_scenario(d)
    assert sc.relay_pattern(0) == "shallow" and sc.relay_pattern(1) == "deep"
    assert sc.daemon_scan() == {"estimator": "lobe"}
    w = World(sc, seed=0)
    base = -15.0 - 30.0 * math.log10(math.hypot(5, 5))
    # Relay a: the shallow lobe's -12 dB floor 135 deg off axis.
    assert w.yagi_rssi_dbm(0, -90.0) == pytest.approx(base - 12.0)


def test_an_unknown_pattern_names_its_key() -> None:
    d = _two_relays(pattern="dish")
    d["relay"][1]["pattern"] = "horn"
    with pytest.raises(ScenarioError) as ei:
        parse_scenario(d)
    text = "\n".join(ei.value.errors)
    assert "scan.pattern: unknown antenna pattern 'dish'" in text
    assert "relay.1.pattern: unknown antenna pattern 'horn'" in text


def test_the_measured_helical_is_the_published_table() -> None:
    """The real antenna's table as shipped: its file parses, its figures are the measurement's."""
    from relayd.sim.antennas import DRAWN, measured

    p = measured("helical_xw24o_h10.toml")
    assert p.full_circle and len(p.angles_deg) == 360 and p.peak_deg() == 1.0
    assert p.beamwidth_deg() == pytest.approx(39.0, abs=0.5)
    assert p.side_lobe_db() == pytest.approx(-3.37, abs=0.01)  # near +45 deg: a real helix's
    assert p.front_to_back_db() == pytest.approx(13.29, abs=0.01)
    assert dict(p.conditions)["frequency_mhz"] == "2440"
    assert FAMILY["helical"](45.0) == p.gain_db(45.0) and "helical" not in DRAWN
