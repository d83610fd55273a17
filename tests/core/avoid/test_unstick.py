"""An escape never stands still for good ([avoidance] blocked_retry_s, unpin).

Generated corridor networks ended with relay1 on "blocked" 20-34 m behind its leader in
10 of 200 worlds: a BLOCKED escape waited for the leader to come back in front of it,
which in a building it never does (corridors 20: the escape had strayed 6 m down a hall
whose wall the leader's signal came through). And in corridors 2 a turn in place the
guard refused (the corridor's corner along the right and behind) was held for the rest
of the run. These are the rules that end both, unit by unit and with the simulator.
"""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given
from hypothesis import strategies as st

from relayd.core.avoid.escape import avoid_step
from relayd.core.avoid.ring import guard
from relayd.core.avoid.state import AvoidMode, AvoidParams, AvoidState, episode_only
from relayd.core.avoid.unpin import UNPIN_MARGIN_M, rear_swing_m
from relayd.core.control.law import ControlParams
from relayd.core.geometry import HALF_WIDTH_M, SONAR_POSES
from tests.core.avoid.test_escape import ACT, P, ring, sense

#: A BLOCKED escape since t=100 s, the leader 56 deg left (not ahead), the way open.
BLOCKED = AvoidState(mode=AvoidMode.BLOCKED, mode_t=100.0, escape_t=40.0, side=-1)
OPEN = ring()


def test_on_by_default_and_from_the_config() -> None:
    assert (P.blocked_retry_s, P.blocked_retry_max_s, P.unpin) == (10.0, 80.0, True)
    assert ControlParams().avoid.blocked_retry_s == 10.0


def test_a_block_waits_then_starts_a_fresh_escape() -> None:
    st, cmd = avoid_step(BLOCKED, sense(109.9, OPEN, 56.0), P, ACT)
    assert st.mode is AvoidMode.BLOCKED and (cmd.vel_mm_s, cmd.rvel_deg_s) == (0, 0)
    assert cmd.reason == "blocked"
    st, cmd = avoid_step(st, sense(110.0, OPEN, 56.0), P, ACT)
    assert cmd.follow and st.mode is AvoidMode.FOLLOW
    # A fresh escape: no episode, no side, nothing spent; only the wait is remembered.
    assert st.escape_t is None and st.side == 0 and st.hit_at is None
    assert (st.path_m, st.turned_deg, st.retry_wait_s) == (0.0, 0.0, 10.0)


@pytest.mark.parametrize(
    ("last_s", "wait_s"), [(0.0, 10.0), (10.0, 20.0), (40.0, 80.0), (80.0, 80.0)]
)
def test_each_block_of_a_run_of_escapes_waits_twice_as_long(last_s: float, wait_s: float) -> None:
    st0 = dataclasses.replace(BLOCKED, retry_wait_s=last_s)
    st, _ = avoid_step(st0, sense(100.0 + wait_s - 0.1, OPEN, 56.0), P, ACT)
    assert st.mode is AvoidMode.BLOCKED
    st, cmd = avoid_step(st0, sense(100.0 + wait_s, OPEN, 56.0), P, ACT)
    assert cmd.follow and st.retry_wait_s == wait_s


def test_an_escape_that_ends_free_forgets_the_waits() -> None:
    # Free of echoes for episode_clear_s after a retried escape: the next block is a new one.
    st = AvoidState(escape_t=50.0, side=1, retry_wait_s=40.0, anchor=(0.0, 0.0), anchor_t=60.0)
    st, _ = avoid_step(st, sense(60.0, OPEN, 0.0), P, ACT)
    moved = (2000.0, 0.0, 0.0)  # it drove on: no progress watchdog
    st, cmd = avoid_step(st, sense(60.0 + P.episode_clear_s + 0.1, OPEN, 0.0, moved), P, ACT)
    assert cmd.follow and st.escape_t is None and st.retry_wait_s == 0.0


def test_a_retried_escape_that_runs_free_forgets_the_waits() -> None:
    # The fresh escape after a block has no episode; running free for episode_clear_s
    # ends the run of blocks all the same, so a block much later waits the first wait.
    st = AvoidState(retry_wait_s=80.0, anchor=(0.0, 0.0), anchor_t=0.0)
    for i, x in enumerate((0.0, 500.0, 1000.0, 1500.0)):
        t = i * (P.episode_clear_s / 2.0)
        st, cmd = avoid_step(st, sense(t, OPEN, 0.0, (x, 0.0, 0.0)), P, ACT)
        assert cmd.follow
    assert st.retry_wait_s == 0.0


def test_a_lost_leaders_stop_keeps_the_wait() -> None:
    st = dataclasses.replace(BLOCKED, mode=AvoidMode.WALL, retry_wait_s=40.0)
    assert episode_only(st, 120.0, P).retry_wait_s == 40.0


def test_off_a_block_holds_until_the_leader_is_ahead() -> None:
    off = dataclasses.replace(P, blocked_retry_s=0.0)
    st, cmd = avoid_step(BLOCKED, sense(10_000.0, OPEN, 56.0), off, ACT)
    assert st.mode is AvoidMode.BLOCKED and cmd.reason == "blocked"
    st, cmd = avoid_step(st, sense(10_000.1, OPEN, 5.0), off, ACT)  # as before: ahead and open
    assert cmd.follow and st.mode is AvoidMode.FOLLOW


@given(
    since_s=st.floats(0.0, 500.0),
    last_s=st.sampled_from([0.0, 10.0, 20.0, 40.0, 80.0]),
    bearing=st.floats(-180.0, 180.0),
    ranges=st.lists(st.integers(100, 5000), min_size=16, max_size=16),
)
def test_a_block_never_moves_the_wheels_itself(
    since_s: float, last_s: float, bearing: float, ranges: list[int]
) -> None:
    # It waits with wheels at zero, or it hands the wheels back to the paper's law (whose
    # command the guard still checks); nothing in between.
    st0 = dataclasses.replace(BLOCKED, retry_wait_s=last_s)
    st, cmd = avoid_step(st0, sense(100.0 + since_s, list(ranges), bearing), P, ACT)
    if not cmd.follow:
        assert (cmd.vel_mm_s, cmd.rvel_deg_s, cmd.reason) == (0, 0, "blocked")
        assert st.mode is AvoidMode.BLOCKED
    elif abs(bearing) >= 30.0:
        assert since_s >= min(P.blocked_retry_max_s, max(P.blocked_retry_s, 2 * last_s))


# --- a turn in place the guard refuses ------------------------------------------------------

#: Generated corridors 2 at t=120.2 s: turning right (side -1) round the corner, the
#: corridor's wall along the right (sonars 5-7 at 0.31-0.34 m) and behind (9-11), the way
#: ahead and to the left open. The guard refuses the turn (no room for the corners) and
#: there is no room to back off.
PINNED = ring(s5=334, s6=314, s7=344, s8=519, s9=337, s10=331, s11=350)
TURNING = AvoidState(
    mode=AvoidMode.TURN, mode_t=119.0, side=-1, escape_t=93.0, hit_at=(0.0, 0.0), anchor_t=119.0
)


def test_pinned_it_creeps_on_along_an_arc_away_from_the_wall() -> None:
    _, cmd = avoid_step(TURNING, sense(120.2, PINNED, 42.0), P, ACT)
    assert not cmd.follow and cmd.reason == "avoiding"
    assert cmd.vel_mm_s > 0 and cmd.rvel_deg_s > 0  # on, veering left: away from the wall
    # What the wheels are told is what the guard allows.
    assert guard(cmd.vel_mm_s, cmd.rvel_deg_s, sense(0, PINNED).sonar, P.stop_distance_m) == (
        cmd.vel_mm_s,
        cmd.rvel_deg_s,
    )
    off = dataclasses.replace(P, unpin=False)
    _, cmd = avoid_step(TURNING, sense(120.2, PINNED, 42.0), off, ACT)
    assert (cmd.vel_mm_s, cmd.rvel_deg_s, cmd.reason) == (0, 0, "blocked")  # as before


def test_pinned_with_something_beside_the_rear_corner_it_holds() -> None:
    # The arc away from the wall swings the near side's rear corner out by rear_swing_m
    # (5.7 cm at the back-off speed and half the turn rate): an echo nearer than that
    # and the margin beside it (sonar 8, the rear ring's right side) holds the robot.
    swing = rear_swing_m(P.backoff_speed_mm_s, P.turn_rate_deg_s / 2.0)
    assert 0.05 < swing < 0.06
    inset_mm = 1000 * HALF_WIDTH_M - abs(SONAR_POSES[8].y_mm)  # the transducer's inside the side
    edge = round(inset_mm + 1000 * (swing + UNPIN_MARGIN_M))
    for mm, moves in ((140, False), (edge - 5, False), (edge + 5, True)):
        ranges = list(PINNED)
        ranges[8] = mm
        _, cmd = avoid_step(TURNING, sense(120.2, ranges, 42.0), P, ACT)
        assert (cmd.vel_mm_s > 0) is moves, (mm, cmd)
    # A rear ring never read: no creep either.
    blind = list(PINNED)
    blind[8] = None
    _, cmd = avoid_step(TURNING, sense(120.2, blind, 42.0), P, ACT)
    assert (cmd.vel_mm_s, cmd.rvel_deg_s) == (0, 0)


def test_boxed_in_it_holds() -> None:
    closed = ring(**{f"s{i}": 250 for i in range(16)})
    _, cmd = avoid_step(TURNING, sense(120.2, closed, 42.0), P, ACT)
    assert (cmd.vel_mm_s, cmd.rvel_deg_s, cmd.reason) == (0, 0, "blocked")


@given(
    ranges=st.lists(st.integers(100, 5000), min_size=16, max_size=16), side=st.sampled_from([-1, 1])
)
def test_unpinning_never_moves_toward_a_near_echo(ranges: list[int], side: int) -> None:
    turning = dataclasses.replace(TURNING, side=side)
    s = sense(120.2, list(ranges), 42.0)
    _, cmd = avoid_step(turning, s, P, ACT)
    if not cmd.follow:
        assert guard(cmd.vel_mm_s, cmd.rvel_deg_s, s.sonar, P.stop_distance_m, s.rear) == (
            cmd.vel_mm_s,
            cmd.rvel_deg_s,
        )


def test_the_settings_reach_the_escape_from_the_config() -> None:
    from relayd.config.load import parse_settings
    from relayd.config.params import control_params

    keys = {"blocked_retry_s": 5, "blocked_retry_max_s": 30, "unpin": False, "align_open_deg": 0}
    a = control_params(
        parse_settings({"control": {"rear_link": "ignore"}, "avoidance": keys})
    ).avoid
    assert (a.blocked_retry_s, a.blocked_retry_max_s, a.unpin, a.align_open_deg) == (
        5,
        30,
        False,
        0,
    )


# --- a jamb beside the way to the leader ----------------------------------------------------


def _first_escape(ranges: list[int | None], bearing: float, p: AvoidParams = P) -> AvoidState:
    """The escape's first step at a near echo (0.25 m, below the stop distance)."""
    st, _ = avoid_step(AvoidState(), sense(0.0, ranges, bearing), p, ACT)
    return st


def test_a_jamb_with_the_leaders_way_open_is_turned_from_onto_the_leader() -> None:
    # Generated corridors 141: at a corridor's mouth, nose 0.25 m off the jamb to the right
    # (sonar 4), the leader 32 deg left down the corridor, which the sonars near that
    # bearing see open. The escape went round the jamb, back up the hall it came down.
    jamb = ring(s4=250, s5=400)
    assert _first_escape(jamb, 32.0).mode is AvoidMode.ALIGN
    off = dataclasses.replace(P, align_open_deg=0.0)
    assert _first_escape(jamb, 32.0, off).mode in (
        AvoidMode.BACKOFF,
        AvoidMode.TURN,
        AvoidMode.LANE,
    )


def test_an_obstacle_in_the_leaders_way_is_still_gone_round() -> None:
    # The box dead ahead with the leader 20 deg left: its way is not open.
    box = ring(s2=250, s3=250, s4=250, s1=600)
    assert _first_escape(box, 20.0).mode is not AvoidMode.ALIGN
    # Nearly dead ahead, open or not: the paper's law was already steering at it.
    assert _first_escape(ring(s4=250), P.align_open_deg - 1.0).mode is not AvoidMode.ALIGN


# --- the generated corridor networks, with real daemons' brains in the simulator ----------


def _final(world: str, **avoidance: object) -> list[dict[str, object]]:
    """Each relay's last record of `world` (two relays, seed 1, as the sweep runs it)."""
    from relayd.runtime import vtime
    from relayd.sim.runner import SimRunner
    from relayd.sim.scenario import load_scenario

    sc = load_scenario(world).with_relays(2)
    sc = sc.model_copy(update={"avoidance": {**sc.avoidance, **avoidance}})
    result = vtime.run(SimRunner(sc, speed=None, seed=1).run())
    relays: list[dict[str, object]] = result.records[-1]["relays"]
    return relays


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_block_tried_again_takes_relay1_on_down_the_corridors() -> None:
    # Generated corridors 117: relay1's escape strayed 6 m at x = 17 m and stood "blocked"
    # for the rest of the run without the retry, its leader going on to x = 39 m.
    on = _final("generated:corridors:117")[0]
    off = _final("generated:corridors:117", blocked_retry_s=0)[0]
    assert on["reason"] == "rear_weak" and float(on["x"]) > 35.0, on  # type: ignore[arg-type]
    assert float(off["x"]) < 30.0, off  # type: ignore[arg-type]
    assert on["collisions"] == off["collisions"] == 0


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_corridors_mouth_beside_a_jamb_is_turned_into() -> None:
    # Generated corridors 141: without align_open_deg relay1 went round the jamb, back up
    # the hall, and lost its leader 32 m away. (Turning from a graze without backing off,
    # beside_turn, also gets it through on its own, so both are off for the comparison.)
    on = _final("generated:corridors:141")
    off = _final("generated:corridors:141", align_open_deg=0, beside_turn=False)
    assert [r["reason"] for r in on] == ["rear_weak", "rear_weak"], on
    assert off[0]["reason"] == "leader_lost", off
