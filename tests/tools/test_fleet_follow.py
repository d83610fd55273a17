"""The fleet config's chain is each relay's leader: follow_keys gives every relay after the
first its [control] leader_url and leader_origin, and they pass the daemon's config."""

from __future__ import annotations

import math

from relayd.config.load import parse_settings
from relayd.config.params import trail_params
from relayd.fleet.config import follow_keys, parse_fleet


def test_the_chain_gives_each_relay_its_leader_and_origin() -> None:
    fleet = parse_fleet(
        {
            "fleet": {
                "relay": [
                    {"name": "relay1", "url": "10.0.0.31:8080", "origin": [2.0, 0.0, 0.0]},
                    {"name": "relay2", "url": "http://10.0.0.32:8080", "origin": [0.5, 0.0, 0.0]},
                    {"name": "relay3", "url": "http://10.0.0.33:8080", "origin": [0.0, -1.0, 90]},
                    {"name": "relay4", "url": "http://10.0.0.34:8080"},
                ]
            }
        },
        environ={},
    )
    keys = follow_keys(fleet)
    assert keys["relay1"] == {}  # it follows the person
    assert keys["relay2"] == {
        "leader_url": "http://10.0.0.31:8080",
        "leader_origin": [1.5, 0.0, 0.0],
    }
    # relay2 started 0.5 m east and 1 m north of relay3, which faced north: ahead, on its right.
    origin = keys["relay3"]["leader_origin"]
    assert isinstance(origin, list)
    assert all(
        math.isclose(a, b, abs_tol=1e-9) for a, b in zip(origin, [1.0, -0.5, -90.0], strict=True)
    )
    assert keys["relay4"] == {"leader_url": "http://10.0.0.33:8080"}  # no origin: none given
    s = parse_settings({"control": {"rear_link": "ignore", "pursuit": "trail", **keys["relay2"]}})
    assert s.control.leader_url == "http://10.0.0.31:8080"
    assert trail_params(s).feed.prior is not None
