"""keep_off_sides: the paper's law steered off a wall beside the robot (control.side_keep_m)."""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given
from hypothesis import strategies as st

from relayd.core.control.law import ControlParams, wheel_law
from relayd.core.control.steer import KEEP_PUSH_DEG, keep_off_sides
from relayd.core.scan.estimator import SonarReading
from tests.core.control.test_law import P, sonar, step, wire

LEFT, RIGHT = 0, 7  # the front ring's side sonars: +90 and -90 deg


def sides(left_mm: int | None, right_mm: int | None) -> tuple[SonarReading, ...]:
    return sonar(**{f"s{LEFT}": left_mm, f"s{RIGHT}": right_mm})


def test_on_by_default_and_off_at_zero() -> None:
    assert ControlParams().side_keep_m == 0.35
    assert keep_off_sides(7.0, 3.0, sides(100, 100), 0.0) == (7.0, 3.0)


def test_a_wall_near_on_the_right_turns_the_steer_left_in_proportion() -> None:
    assert keep_off_sides(0.0, None, sides(None, 100), 0.35)[0] == pytest.approx(
        KEEP_PUSH_DEG * 0.25 / 0.35
    )
    assert keep_off_sides(0.0, None, sides(100, None), 0.35)[0] == pytest.approx(
        -KEEP_PUSH_DEG * 0.25 / 0.35
    )
    # Beyond the keep distance, nothing; between two walls, toward the farther one.
    assert keep_off_sides(3.0, None, sides(400, 500), 0.35) == (3.0, None)
    assert keep_off_sides(0.0, None, sides(300, 100), 0.35)[0] > 0.0


@given(
    st.floats(-90, 90),
    st.one_of(st.none(), st.integers(0, 5000)),
    st.one_of(st.none(), st.integers(0, 5000)),
    st.floats(0.05, 1.5),
)
def test_the_push_is_bounded_and_never_toward_the_nearer_side(
    steer: float, left: int | None, right: int | None, keep: float
) -> None:
    kept, prev = keep_off_sides(steer, steer - 2.0, sides(left, right), keep)
    push = kept - steer
    assert prev is not None and prev - (steer - 2.0) == pytest.approx(push)  # D term: the bearing's
    assert abs(push) <= KEEP_PUSH_DEG + 1e-9
    far = 10_000
    lm, rm = (left if left is not None else far), (right if right is not None else far)
    if lm < rm:
        assert push <= 1e-9  # a nearer left wall never pulls the steer left
    if rm < lm:
        assert push >= -1e-9


def test_the_law_turns_off_a_glancing_wall_and_stays_within_v_max() -> None:
    near_right = sides(None, 200)
    paper = dataclasses.replace(ControlParams(), side_keep_m=0.0)
    plain = step(params=paper, bearing_deg=0.0, prev_bearing_deg=0.0, front_sonar=near_right)
    keep = ControlParams()
    kept = step(params=keep, bearing_deg=0.0, prev_bearing_deg=0.0, front_sonar=near_right)
    assert plain.left_mm_s == plain.right_mm_s  # the paper's law: straight at the bearing
    assert kept.right_mm_s > kept.left_mm_s  # turning left, off the wall on the right
    assert max(abs(kept.left_mm_s), abs(kept.right_mm_s)) <= keep.v_max_mm_s
    assert kept.reason == plain.reason == "driving"


def test_the_d_term_sees_the_bearing_change_not_the_push() -> None:
    """Bearing 6 after 2, a wall near on the right: the wheels are the law's on the pushed
    steer with the previous steer pushed alike (kd x 4, not kd x (4 + push))."""
    near_right = sides(None, 200)
    out = step(bearing_deg=6.0, prev_bearing_deg=2.0, front_sonar=near_right)
    kept, prev = keep_off_sides(6.0, 2.0, near_right, P.side_keep_m)
    assert prev is not None and kept - prev == pytest.approx(4.0)
    v = out.left_mm_s + out.right_mm_s  # 2 v: the turn cancels
    left, right = wheel_law(v / 2.0, kept, prev, P.kp, P.kd, P.v_max_mm_s)
    assert wire(left, right) == (out.left_mm_s, out.right_mm_s)
    without = step(bearing_deg=6.0, prev_bearing_deg=2.0, front_sonar=sides(None, None))
    assert out.right_mm_s - out.left_mm_s > without.right_mm_s - without.left_mm_s


def test_no_push_along_a_detour_or_in_the_obstacle_slow_down() -> None:
    near_right = sides(None, 200)
    paper = dataclasses.replace(P, side_keep_m=0.0)
    for changes in ({"detour_steer_deg": 0.0}, {"front_sonar": sonar(s0=None, s3=700, s7=200)}):
        kw = {"bearing_deg": 0.0, "prev_bearing_deg": 0.0, "front_sonar": near_right, **changes}
        on, off = step(**kw), step(params=paper, **kw)
        assert (on.left_mm_s, on.right_mm_s, on.reason) == (
            off.left_mm_s,
            off.right_mm_s,
            off.reason,
        )
        assert on.reason in ("detour", "obstacle")
