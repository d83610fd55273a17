"""The multi-hop throughput model (relayd.sim.radio.chain_throughput_mbps) and the rate tables."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from relayd.sim.radio import (
    RATE_TABLE_80211N_1X1,
    chain_throughput_mbps,
    phy_rate_mbps,
)
from relayd.sim.scenario import load_scenario
from relayd.sim.world import World

rates = st.floats(min_value=1.0, max_value=60.0, allow_nan=False)


def test_one_hop_is_its_own_throughput_and_a_dead_hop_breaks_the_chain() -> None:
    assert chain_throughput_mbps([27.0], 0.2) == 27.0
    assert chain_throughput_mbps([27.0, 0.0, 27.0], 0.2) == 0.0
    assert chain_throughput_mbps([], 0.2) == 0.0


def test_coupling_limits() -> None:
    # separate channels: the weakest hop; one shared channel: the hops' airtimes add up
    assert chain_throughput_mbps([30.0, 12.0, 20.0], 0.0) == 12.0
    assert chain_throughput_mbps([20.0, 20.0], 1.0) == 10.0
    assert chain_throughput_mbps([30.0, 30.0, 30.0], 1.0) == 10.0


def test_equal_hops_cost_more_with_every_relay() -> None:
    t = 32.5
    zero, one, two = (chain_throughput_mbps([t] * (n + 1), 0.2) for n in (0, 1, 2))
    assert zero > one > two
    assert one == pytest.approx(t / 1.2, abs=1e-3) and two == pytest.approx(t / 1.4, abs=1e-3)


@given(st.lists(rates, min_size=1, max_size=6), st.floats(min_value=0.0, max_value=1.0))
def test_never_above_the_weakest_hop_and_never_below_full_sharing(
    hops: list[float], k: float
) -> None:
    e2e = chain_throughput_mbps(hops, k)
    assert e2e <= min(hops) + 1e-3
    assert e2e >= 1.0 / sum(1.0 / h for h in hops) - 1e-3


@given(
    st.lists(rates, min_size=1, max_size=6),
    st.floats(min_value=0.0, max_value=0.9),
    st.floats(0.01, 0.1),
)
def test_more_coupling_never_helps(hops: list[float], k: float, dk: float) -> None:
    assert chain_throughput_mbps(hops, k + dk) <= chain_throughput_mbps(hops, k) + 1e-3


def test_80211n_table() -> None:
    assert phy_rate_mbps(-50.0, RATE_TABLE_80211N_1X1) == 65.0
    assert phy_rate_mbps(-74.0, RATE_TABLE_80211N_1X1) == 26.0
    assert phy_rate_mbps(-82.0, RATE_TABLE_80211N_1X1) == 6.5
    assert phy_rate_mbps(-82.1, RATE_TABLE_80211N_1X1) == 0.0


def test_corridor_start_orders_zero_one_two_relays() -> None:
    """Fig. 6-17 at the start: no relays the highest throughput, two relays the lowest."""
    e2e = []
    for n in (0, 1, 2):
        w = World(load_scenario("corridor").with_relays(n), seed=1)
        w.advance(1.0)
        e2e.append(w.links().e2e_mbps)
    assert e2e[0] > e2e[1] > e2e[2] > 0


@pytest.mark.parametrize("name", ["corridor", "outdoor"])
def test_start_orders_zero_one_two_relays_in_both_paper_scenarios(name: str) -> None:
    e2e = []
    for n in (0, 1, 2):
        w = World(load_scenario(name).with_relays(n), seed=3)
        w.advance(1.0)
        e2e.append(w.links().e2e_mbps)
    assert e2e[0] > e2e[1] > e2e[2] > 0


def test_outdoor_without_relays_breaks_round_the_second_corner() -> None:
    """Fig. 6-21: after almost 60 m the link without relays goes, before the goal."""
    w = World(load_scenario("outdoor").with_relays(0), seed=1)
    broke = next(
        (
            t
            for t in range(int(w.leader_script.end_s) + 1)
            if (w.advance(float(t)) or True) and w.links().broken
        ),
        None,
    )
    assert broke is not None and 250 < broke < w.leader_script.end_s
