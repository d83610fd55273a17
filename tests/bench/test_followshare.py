"""The follow policies of bench/followshare.py: thresholds from calibrate's arithmetic, the speed law."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench import followshare as fs
from relayd.calibrate.fit import PathLossFit
from relayd.config.model import ControlSettings
from relayd.core.control.law import background_speed
from relayd.sim.scenario import load_scenario


@given(
    l0=st.floats(-30.0, -10.0),
    n=st.floats(1.2, 4.0),
    gap=st.floats(1.0, 4.5),
    leader=st.floats(50.0, 350.0),
    v_max=st.floats(360.0, 1200.0),
)
@settings(max_examples=100, deadline=None)
def test_the_speed_law_keeps_up_where_it_stops_and_is_flat_out_at_5_m(
    l0: float, n: float, gap: float, leader: float, v_max: float
) -> None:
    fit = PathLossFit.known(l0, n, 3.0)
    thr = fit.rssi_at(gap)
    w1, w2 = fs.speed_law(fit, thr, leader, v_max)
    assert w1 > 0
    assert background_speed(thr, w1, w2, v_max) == pytest.approx(leader, abs=1e-6)
    assert background_speed(fit.rssi_at(5.0), w1, w2, v_max) == pytest.approx(v_max, abs=1e-6)
    # Between the two: faster the fainter the leader; beyond: v_max.
    mid = fit.rssi_at(math.sqrt(gap * 5.0))
    assert leader < background_speed(mid, w1, w2, v_max) < v_max
    assert background_speed(fit.rssi_at(9.0), w1, w2, v_max) == pytest.approx(v_max)


def test_a_threshold_at_or_below_the_5_m_level_is_refused() -> None:
    fit = PathLossFit.known(-20.0, 2.5, 4.0)
    with pytest.raises(ValueError, match="not above"):
        fs.speed_law(fit, fit.rssi_at(6.0), 200.0, 400.0)


@pytest.mark.parametrize("name", ["convoy", "corridor"])
def test_the_policies_are_calibrates_thresholds_for_the_scenarios_radio(name: str) -> None:
    sc = load_scenario(name)
    r = sc.radio_params()
    gap = fs.gap_threshold(sc)
    # calibrate --link leader --hop-m 3: the median level at 3 m.
    assert gap == pytest.approx(r.l0_dbm - 10.0 * r.exponent * math.log10(3.0))
    within = fs.within_threshold(sc)
    # The median at 5 m raised by z(0.1 %) = 3.09 sigma: a stop beyond 5 m once in a thousand.
    assert within == pytest.approx(
        r.l0_dbm - 10.0 * r.exponent * math.log10(5.0) + 3.0902 * r.shadow_sigma_db, abs=0.01
    )
    assert within > gap  # the stricter ask stops sooner
    for policy in fs.POLICIES[1:]:
        control = {**sc.control, **policy.control(sc)}
        ControlSettings.model_validate(control)  # a config the daemon accepts
        assert control["w1"] > 0
        assert (
            control["leader_gap_max_m"] == fs.GAP_MAX_M
        )  # the sonar release (docs/CONTROL.md 5.3)
    assert "leader_gap_max_m" not in fs.POLICIES[0].control(sc)  # the paper's rule alone


def test_the_paper_policy_leaves_the_scenario_alone_and_the_extra_relay_starts_behind() -> None:
    sc = load_scenario("corridor")
    paper = fs.policy_scenario("corridor", fs.POLICIES[0], {"estimator": "wca", "window": "full"})
    assert paper.control == sc.control and paper.relays == sc.relays
    assert paper.scan["estimator"] == "wca"
    plus = fs.policy_scenario("corridor", fs.CORRIDOR_PLUS_ONE, {})
    assert plus.relays == len(plus.relay) == 3
    assert plus.relay[-1].x < plus.relay[-2].x and plus.relay[-1].x > sc.command_center.x


def test_the_rear_free_corridor_policy_is_within_5_m_without_the_rear_duty() -> None:
    sc = load_scenario("corridor")
    free = fs.policy_scenario("corridor", fs.CORRIDOR_REAR_FREE, {})
    within = fs.policy_scenario("corridor", fs.POLICIES[2], {})
    assert sc.control.get("rear_link", "require") == "require"
    assert free.control == {**within.control, "rear_link": "ignore"}
    ControlSettings.model_validate(free.control)
    assert free.relays == sc.relays
