"""A relay following a relay in the simulator (bench/relayfeed.py's world: a door, two
corners): relay2 follows relay1's own path (its GET /path, in process on virtual time) within
0.3 m RMS while the feed is up; when the feed dies halfway it goes on on its estimated trail,
and the trace says why (trail.source "estimate", trail.feed "stale"). A relay following the
person, or any relay with the bearing pursuit, gets no leader_url (its trace is as it was)."""

from __future__ import annotations

import pytest

from bench.relayfeed import WORLD, path_errors, rms, scenario
from relayd.core.vocab import LINK_RULE_ENDS
from relayd.runtime import vtime
from relayd.sim.relay import leader_feed
from relayd.sim.runner import SimRunner

CUT_S = 80.0


def test_only_a_relay_following_a_relay_with_the_trail_pursuit_reads_a_feed() -> None:
    ahead = ("sim-relay1", (2.0, 0.0, 0.0))
    assert leader_feed({"pursuit": "bearing"}, ahead, (0.5, 0.0, 0.0)) == {}
    assert leader_feed({}, ahead, (0.5, 0.0, 0.0)) == {}  # the default pursuit is bearing
    assert leader_feed({"pursuit": "trail"}, None, (0.5, 0.0, 0.0)) == {}  # follows the person
    got = leader_feed({"pursuit": "trail"}, ahead, (0.5, 0.0, 0.0))
    assert got == {"leader_url": "http://sim-relay1-api.inproc", "leader_origin": [1.5, 0.0, 0.0]}


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_a_relay_follows_its_leaders_path_and_finishes_on_the_estimate_when_the_feed_dies() -> None:
    assert WORLD["relays"] == 2
    runner = SimRunner(scenario(), speed=None, seed=1)

    def cut(rec: dict[str, object]) -> None:
        feed = runner.relays[1].daemon.leader_feed
        assert feed is not None
        if float(rec["t"]) >= CUT_S:  # type: ignore[arg-type]
            feed.client.cut()  # type: ignore[attr-defined]

    runner.on_progress = cut
    records = vtime.run(runner.run()).records
    errors = path_errors(records)
    before = [e for t, e in errors if t < CUT_S]
    # It joined relay1's path well before the cut and followed it through the door (x 6 m)
    # and into the first corner.
    assert len(before) > 200 and rms(before) <= 0.3, rms(before)
    assert any(r["relays"][1]["x"] > 7.5 for r in records if r["t"] < CUT_S)
    trails = [(r["t"], r["relays"][1]["trail"]) for r in records]
    assert all(tr["source"] == "leader_feed" for t, tr in trails if 40.0 <= t < CUT_S)
    after = [tr for t, tr in trails if t >= CUT_S + 3.0]
    assert after and all(tr["feed"] == "stale" for tr in after)
    assert all(tr["source"] in ("estimate", "bearing") for tr in after)
    last = records[-1]["relays"][1]
    assert last["trail"]["source"] == "estimate" and last["trail"]["feed"] == "stale"
    assert last["reason"] in LINK_RULE_ENDS and last["collisions"] == 0
