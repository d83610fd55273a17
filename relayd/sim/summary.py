"""summary.json from a run's trace: pure functions of the records, nothing else.

Kept apart from the runner so that what a run *means* (goal reached, gaps, commands
stuck on their way) can be read and tested without starting a simulation.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import Any

from relayd.core.vocab import LINK_RULE_ENDS, Reason
from relayd.sim.outcomes import downtime_s, link_breaks, recovery_episodes


def unapplied_command_s(records: Sequence[dict[str, Any]], i: int, grace_s: float = 1.0) -> float:
    """Clock seconds relay i's daemon commanded wheel motion the robot never started on.

    The fake robot accelerates within a few tenths of a second, so a daemon that has
    commanded more than 50 mm/s for longer than `grace_s` while the true speed is still
    zero has commands stuck on their way (a queue backlog, a dead link). Stalls against
    an obstacle do not count: the robot's speed stays set while the world rejects it.
    """
    total = 0.0
    since: float | None = None
    prev_t: float | None = None
    for r in records:
        rel = r["relays"][i]
        wheels = rel.get("wheels") or [0, 0]
        stuck = (
            max(abs(wheels[0]), abs(wheels[1])) > 50
            and rel.get("v_mm_s", 0) == 0
            and abs(rel.get("w_deg_s", 0)) == 0
        )
        if stuck:
            since = r["t"] if since is None else since
            if prev_t is not None and r["t"] - since > grace_s:
                total += r["t"] - prev_t
        else:
            since = None
        prev_t = r["t"]
    return round(total, 2)


def stuck_s(
    records: Sequence[dict[str, Any]], i: int, window_s: float = 10.0, progress_m: float = 0.5
) -> float:
    """Seconds relay i spent stuck: off the link rule (avoiding, lost, searching, blocked:
    not following anyone, core/vocab.py LINK_RULE_ENDS) while it had moved less than
    `progress_m` over the last `window_s`. A relay that avoids its way round a box keeps
    moving and does not count; one pressed against a wall, or scanning in place for a
    leader it lost, does."""
    total = 0.0
    trail: deque[tuple[float, float, float]] = deque()  # (t, x, y) within the window
    prev_t: float | None = None
    for r in records:
        rel = r["relays"][i]
        t, x, y = r["t"], rel["x"], rel["y"]
        trail.append((t, x, y))
        while trail[0][0] < t - window_s:
            trail.popleft()
        if (
            prev_t is not None
            and rel["reason"] not in LINK_RULE_ENDS
            and t - records[0]["t"] >= window_s
            and max(math.hypot(x - px, y - py) for _, px, py in trail) < progress_m
        ):
            total += t - prev_t
        prev_t = t
    return round(total, 2)


#: A leader within this of its relay (m, centre to centre) is one the sonar may hear.
SONAR_NEAR_M = 3.0


def ended_on_rule(
    records: Sequence[dict[str, Any]], i: int, window_s: float = 3.0, progress_m: float = 0.3
) -> bool:
    """Did relay i end on the link rule or still following (core/vocab.py LINK_RULE_ENDS)?

    The paper's situation 1 ("obstacle": slowing and steering off a near echo) is part
    of its following law too, and a relay closing on a leader the sonar hears ends on
    it. It counts only for that: the leader within SONAR_NEAR_M, and the relay closing,
    at least `progress_m` on within the last `window_s` and its gap not grown over them.
    One standing at a wall on it, crawling along one with its leader far beyond (the
    paper's failure this project's slide is for), or losing ground, is not following.
    """
    if not records:
        return False
    last = records[-1]
    rel = last["relays"][i]
    if rel["reason"] in LINK_RULE_ENDS:
        return True
    if rel["reason"] != Reason.OBSTACLE or last["t"] - records[0]["t"] < window_s:
        return False
    recent = [r["relays"][i] for r in records if r["t"] >= last["t"] - window_s]
    moved = max(math.hypot(rel["x"] - r["x"], rel["y"] - r["y"]) for r in recent)
    closing = rel["gap_m"] <= recent[0]["gap_m"]
    return moved >= progress_m and closing and rel["gap_m"] <= SONAR_NEAR_M


def summarize(
    records: Sequence[dict[str, Any]],
    *,
    scenario: str,
    relays: int,
    goal: tuple[float, float],
    goal_radius_m: float,
    collisions: int,
    followers: Sequence[dict[str, Any]],
) -> dict[str, Any]:
    """summary.json from the trace: the keys docs/SIMULATOR.md lists.

    goal_reached: the leader got within goal_radius_m of its final waypoint while the
    end-to-end link had held all the way (the paper's "reached the destination while
    staying connected"). link_broken_at_s: the first record with any hop down. It is
    also split three ways, so that a stuck relay never reads as a green run:
    leader_arrived (the leader reached its goal), link_held (no hop was ever down), and
    relays_ok (every relay ended on the link rule or still following, each follower's
    on_link_rule: `ended_on_rule`).
    """
    broken_at = next((r["t"] for r in records if r["broken"]), None)
    arrived_at = next(
        (
            r["t"]
            for r in records
            if math.hypot(r["leader"]["x"] - goal[0], r["leader"]["y"] - goal[1]) <= goal_radius_m
        ),
        None,
    )
    reached = arrived_at is not None and (broken_at is None or broken_at > arrived_at)
    e2e = [r["e2e_mbps"] for r in records]
    last = records[-1] if records else None
    out_followers = []
    for i, f in enumerate(followers):
        gaps = [r["relays"][i]["gap_m"] for r in records]
        out_followers.append(
            {
                "name": f["name"],
                "max_gap_m": round(max(gaps), 3) if gaps else None,
                "final_gap_m": round(gaps[-1], 3) if gaps else None,
                "stopped_reason": None if last is None else last["relays"][i]["reason"],
                "on_link_rule": ended_on_rule(records, i),
                "final_state": None if last is None else last["relays"][i]["state"],
                "collisions": f["collisions"],
                "travelled_m": round(f["travelled_m"], 3),
                "unapplied_command_s": unapplied_command_s(records, i) if records else 0.0,
                "stuck_s": stuck_s(records, i),
                "recovery_episodes": recovery_episodes(records, i),
            }
        )
    return {
        "scenario": scenario,
        "relays": relays,
        "sim_seconds": round(last["t"], 2) if last else 0.0,
        "goal_reached": reached,
        "goal_reached_at_s": arrived_at,
        "leader_arrived": arrived_at is not None,
        "link_held": broken_at is None,
        "relays_ok": all(f["on_link_rule"] for f in out_followers),
        "link_broken_at_s": broken_at,
        "min_e2e_mbps": min(e2e) if e2e else 0.0,
        "final_e2e_mbps": e2e[-1] if e2e else 0.0,
        "collisions": collisions,
        "link_breaks": link_breaks(records),
        "downtime_s": downtime_s(records) if records else 0.0,
        "followers": out_followers,
    }
