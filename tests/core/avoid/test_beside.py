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
from relayd.core.avoid.ring import guard, jammed_beside
from relayd.core.avoid.state import AvoidMode, AvoidState
from tests.core.avoid.test_escape import ACT, P, ring, sense
from tests.core.avoid.test_unstick import _final

#: Grazing the corridor's left wall: its 50 and 90 deg sonars at 0.28 and 0.29 m, the
#: way ahead open, the leader 47 deg left beyond the wall (corridors 52 at t = 136 s).
GRAZE = ring(s0=290, s1=280, s15=420, s14=700)


def test_on_by_default() -> None:
    assert P.beside_turn and P.unpin


def test_a_graze_turns_away_at_once_without_backing_off() -> None:
    st, cmd = avoid_step(AvoidState(), sense(10.0, GRAZE, 47.0), P, ACT)
    assert st.escape_t == 10.0 and st.side == -1  # round it on the right, away from the wall
    assert st.mode is not AvoidMode.BACKOFF and cmd.vel_mm_s >= 0
    off = dataclasses.replace(P, beside_turn=False)
    st, cmd = avoid_step(AvoidState(), sense(10.0, GRAZE, 47.0), off, ACT)
    assert st.mode is AvoidMode.BACKOFF and cmd.vel_mm_s < 0  # as before


@pytest.mark.parametrize("ahead_mm", [300, 1390])
def test_something_ahead_is_still_backed_off_from(ahead_mm: int) -> None:
    # A box in the way (the 10 deg sonar) is a hit ahead: room to turn comes from backing off.
    ranges = ring(s1=280, s3=ahead_mm)
    st, cmd = avoid_step(AvoidState(), sense(10.0, ranges, 20.0), P, ACT)
    assert st.mode is AvoidMode.BACKOFF and cmd.vel_mm_s < 0


def test_a_wall_along_the_side_is_told_from_a_jamb() -> None:
    wall = sense(0.0, ring(s0=290, s15=300))
    jamb = sense(0.0, ring(s0=290))  # the rear corner's sonar sees past it: a door's jamb
    assert jammed_beside(wall.sonar, wall.rear, 0.085)
    assert not jammed_beside(jamb.sonar, jamb.rear, 0.085)
    right = sense(0.0, ring(s7=290, s8=300))
    assert jammed_beside(right.sonar, right.rear, 0.085)
    assert not jammed_beside(sense(0.0, ring()).sonar, sense(0.0, ring()).rear, 0.085)


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


def test_pinned_in_align_with_the_way_ahead_open_it_turns_on_the_move() -> None:
    # Corridors 63 at t = 132.4 s: the creep's rear corner would swing into the wall
    # (sonar 15 at 0.2 m), nothing behind has room, the way ahead is open. Rounding would
    # hand straight back to ALIGN (the leader's direction is open) and hold: it stood so
    # for 87 s. The paper's law turns while it drives on.
    pinned = ring(s0=330, s15=200, **{f"s{i}": 350 for i in range(9, 15)})
    st, cmd = avoid_step(ALIGNING, sense(132.4, pinned, -19.0), P, ACT)
    assert cmd.follow and st.mode is AvoidMode.FOLLOW
    off = dataclasses.replace(P, unpin=False)
    st, cmd = avoid_step(ALIGNING, sense(132.4, pinned, -19.0), off, ACT)
    assert not cmd.follow and st.mode is AvoidMode.WALL  # rounding, as before
    # Something ahead: no hand-back (the guard would stop the paper's law at once).
    ahead = list(pinned)
    ahead[3] = 600
    st, cmd = avoid_step(ALIGNING, sense(132.4, ahead, -19.0), P, ACT)
    assert not cmd.follow


@given(
    ranges=st.lists(st.integers(100, 5000), min_size=16, max_size=16),
    bearing=st.floats(-90.0, 90.0),
    mode=st.sampled_from([AvoidMode.ALIGN, AvoidMode.TURN, AvoidMode.FOLLOW]),
)
def test_what_the_wheels_are_told_is_what_the_guard_allows(
    ranges: list[int], bearing: float, mode: AvoidMode
) -> None:
    st0 = dataclasses.replace(ALIGNING, mode=mode)
    s = sense(151.5, list(ranges), bearing)
    _, cmd = avoid_step(st0, s, P, ACT)
    if not cmd.follow:
        assert guard(cmd.vel_mm_s, cmd.rvel_deg_s, s.sonar, P.stop_distance_m, s.rear) == (
            cmd.vel_mm_s,
            cmd.rvel_deg_s,
        )


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
