"""A wall beside the way is not met like a wall ahead ([avoidance] beside_turn, unpin).

Two rules from tracing generated corridor networks, where a relay heading for a leader
heard through a corridor's wall grazes that wall again and again:

- A hit by an echo beside the way (the +-10 and +-30 deg sonars see the way ahead open):
  the escape turns away at once. It used to back off 1.2 m first (12 s at the back-off
  speed) at every graze, since in a corridor the 50 deg sonars never see backoff_to_m;
  in the 33 corridor worlds that failed, relay1 spent 604 s backing off.
- A turn in place refused for a wall along the robot's side: the unpin's creep on an
  arc away from it, not the 0.3 m back-off, which runs along the wall and gains no room
  (corridors 116: ALIGN and its back-off took turns for 2.4 m until a rear corner
  touched the wall).
"""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given
from hypothesis import strategies as st

from relayd.core.avoid.escape import avoid_step
from relayd.core.avoid.ring import REAR_SIDE_SONAR, by_heading, guard, min_at, wall_along_side
from relayd.core.avoid.state import AvoidMode, AvoidState
from relayd.core.avoid.unpin import UNPIN_MARGIN_M, rear_swing_m
from relayd.core.geometry import HALF_WIDTH_M, SONAR_POSES
from tests.core.avoid.test_escape import ACT, P, ring, sense
from tests.core.avoid.test_unstick import _final

#: Grazing the corridor's left wall: its 50 and 90 deg sonars at 0.28 and 0.29 m, the
#: way ahead open, the leader 47 deg left beyond the wall (corridors 52 at t = 136 s).
GRAZE = ring(s0=290, s1=280, s15=420, s14=700)


def test_on_by_default() -> None:
    assert P.beside_turn and P.unpin


def test_a_graze_backs_off_only_the_unjams_way() -> None:
    # The wall 0.45 m off the left side, the 50 deg sonar at 0.28 m: the turn away has
    # no room yet (that echo is inside the corners' sweep), so it backs off the unjam's
    # 0.3 m and turns, not the 1.2 m the back-off after a hit ahead runs.
    graze = ring(s0=450, s1=280, s15=470, s14=800)
    st, cmd = avoid_step(AvoidState(), sense(10.0, graze, 10.0), P, ACT)
    assert st.escape_t == 10.0 and st.side == -1  # round it on the right, away from the wall
    assert st.mode is AvoidMode.BACKOFF and st.backoff_len_m == P.unjam_m
    assert st.after_backoff is AvoidMode.TURN and cmd.vel_mm_s < 0
    off = dataclasses.replace(P, beside_turn=False)
    st, cmd = avoid_step(AvoidState(), sense(10.0, graze, 10.0), off, ACT)
    assert st.mode is AvoidMode.BACKOFF and st.backoff_len_m == P.backoff_max_m  # as before


def test_a_graze_along_the_wall_creeps_off_it() -> None:
    # Nearer (0.29 m at the left 90 deg sonar, the rear corner's 0.42 m): no room to turn
    # in place, and backing off along the wall would not make any. It creeps on, veering
    # right, off the wall; without the creep it backs off the unjam's 0.3 m.
    st, cmd = avoid_step(AvoidState(), sense(10.0, GRAZE, 47.0), P, ACT)
    assert st.side == -1 and st.mode is not AvoidMode.BACKOFF
    assert cmd.vel_mm_s > 0 and cmd.rvel_deg_s < 0
    off = dataclasses.replace(P, unpin=False)
    st, cmd = avoid_step(AvoidState(), sense(10.0, GRAZE, 47.0), off, ACT)
    assert st.mode is AvoidMode.BACKOFF and cmd.vel_mm_s < 0


@pytest.mark.parametrize("ahead_mm", [300, 1390])
def test_something_ahead_is_still_backed_off_from(ahead_mm: int) -> None:
    # A box in the way (the 10 deg sonar) is a hit ahead: room to turn comes from backing off.
    ranges = ring(s1=280, s3=ahead_mm)
    st, cmd = avoid_step(AvoidState(), sense(10.0, ranges, 20.0), P, ACT)
    assert st.mode is AvoidMode.BACKOFF and cmd.vel_mm_s < 0


def test_a_wall_along_the_side_is_told_from_a_jamb() -> None:
    def side(ranges: list[int | None]) -> int:
        s = sense(0.0, ranges)
        return wall_along_side(s.sonar, s.rear, 0.085)

    assert side(ring(s0=290, s15=300)) == 1
    assert side(ring(s7=290, s8=300)) == -1
    assert side(ring(s0=290)) == 0  # the rear corner's sonar sees past it: a door's jamb
    assert side(ring(s0=290, s15=600)) == 0  # ... or sees something well beyond the sweep
    assert side(ring(s0=290, s15=300, s7=290, s8=300)) == 0  # both sides: nowhere to creep
    assert side(ring()) == 0


#: ALIGN, turning right onto a leader 54 deg right, a wall along the left 0.30 m off at
#: both corners: the corners' sweep has no room (corridors 116 at t = 151.5 s).
ALIGNING = AvoidState(mode=AvoidMode.ALIGN, mode_t=150.0, escape_t=149.0, side=-1)
ALONG_LEFT = ring(s0=300, s15=310)


def test_a_turn_refused_by_a_wall_along_the_side_creeps_away_instead_of_backing() -> None:
    _, cmd = avoid_step(ALIGNING, sense(151.5, ALONG_LEFT, -54.0), P, ACT)
    assert cmd.vel_mm_s > 0 and cmd.rvel_deg_s < 0  # on, veering right: away from the wall
    s = sense(151.5, ALONG_LEFT, -54.0)
    assert guard(cmd.vel_mm_s, cmd.rvel_deg_s, s.sonar, P.stop_distance_m, s.rear) == (
        cmd.vel_mm_s,
        cmd.rvel_deg_s,
    )
    off = dataclasses.replace(P, unpin=False)
    st, cmd = avoid_step(ALIGNING, sense(151.5, ALONG_LEFT, -54.0), off, ACT)
    assert st.mode is AvoidMode.BACKOFF and cmd.vel_mm_s < 0  # as before


def test_a_turn_refused_by_a_jamb_still_backs_out_of_the_door() -> None:
    jamb = ring(s0=300)
    st, cmd = avoid_step(ALIGNING, sense(151.5, jamb, -54.0), P, ACT)
    assert st.mode is AvoidMode.BACKOFF and cmd.vel_mm_s < 0


def test_aligning_onto_a_leader_beyond_the_wall_that_jams_it_goes_along_the_wall() -> None:
    # The leader 78 deg left, beyond the wall along the left that refuses the turn: the
    # creep off that wall would turn away from the leader, and round in circles
    # (corridors 78: 187 deg in 21 s). It goes along the wall (boundary on the left).
    st, cmd = avoid_step(ALIGNING, sense(151.5, ALONG_LEFT, 78.0), P, ACT)
    assert st.mode is AvoidMode.WALL and st.side == -1 and cmd.vel_mm_s >= 0
    off = dataclasses.replace(P, unpin=False)
    st, _ = avoid_step(ALIGNING, sense(151.5, ALONG_LEFT, 78.0), off, ACT)
    assert st.mode is AvoidMode.BACKOFF  # the unjam's back-off along the wall, as before


def test_pinned_in_align_with_the_way_ahead_open_it_goes_straight_on() -> None:
    # Corridors 63 at t = 132.4 s: the creep's rear corner would swing into the wall
    # (sonar 15 at 0.2 m), nothing behind has room, the way ahead is open. Rounding would
    # hand straight back to ALIGN (the leader's direction is open) and hold: it stood so
    # for 87 s. It goes straight on, which swings no corner out, until it can turn.
    pinned = ring(s0=330, s15=200, **{f"s{i}": 350 for i in range(9, 15)})
    st, cmd = avoid_step(ALIGNING, sense(132.4, pinned, -19.0), P, ACT)
    assert st.mode is AvoidMode.ALIGN and (cmd.vel_mm_s, cmd.rvel_deg_s) == (100, 0)
    off = dataclasses.replace(P, unpin=False)
    st, cmd = avoid_step(ALIGNING, sense(132.4, pinned, -19.0), off, ACT)
    assert not cmd.follow and st.mode is AvoidMode.WALL  # rounding, as before
    # Something ahead within threshold_o: not straight on.
    ahead = list(pinned)
    ahead[3] = 600
    st, _ = avoid_step(ALIGNING, sense(132.4, ahead, -19.0), P, ACT)
    assert st.mode is AvoidMode.WALL  # rounding, as before


def test_the_creep_goes_away_from_the_wall_that_jams_it() -> None:
    # The wall along the left jams the turn; an echo at the right 50 deg sonar is nearer
    # than the wall but is not along the side (its rear corner sees nothing). The creep
    # veers right, off the wall, not left into it.
    ranges = ring(s0=300, s15=310, s6=340)
    _, cmd = avoid_step(ALIGNING, sense(151.5, ranges, -54.0), P, ACT)
    assert cmd.vel_mm_s > 0 and cmd.rvel_deg_s < 0
    # With the right 50 deg sonar inside the stop distance, the front-right corner would
    # move toward it: no creep (it backs off the jamb's way instead, or holds).
    ranges = ring(s0=300, s15=310, s6=280)
    _, cmd = avoid_step(ALIGNING, sense(151.5, ranges, -54.0), P, ACT)
    assert not (cmd.vel_mm_s > 0 and cmd.rvel_deg_s != 0)


@given(
    ranges=st.lists(st.integers(100, 5000), min_size=16, max_size=16),
    bearing=st.floats(-90.0, 90.0),
    mode=st.sampled_from([AvoidMode.ALIGN, AvoidMode.TURN, AvoidMode.FOLLOW]),
)
def test_a_creep_checks_both_outer_corners_of_its_arc(
    ranges: list[int], bearing: float, mode: AvoidMode
) -> None:
    # Whatever the escape commands is what the guard allows; and a forward arc of the
    # escape's own (the creep) also keeps the two corners the guard does not check: the
    # rear corner swinging out on the side it turns from (that side's rear sonar sees the
    # swing and the margin beyond the body), the front corner moving toward the side it
    # turns to (that side's 50 and 90 deg sonars see the stop distance).
    st0 = dataclasses.replace(ALIGNING, mode=mode)
    s = sense(151.5, list(ranges), bearing)
    _, cmd = avoid_step(st0, s, P, ACT)
    if cmd.follow:
        return
    assert guard(cmd.vel_mm_s, cmd.rvel_deg_s, s.sonar, P.stop_distance_m, s.rear) == (
        cmd.vel_mm_s,
        cmd.rvel_deg_s,
    )
    if cmd.vel_mm_s > 0 and cmd.rvel_deg_s != 0 and cmd.vel_mm_s <= P.backoff_speed_mm_s:
        turn = 1 if cmd.rvel_deg_s > 0 else -1
        assert min_at(by_heading(s.sonar), (turn * 90.0, turn * 50.0)) >= P.stop_distance_m
        index = REAR_SIDE_SONAR[-turn]
        inset_m = HALF_WIDTH_M - abs(SONAR_POSES[index].y_mm) / 1000.0
        rear_m = ranges[index] / 1000.0 - inset_m
        assert rear_m >= rear_swing_m(cmd.vel_mm_s, cmd.rvel_deg_s) + UNPIN_MARGIN_M - 1e-9


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_no_long_reverse_along_a_wall_in_corridors_116() -> None:
    # With the graze rule and no creep, ALIGN's back-off took turns along the wall until a
    # rear corner touched it; with both, relay1 goes on to its link rule.
    relays = _final("generated:corridors:116")
    assert [r["collisions"] for r in relays] == [0, 0], relays
    assert relays[0]["reason"] == "rear_weak", relays[0]
    no_creep = _final("generated:corridors:116", unpin=False)
    assert no_creep[0]["collisions"] == 1, no_creep[0]
