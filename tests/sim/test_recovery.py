"""Simulator pieces for self-healing: timed world events, the leader's speed profile, a carried
command center, the break/downtime/episode summary, and the three shipped scenarios."""

from __future__ import annotations

import math
from typing import Any

import pytest

from relayd.core.geometry import ROBOT_LENGTH_M
from relayd.runtime import vtime
from relayd.sim.leader_script import LeaderScript
from relayd.sim.outcomes import downtime_s, link_breaks, recovery_episodes
from relayd.sim.runner import SimRunner
from relayd.sim.scenario import ScenarioError, load_scenario, parse_scenario
from relayd.sim.world import DOOR_CLEAR_M, World


def doc(**extra: Any) -> dict[str, Any]:
    base: dict[str, Any] = {
        "name": "t",
        "command_center": {"x": -3.0, "y": 0.0},
        "leader": {"waypoints": [{"x": 6.0, "y": 0.0}]},
        "relays": 1,
        "relay": [{"name": "r1", "x": 0.0, "y": 0.0}],
    }
    base.update(extra)
    return base


# -- scenario format -------------------------------------------------------------------


def test_timed_walls_and_boxes_parse_and_bad_windows_name_their_key() -> None:
    sc = parse_scenario(
        doc(
            walls=[
                {
                    "points": [[3, -1], [3, 1]],
                    "material": "concrete",
                    "appear_s": 5,
                    "disappear_s": 9,
                }
            ],
            boxes=[{"min": [1, 1], "max": [2, 2], "disappear_s": 4}],
        )
    )
    assert sc.wall_segments() == [] and sc.box_shapes() == []
    timed = sc.timed_obstacles()
    assert [(a, b, len(o)) for a, b, o in timed] == [(5.0, 9.0, 1), (0.0, 4.0, 4)]
    with pytest.raises(ScenarioError) as e:
        parse_scenario(doc(walls=[{"points": [[0, 0], [1, 0]], "appear_s": 5, "disappear_s": 5}]))
    assert e.value.errors[0].startswith("walls.0: ")
    with pytest.raises(ScenarioError) as e:
        parse_scenario(
            doc(
                leader={
                    "waypoints": [{"x": 1, "y": 0}],
                    "speed_profile": [{"at_s": 9, "speed_m_s": 1}, {"at_s": 2, "speed_m_s": 1}],
                }
            )
        )
    assert "leader.speed_profile" in e.value.errors[0]
    with pytest.raises(ScenarioError) as e:
        parse_scenario(doc(recovery={"max_time_s": -1, "enabeld": True}))
    assert sorted(m.split(":")[0] for m in e.value.errors) == [
        "recovery.enabeld",
        "recovery.max_time_s",
    ]


def test_leader_speed_profile_changes_the_walk() -> None:
    plain = LeaderScript([(0.0, 0.0, 0.0), (30.0, 0.0, 0.0)], 0.2)
    hurried = LeaderScript(
        [(0.0, 0.0, 0.0), (30.0, 0.0, 0.0)], 0.2, 0.0, [(10.0, 1.0), (20.0, 0.2)]
    )
    assert plain.pose(10.0).x_m == pytest.approx(2.0)
    assert hurried.pose(10.0).x_m == pytest.approx(2.0)
    assert hurried.pose(15.0).x_m == pytest.approx(7.0)  # 2 m + 5 s at 1 m/s
    assert hurried.pose(25.0).x_m == pytest.approx(13.0)  # + 10 m, then 5 s at 0.2 m/s
    assert hurried.end_s == pytest.approx(20.0 + 18.0 / 0.2)
    assert hurried.pose(hurried.end_s + 1).done


def test_a_door_closes_and_opens_on_time_and_cuts_the_radio_path() -> None:
    sc = parse_scenario(
        doc(
            radio={"wall_loss_db": {"door": 40.0}, "shadow_sigma_db": 0.0, "fading": False},
            walls=[
                {
                    "points": [[3, -1.5], [3, 1.5]],
                    "material": "door",
                    "appear_s": 5,
                    "disappear_s": 25,
                }
            ],
        )
    )
    w = World(sc, seed=1)
    open_dbm = w.hop(0).power_dbm
    w.advance(4.9)
    assert w.timed_present == [False]
    w.advance(5.0)
    assert w.timed_present == [True]
    assert w.hop(0).power_dbm == pytest.approx(open_dbm - 40.0)
    assert w.hop(0).walls == 1
    assert min(w.sonar_mm(0, 0.0, 0.0, 0.0)[3:5]) < 3100  # the front sonars see the door
    w.advance(25.0)
    assert w.timed_present == [False]
    assert w.hop(0).power_dbm == pytest.approx(open_dbm)


def test_a_door_never_shuts_on_a_robot_in_the_doorway() -> None:
    sc = parse_scenario(
        doc(
            walls=[{"points": [[0, -1.5], [0, 1.5]], "material": "door", "appear_s": 5}],
            radio={"wall_loss_db": {"door": 40.0}},
        )
    )
    w = World(sc, seed=1)
    w.advance(6.0)
    assert w.timed_present == [False]  # relay r1 stands at x = 0, in the doorway
    w.set_pose(0, -1500.0, 0.0, 0.0)
    w.advance(6.1)
    assert w.timed_present == [True]
    assert w.collisions() == 0


def test_a_door_is_held_open_for_a_robot_about_to_pass_it() -> None:
    """A door appearing 0.1 m ahead of a moving relay is a contact no controller avoids."""
    sc = parse_scenario(
        doc(
            walls=[{"points": [[0, -1.5], [0, 1.5]], "material": "door", "appear_s": 5}],
            radio={"wall_loss_db": {"door": 40.0}},
        )
    )
    w = World(sc, seed=1)
    # The robot's front (half its length ahead of the centre) 0.3 m short of the door.
    w.set_pose(0, -(ROBOT_LENGTH_M / 2 + 0.3) * 1000.0, 0.0, 0.0)
    w.advance(6.0)
    assert w.timed_present == [False]
    w.set_pose(0, -(ROBOT_LENGTH_M / 2 + DOOR_CLEAR_M + 0.1) * 1000.0, 0.0, 0.0)
    w.advance(6.1)
    assert w.timed_present == [True]


def test_the_command_center_is_carried_along_its_waypoints() -> None:
    sc = parse_scenario(
        doc(
            command_center={
                "x": 0.0,
                "y": 0.0,
                "start_s": 10.0,
                "speed_m_s": 0.1,
                "waypoints": [{"x": 0.0, "y": -5.0}],
            }
        )
    )
    w = World(sc, seed=1)
    w.advance(5.0)
    assert w.node_pos(2) == (0.0, 0.0)
    w.advance(30.0)
    assert w.node_pos(2) == pytest.approx((0.0, -2.0))
    w.advance(500.0)
    assert w.node_pos(2) == pytest.approx((0.0, -5.0))


# -- summary ---------------------------------------------------------------------------


def rec(
    t: float,
    broken: bool,
    phase: str = "idle",
    episodes: int = 0,
    dist: float | None = None,
    outcome: str | None = None,
    kind: str | None = None,
) -> dict[str, Any]:
    return {
        "t": t,
        "broken": broken,
        "relays": [
            {
                "recovery": {
                    "phase": phase,
                    "kind": kind,
                    "episodes": episodes,
                    "distance_m": dist,
                    "outcome": outcome,
                }
            }
        ],
    }


def test_link_breaks_merge_flicker_and_keep_an_open_break_open() -> None:
    states = [False] * 10 + [True] * 5 + [False] * 5 + [True] * 3 + [False] * 30 + [True] * 4
    records = [rec(round(0.1 * k, 2), b) for k, b in enumerate(states)]
    breaks = link_breaks(records)
    assert [(b["start_s"], b["end_s"]) for b in breaks] == [(1.0, 2.3), (5.3, None)]
    assert breaks[0]["duration_s"] == pytest.approx(1.3)
    assert downtime_s(records) == pytest.approx(0.5 + 0.3 + 0.3)


def test_recovery_episodes_from_the_trace() -> None:
    records = [
        rec(0.0, False),
        rec(0.1, False, "widen", 1, 0.0, None, "leader"),
        rec(0.2, False, "retrace", 1, 0.4, None, "leader"),
        rec(0.3, False, "backup", 2, 0.0, "preempted", "rear"),
        rec(0.4, False, "backup", 2, 1.2, "preempted", "rear"),
        rec(0.5, False, "idle", 2, None, "restored"),
        rec(0.6, False, "gave_up", 2, None, "restored"),
    ]
    eps = recovery_episodes(records, 0)
    assert [(e["kind"], e["start_s"], e["end_s"], e["outcome"], e["distance_m"]) for e in eps] == [
        ("leader", 0.1, 0.3, "preempted", 0.4),
        ("rear", 0.3, 0.5, "restored", 1.2),
    ]


# -- the shipped scenarios, recovery on vs off ------------------------------------------


def _run(name: str, recovery: bool, seed: int = 1) -> dict[str, Any]:
    runner = SimRunner(load_scenario(name), speed=None, seed=seed, recovery=recovery)
    summary: dict[str, Any] = vtime.run(runner.run(), speed=None).summary
    return summary


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_drift_the_rear_link_heals_only_with_recovery() -> None:
    off, on = _run("drift", False), _run("drift", True)
    assert off["collisions"] == on["collisions"] == 0
    # Off: the relay stands where its leader stopped; the command center carried away
    # breaks the link for good.
    assert off["link_breaks"] and off["link_breaks"][-1]["end_s"] is None
    assert off["followers"][0]["recovery_episodes"] == []
    # On: it backs along its trail and the link stays up or heals within 60 s.
    assert all(b["duration_s"] is not None and b["duration_s"] <= 60 for b in on["link_breaks"])
    assert on["downtime_s"] < off["downtime_s"]
    eps = on["followers"][0]["recovery_episodes"]
    assert any(
        e["kind"] == "rear" and e["outcome"] == "restored" and e["distance_m"] > 1.0 for e in eps
    )
    assert all(e["distance_m"] <= 8.0 + 0.05 for e in eps)
    assert all(e["end_s"] is None or e["end_s"] - e["start_s"] <= 60.0 + 0.2 for e in eps)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_door_breaks_the_link_while_shut_and_heals_when_it_opens() -> None:
    for recovery in (False, True):
        s = _run("door", recovery)
        assert s["collisions"] == 0
        first = s["link_breaks"][0]
        assert 44.0 <= first["start_s"] <= 47.0 and first["end_s"] is not None
        assert math.isclose(first["end_s"], 65.0, abs_tol=2.0)
