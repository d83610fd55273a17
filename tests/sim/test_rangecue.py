"""The sonar release in the simulated convoy: real daemons, virtual time (docs/CONTROL.md 5.3).

Seed 4 of the convoy under bench/followshare.py's "within 5 m" policy is where a bright
spot stood the second relay on "leader_near" with its leader 5-5.7 m away (t = 30-33 s).
With the release the relay drives on, and every released record has the leader at
least as far as the floor said (the floor is a lower bound in the simulator too).
"""

from __future__ import annotations

import pytest

from bench import followshare as fs
from relayd.core.control.rangecue import RELEASE_HYSTERESIS_M
from relayd.runtime import vtime
from relayd.sim.runner import SimRunner

pytestmark = pytest.mark.slow


@pytest.mark.timeout(120)
def test_a_relay_in_a_bright_spot_drives_on_instead_of_standing_beyond_5_m() -> None:
    policy = fs.POLICIES[2]
    sc = fs.policy_scenario("convoy", policy, {"estimator": "lobe", "window": "adaptive"})
    assert sc.control["leader_gap_max_m"] == fs.GAP_MAX_M
    result = vtime.run(SimRunner(sc, speed=None, seed=4, seconds=45.0).run())
    rows = [(r["t"], x) for r in result.records for x in r["relays"]]
    released = [(t, x) for t, x in rows if x["reason"] == "leader_far_sonar"]
    assert any(x["name"] == "relay2" and 25.0 <= t <= 35.0 for t, x in released), (
        "no release where it stood"
    )
    # Released only with the leader truly beyond the limit less the hysteresis.
    assert all(x["gap_m"] >= fs.GAP_MAX_M - RELEASE_HYSTERESIS_M for _, x in released), released
    # ... and no relay stands on "leader_near" with its leader beyond 5 m.
    standing_far = [
        (t, x["name"], x["gap_m"])
        for t, x in rows
        if x["reason"] == "leader_near" and x["gap_m"] > 5.0
    ]
    assert not standing_far
    assert result.summary["collisions"] == 0
