"""situation_speed: an echo beside the robot's path slows it no lower than
control.beside_speed_floor; what may lie in its path still slows it to a stop.

In a 1.5 m corridor of the generated corridor networks the 50 deg sonars read 0.4-0.7 m
off the walls; the paper's law slowed a relay a little off centre to a stop there, and the
escape's watchdog took that for stuck and backed it off 1.2 m, again and again."""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given
from hypothesis import strategies as st

from relayd.core.avoid.ring import by_heading, path_blocked
from relayd.core.control.law import ControlParams, speed_scale
from relayd.core.control.steer import BESIDE_RAMP_M, in_path_m, situation_speed
from relayd.core.scan.estimator import nearest_front_m
from tests.core.control.test_law import sonar, step

FLOOR = ControlParams()
PAPER = dataclasses.replace(FLOOR, beside_speed_floor=0.0)


def paper(ring: tuple) -> float:
    d = nearest_front_m(ring)
    assert d is not None
    return speed_scale(d, FLOOR.threshold_o_m, FLOOR.stop_distance_m)


def test_on_by_default() -> None:
    assert FLOOR.beside_speed_floor == 0.3


@pytest.mark.parametrize("index", [1, 6])  # the 50 deg sonars, left and right
def test_a_wall_beside_slows_no_lower_than_the_floor(index: int) -> None:
    beside = sonar(**{f"s{index}": 400})  # 0.4 m: the paper's law at a fifth of its speed
    assert paper(beside) == pytest.approx(0.2)
    assert situation_speed(0.4, beside, FLOOR) == pytest.approx(0.3)
    assert situation_speed(0.4, beside, PAPER) == pytest.approx(paper(beside))
    # Within BESIDE_RAMP_M of the stop distance the floor fades: 0.31 m, a tenth of it.
    near = sonar(**{f"s{index}": 310})
    assert situation_speed(0.31, near, FLOOR) == pytest.approx(0.03)
    # Above the floor, the paper's own scale.
    wide = sonar(**{f"s{index}": 700})
    assert situation_speed(0.7, wide, FLOOR) == pytest.approx(paper(wide))


@pytest.mark.parametrize("index", [3, 4, 2, 5])  # ahead, and the 30 deg sonars near the path
def test_what_may_lie_in_the_path_still_slows_by_the_papers_scale(index: int) -> None:
    # 0.4 m, beyond the floor's fade: the paper's 0.2, not the floor's 0.3.
    ahead = sonar(**{f"s{index}": 400})
    assert situation_speed(0.4, ahead, FLOOR) == pytest.approx(0.2)
    assert situation_speed(0.3, sonar(**{f"s{index}": 300}), FLOOR) == 0.0


@given(
    ranges=st.lists(st.one_of(st.none(), st.integers(100, 5000)), min_size=8, max_size=8),
    floor=st.floats(0.0, 1.0),
)
def test_never_faster_than_the_papers_scale_or_the_floor(
    ranges: list[int | None], floor: float
) -> None:
    ring = sonar(**{f"s{i}": r for i, r in enumerate(ranges)})
    d = nearest_front_m(ring)
    if d is None:
        return
    params = dataclasses.replace(FLOOR, beside_speed_floor=floor)
    share = situation_speed(d, ring, params)
    assert 0.0 <= share <= max(paper(ring), floor) + 1e-9
    # Never faster than what may lie in the path allows (the paper's scale for it).
    in_path = in_path_m(by_heading(ring))
    assert share <= speed_scale(in_path, FLOOR.threshold_o_m, FLOOR.stop_distance_m) + 1e-9
    if in_path >= FLOOR.threshold_o_m:
        # Nothing near that may lie in the path: the paper's scale or the (faded) floor,
        # whichever is more.
        ramp = min(max((d - FLOOR.stop_distance_m) / BESIDE_RAMP_M, 0.0), 1.0)
        assert share == pytest.approx(max(paper(ring), floor * ramp))


@given(
    ranges=st.lists(st.one_of(st.none(), st.integers(100, 5000)), min_size=8, max_size=8),
    bearing=st.floats(-90.0, 90.0),
)
def test_the_law_never_drives_toward_an_echo_in_its_path_below_the_stop_distance(
    ranges: list[int | None], bearing: float
) -> None:
    ring = sonar(**{f"s{i}": r for i, r in enumerate(ranges)})
    out = step(front_sonar=ring, bearing_deg=bearing, prev_bearing_deg=bearing)
    if path_blocked(ring, FLOOR.stop_distance_m):
        assert out.left_mm_s + out.right_mm_s <= 0.0
    assert max(abs(out.left_mm_s), abs(out.right_mm_s)) <= FLOOR.v_max_mm_s + 1e-6


def test_in_a_corridor_off_centre_the_law_keeps_moving() -> None:
    # 1.5 m corridor, 0.15 m right of its middle: the right 50 deg sonar at 0.38 m, the
    # left at 0.9, the 30s beyond their in-path ranges, the way ahead open.
    ring = sonar(s1=900, s2=1500, s3=5000, s4=5000, s5=700, s6=380, s7=410, s0=1100)
    moving = step(front_sonar=ring, bearing_deg=0.0, prev_bearing_deg=0.0)
    crawling = step(front_sonar=ring, bearing_deg=0.0, prev_bearing_deg=0.0, params=PAPER)
    # 0.08 m beyond the stop distance: the floor at 0.8 of itself, 0.24 of 350 mm/s,
    # against the paper's 0.16.
    assert moving.left_mm_s + moving.right_mm_s == pytest.approx(2 * 0.24 * 350.0, abs=2)
    assert crawling.left_mm_s + crawling.right_mm_s == pytest.approx(2 * 0.16 * 350.0, abs=2)
