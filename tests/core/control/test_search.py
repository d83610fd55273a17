"""The turn toward a lost leader last seen beyond the servo's reach (relayd.core.control.search), alone,
through the controller, and in the brain with a leader that ends up behind the relay."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.brainrig import BrainRig, cos_n_pattern
from relayd.core.avoid.ring import rear_readings
from relayd.core.control.actuator import Actuator
from relayd.core.control.law import ControlInputs, ControlMemory, ControlParams, control_step
from relayd.core.control.search import SearchParams, SearchState, search_step, search_wheels
from relayd.core.scan.estimator import front_readings
from relayd.core.vocab import DriveState, Mode

P = SearchParams()


def run(
    bearing0: float,
    steps: int,
    *,
    dt: float = 0.1,
    turns: bool = True,
    found_after: int | None = None,
) -> tuple[list[float], SearchState, float]:
    """Step the search with a robot that turns as asked (or not at all); the evidence stays
    where it was seen, in the world: (the rates asked for, the last state, the heading turned)."""
    st_, heading, t, rates = SearchState(), 0.0, 0.0, []
    for k in range(steps):
        if found_after is not None and k >= found_after:
            break
        st_, rvel = search_step(st_, math.remainder(bearing0 - heading, 360.0), heading, t, P)
        rates.append(rvel)
        if turns:
            heading += rvel * dt
        t += dt
    return rates, st_, heading


@settings(max_examples=200, deadline=None)
@given(b=st.floats(-180.0, 180.0))
def test_it_turns_toward_the_evidence_beyond_reach_and_not_otherwise(b: float) -> None:
    st_, rvel = search_step(SearchState(), b, 30.0, 5.0, P)
    if abs(b) >= P.min_bearing_deg:
        assert rvel == math.copysign(P.rate_deg_s, b) and st_.side == (1 if b > 0 else -1)
    else:
        assert rvel == 0.0 and st_ == SearchState()  # the full sweep covers it: stand
    _, rvel = search_step(SearchState(), None, 30.0, 5.0, P)
    assert rvel == 0.0


@settings(max_examples=100, deadline=None)
@given(b=st.floats(60.0, 180.0), side=st.sampled_from((-1.0, 1.0)))
def test_it_turns_until_the_evidence_is_ahead_then_stands(b: float, side: float) -> None:
    rates, st_, heading = run(side * b, 100)  # 10 s: time to face it, not the episode's end
    assert rates[0] == side * P.rate_deg_s
    moving = [r for r in rates if r != 0.0]
    assert all(r == side * P.rate_deg_s for r in moving)  # never back and forth
    # It stops within one step of facing where the leader was seen.
    assert abs(math.remainder(side * b - heading, 360.0)) <= P.rate_deg_s * 0.1 + 1e-9
    assert not st_.done and st_.side == (1 if side > 0 else -1)


@settings(max_examples=100, deadline=None)
@given(b=st.floats(60.0, 180.0), side=st.sampled_from((-1.0, 1.0)))
def test_at_most_one_full_turn_then_it_stands_for_good(b: float, side: float) -> None:
    # A leader that keeps moving away round the relay: the evidence stays beyond reach.
    st_, heading, t, total = SearchState(), 0.0, 0.0, 0.0
    for _ in range(2000):
        st_, rvel = search_step(st_, side * b, heading, t, P)
        heading = math.remainder(heading + rvel * 0.1, 360.0)
        total += abs(rvel) * 0.1
        t += 0.1
    assert P.max_turn_deg - 1.0 <= total <= P.max_turn_deg + P.rate_deg_s * 0.1 + 1e-9
    assert st_.done
    assert search_step(st_, side * b, heading, t, P)[1] == 0.0


def test_a_turn_that_never_happens_ends_on_time() -> None:
    # The guard refusing every step (a wall at the side): odometry never moves.
    rates, st_, _ = run(-150.0, 300, turns=False)
    limit = 1.5 * P.max_turn_deg / P.rate_deg_s
    assert st_.done and rates[-1] == 0.0
    assert sum(1 for r in rates if r != 0.0) == pytest.approx(limit / 0.1, abs=1)


def test_new_evidence_beyond_reach_on_the_other_side_turns_it_there() -> None:
    st_, rvel = search_step(SearchState(), -120.0, 0.0, 0.0, P)
    assert rvel < 0
    st_, rvel = search_step(st_, -40.0, -20.0, 1.0, P)  # still to the right: keep on
    assert rvel < 0
    st_, rvel = search_step(st_, 100.0, -20.0, 2.0, P)  # a later scan: far left
    assert rvel > 0 and st_.turned_deg == pytest.approx(20.0)


def test_disabled_or_without_odometry_it_stands() -> None:
    off = dataclasses.replace(P, enabled=False)
    assert search_step(SearchState(), 150.0, 0.0, 0.0, off)[1] == 0.0
    assert search_step(SearchState(), 150.0, None, 0.0, P)[1] == 0.0
    assert search_step(SearchState(), 150.0, 0.0, None, P)[1] == 0.0
    with pytest.raises(ValueError):
        SearchParams(rate_deg_s=0.0)


def test_the_guard_refuses_a_turn_without_room() -> None:
    act = Actuator()
    free = front_readings([None] * 16)
    left, right = search_wheels(25.0, act, free, rear_readings([None] * 16), 0.3, 400.0)
    assert right > 0 > left and act.vel_rvel(left, right)[1] == pytest.approx(25.0, abs=0.6)
    # Something inside the circle the corners sweep: no turn in place at all.
    near = [None] * 16
    near[0] = 350  # the left sonar, 0.35 m
    assert search_wheels(25.0, act, front_readings(near), rear_readings(near), 0.3, 400.0) == (
        0.0,
        0.0,
    )


# -- through the controller ------------------------------------------------------------


def lost_inputs(**changes: object) -> ControlInputs:
    base = ControlInputs(
        mode=Mode.FOLLOW,
        sip_age_s=0.1,
        rssi_age_s=0.1,
        scan_servo_ok=True,
        bearing_deg=None,
        prev_bearing_deg=None,
        rssi_leader_dbm=-40.0,
        rssi_behind_dbm=-40.0,
        rear_age_s=0.5,
        front_sonar=front_readings([None] * 16),
        leader_lost=True,
        t_s=10.0,
        odom=(0.0, 0.0, 90.0),
        rear_sonar=rear_readings([None] * 16),
        search_bearing_deg=-130.0,
    )
    return dataclasses.replace(base, **changes)  # type: ignore[arg-type]


def test_the_controller_turns_a_lost_relay_toward_a_leader_behind_it_and_forgets_once_found() -> (
    None
):
    p = ControlParams()
    out = control_step(lost_inputs(), p, ControlMemory(link_drive=True))
    assert out.state is DriveState.LEADER_LOST and out.reason == "leader_search"
    assert out.left_mm_s > 0 > out.right_mm_s  # to the right, in place
    assert out.memory.search.side == -1 and out.memory.link_drive
    # Found: the wheel law takes over, and the next loss starts afresh.
    found = control_step(
        lost_inputs(
            leader_lost=False, bearing_deg=-20.0, search_bearing_deg=None, rssi_leader_dbm=-50.0
        ),
        p,
        out.memory,
    )
    assert found.state is DriveState.DRIVING and found.memory.search == SearchState()


@pytest.mark.parametrize(
    "changes",
    [
        {"search_bearing_deg": None},  # nothing seen
        {"search_bearing_deg": -30.0},  # within the servo's sweep
        {"odom": None},
        {"front_sonar": front_readings([350] + [None] * 15)},  # no room to turn
    ],
)
def test_the_controller_keeps_the_wheels_at_zero_otherwise(changes: dict) -> None:
    out = control_step(lost_inputs(**changes), ControlParams(), ControlMemory())
    assert (out.left_mm_s, out.right_mm_s) == (0.0, 0.0) and out.reason == "leader_lost"
    assert out.state is DriveState.LEADER_LOST


@settings(max_examples=100, deadline=None)
@given(
    rate=st.floats(5.0, 90.0), v_max=st.floats(20.0, 1000.0), side=st.sampled_from([-130.0, 130.0])
)
def test_the_turn_keeps_each_wheel_within_v_max(rate: float, v_max: float, side: float) -> None:
    """As every follow-mode command: 90 deg/s is +-462 mm/s a wheel, 25 deg/s +-128."""
    p = ControlParams(v_max_mm_s=v_max, search=SearchParams(rate_deg_s=rate))
    out = control_step(lost_inputs(search_bearing_deg=side), p, ControlMemory())
    assert out.reason == "leader_search" or (out.left_mm_s, out.right_mm_s) == (0.0, 0.0)
    assert max(abs(out.left_mm_s), abs(out.right_mm_s)) <= v_max + 1e-9
    if out.reason == "leader_search":
        assert out.left_mm_s == -out.right_mm_s and (out.right_mm_s > 0) == (side > 0)


@pytest.mark.parametrize(
    "changes",
    [
        {"mode": Mode.HOLD},
        {"mode": Mode.MANUAL},
        {"sip_age_s": None},
        {"rssi_age_s": None},
        {"scan_servo_ok": False},
        {"rear_age_s": None},
    ],
)
def test_hold_manual_and_the_fail_safes_end_the_search(changes: dict) -> None:
    p = ControlParams()
    turning = control_step(lost_inputs(), p, ControlMemory(link_drive=True)).memory
    assert turning.search.side == -1
    out = control_step(lost_inputs(**changes), p, turning)
    assert (out.left_mm_s, out.right_mm_s) == (0.0, 0.0) and out.memory.search == SearchState()


def test_with_search_off_a_lost_relay_stands() -> None:
    p = ControlParams(search=SearchParams(enabled=False))
    out = control_step(lost_inputs(), p, ControlMemory())
    assert (out.left_mm_s, out.right_mm_s) == (0.0, 0.0) and out.reason == "leader_lost"


# -- in the brain --------------------------------------------------------------------------


def passing_leader(t: float) -> tuple[float, float]:
    """Ahead-left at 3.4 m for 20 s, then in 4 s past the relay's left side to right behind it."""
    s = min(1.0, max(0.0, (t - 20.0) / 4.0))
    return (3.0 - 6.0 * s, 1.5 - 1.5 * s)


@pytest.mark.parametrize("search", [True, False])
def test_a_leader_that_walks_past_the_relay_is_found_again_by_turning(search: bool) -> None:
    # "Leader near" at any RSSI (threshold_l -70 dBm): the paper's law never moves this
    # relay, so only the search can. The leader ends where no sweep of the servo's +-90
    # reaches it: the track is lost, its last fits at the left limit.
    r = BrainRig(
        scan={"estimator": "lobe", "window": "adaptive"},
        leader=passing_leader,
        pattern=cos_n_pattern(45.0, 15.0),
        mode=Mode.FOLLOW,
        control={"search_turn": search, "threshold_l_dbm": -70.0, "threshold_b_dbm": -90.0},
    )
    r.start()
    r.run_until(20.0)
    assert abs(r.true_bearing_deg() - 26.6) < 1.0 and r.theta_deg == 0.0
    seen: list[str] = []
    r.run_until(60.0, lambda rig: seen.append(rig.brain.last_output.reason))  # type: ignore[union-attr]
    if search:
        assert (
            "leader_search" in seen and "leader_search" not in seen[-50:]
        )  # over, 5 s ago at least
        # It turned left, toward where the leader went, until its last evidence (the left
        # limit) was ahead: the leader is in the servo's reach and found, where it stays.
        assert 60.0 < r.theta_deg <= 180.0
        assert abs(r.true_bearing_deg()) <= 90.0 + 1e-6 and not r.brain.inputs(r.t).leader_lost
        assert abs(r.bearing_now() - r.true_bearing_deg()) < 5.0  # type: ignore[operator]
    else:
        assert "leader_search" not in seen and r.theta_deg == 0.0
        assert abs(r.true_bearing_deg()) == pytest.approx(180.0) and r.brain.inputs(r.t).leader_lost
