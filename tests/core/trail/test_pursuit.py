"""The trail polyline, pure pursuit along it, and the law's trail hook."""

from __future__ import annotations

import dataclasses
import itertools
import math

from hypothesis import given, settings
from hypothesis import strategies as st

from relayd.core.avoid.ring import path_blocked
from relayd.core.control.law import ControlInputs, ControlMemory, ControlParams, control_step
from relayd.core.geometry import SONAR_HEADINGS_DEG
from relayd.core.scan.estimator import SonarReading, front_readings
from relayd.core.trail.polyline import TrailPoint, add_point, point_along, prune, remaining_m
from relayd.core.trail.pursuit import PursuitParams, lookahead_m, pursue
from relayd.core.vocab import DriveState, Mode

PP = PursuitParams()
TRAIL_P = ControlParams(pursuit="trail")


def pts(*xy: tuple[float, float]) -> tuple[TrailPoint, ...]:
    return tuple(TrailPoint(float(i), x, y) for i, (x, y) in enumerate(xy))


# --- the polyline -------------------------------------------------------------------------


def test_a_stopped_leader_adds_nothing_a_walking_one_a_point_per_spacing() -> None:
    trail: tuple[TrailPoint, ...] = ()
    for k in range(10):  # standing, with a little jitter
        trail = add_point(trail, TrailPoint(k, 0.01 * (k % 3), 0.0), spacing_m=0.4, keep=100)
    assert len(trail) == 2  # where it stood, and the head on its newest estimate
    for k in range(1, 21):  # walking 0.1 m per step: 2 m
        trail = add_point(trail, TrailPoint(10 + k, 0.1 * k, 0.0), spacing_m=0.4, keep=100)
    assert 5 <= len(trail) <= 7
    assert trail[-1].x_m == 2.0  # the head is the newest position
    assert all(b.x_m - a.x_m >= 0.39 for a, b in itertools.pairwise(trail[1:-1]))


def test_keep_bounds_the_trail() -> None:
    trail: tuple[TrailPoint, ...] = ()
    for k in range(50):
        trail = add_point(trail, TrailPoint(k, float(k), 0.0), spacing_m=0.4, keep=10)
    assert len(trail) == 10 and trail[-1].x_m == 49.0


def test_points_behind_the_relay_are_dropped() -> None:
    trail = pts((0, 0), (1, 0), (2, 0), (3, 0), (3, 1), (3, 2))
    # Between the second and third points: the segment it is on starts the trail.
    assert prune(trail, (1.6, 0.05), reach_m=0.4, window=8)[0].xy == (1, 0)
    assert prune(trail, (2.1, 0.0), reach_m=0.4, window=8)[0].xy == (2, 0)
    assert prune(trail, (0.9, 0.0), reach_m=0.4, window=8)[0].xy == (1, 0)
    # The head is never dropped, however far the relay ran.
    assert prune(trail, (9.0, 9.0), reach_m=0.4, window=8)[-1].xy == (3, 2)


def test_a_trail_that_doubles_back_is_not_cut_across_its_loop() -> None:
    """A leader that walked 4 m out and came back: the relay at the start is near the
    returning end too, but the search looks only a few points ahead."""
    out = [(0.5 * k, 0.0) for k in range(9)]
    back = [(4.0 - 0.5 * k, 0.3) for k in range(1, 8)]
    trail = pts(*out, *back)
    kept = prune(trail, (0.0, 0.2), reach_m=0.4, window=4)
    assert len(kept) >= len(trail) - 1
    assert remaining_m(kept, (0.0, 0.2)) > 7.0


def test_point_along_walks_the_polyline() -> None:
    trail = pts((0, 0), (2, 0), (2, 2))
    assert point_along(trail, (0, 0), 1.0) == (1.0, 0.0)
    x, y = point_along(trail, (0, 0), 3.0)
    assert math.isclose(x, 2.0) and math.isclose(y, 1.0)
    assert point_along(trail, (0, 0), 10.0) == (2, 2)


# --- pursuit --------------------------------------------------------------------------------


def ring(**by_index: int | None) -> tuple[SonarReading, ...]:
    ranges: list[int | None] = [None] * 16
    for k, v in by_index.items():
        ranges[int(k.lstrip("s"))] = v
    return front_readings(ranges)


def test_lookahead_shrinks_in_tight_places() -> None:
    assert lookahead_m(ring(), PP) == PP.lookahead_max_m
    assert lookahead_m(ring(s3=900), PP) == 0.9
    assert lookahead_m(ring(s0=200), PP) == PP.lookahead_min_m


def test_pursuit_steers_onto_the_trail_round_a_corner() -> None:
    trail = pts((0, 0), (2, 0), (2, 3))
    p = pursue(trail, (1.9, 0.0, 0.0), ring(), PP)
    assert p is not None and p.steer_deg is not None and not p.caught_up
    assert p.steer_deg > 45.0  # the way on is round the corner, to the left
    p = pursue(trail, (1.0, 0.0, 0.0), ring(s3=700, s4=700), PP)  # tight: 0.7 m ahead
    assert p is not None and p.steer_deg is not None and abs(p.steer_deg) < 10.0


def test_caught_up_with_the_head() -> None:
    trail = pts((0, 0), (1, 0))
    p = pursue(trail, (0.7, 0.1, 0.0), ring(), PP)
    assert p is not None and p.caught_up and p.steer_deg is None
    assert pursue((), (0.0, 0.0, 0.0), ring(), PP) is None


# --- the law's hook ------------------------------------------------------------------------


def healthy(**changes: object) -> ControlInputs:
    base = ControlInputs(
        mode=Mode.FOLLOW,
        sip_age_s=0.1,
        rssi_age_s=0.1,
        scan_servo_ok=True,
        bearing_deg=40.0,
        prev_bearing_deg=35.0,
        rssi_leader_dbm=-50.0,
        rssi_behind_dbm=-40.0,
        rear_age_s=1.0,
        front_sonar=ring(),
        leader_lost=False,
        t_s=10.0,
        odom=(0.0, 0.0, 0.0),
        rear_sonar=(),
    )
    return dataclasses.replace(base, **changes)  # type: ignore[arg-type]


DRIVING = ControlMemory(link_drive=True)


def test_bearing_pursuit_ignores_the_trail() -> None:
    plain = control_step(healthy(), ControlParams(), DRIVING)
    with_trail = control_step(
        healthy(trail_steer_deg=-60.0, trail_caught_up=True), ControlParams(), DRIVING
    )
    assert with_trail == plain


def test_trail_pursuit_steers_by_the_trail_not_the_bearing() -> None:
    out = control_step(healthy(trail_steer_deg=-30.0), TRAIL_P, DRIVING)
    assert out.reason == "driving" and out.left_mm_s > out.right_mm_s  # a right turn
    bearing = control_step(healthy(trail_steer_deg=-30.0), ControlParams(), DRIVING)
    assert bearing.right_mm_s > bearing.left_mm_s  # the bearing (40 deg) turns left
    # No trail: the scan bearing, as the paper's relays.
    assert control_step(healthy(), TRAIL_P, DRIVING) == control_step(
        healthy(), ControlParams(), DRIVING
    )


def test_caught_up_holds_and_the_stop_rule_still_comes_first() -> None:
    out = control_step(healthy(trail_caught_up=True), TRAIL_P, DRIVING)
    assert out.state is DriveState.STOPPED and out.reason == "trail_head"
    assert out.left_mm_s == 0.0 and out.right_mm_s == 0.0
    near = control_step(healthy(rssi_leader_dbm=-20.0, trail_steer_deg=5.0), TRAIL_P, DRIVING)
    assert near.reason == "leader_near" and near.left_mm_s == near.right_mm_s == 0.0
    weak = control_step(healthy(rssi_behind_dbm=-70.0, trail_steer_deg=5.0), TRAIL_P, DRIVING)
    assert weak.reason == "rear_weak"


@settings(max_examples=300, deadline=None)
@given(
    steer=st.floats(-180.0, 180.0),
    rssi=st.floats(-95.0, -25.0),
    ranges=st.lists(st.one_of(st.none(), st.integers(50, 5000)), min_size=8, max_size=8),
    v_max=st.floats(50.0, 1500.0),
    t=st.floats(0.0, 1000.0),
    pursuit=st.sampled_from(["trail", "bearing"]),
)
def test_law_within_v_max_and_never_toward_a_near_echo(
    steer: float, rssi: float, ranges: list[int | None], v_max: float, t: float, pursuit: str
) -> None:
    """Both pursuits. (Before this branch the escape's fixed turn rates could exceed a low
    v_max, e.g. 102 mm/s a wheel at v_max 50: the law now bounds the escape's command too.)"""
    full: list[int | None] = [*ranges, *([None] * 8)]
    front = front_readings(full)
    params = ControlParams(pursuit=pursuit, v_max_mm_s=v_max)
    out = control_step(
        healthy(front_sonar=front, trail_steer_deg=steer, rssi_leader_dbm=rssi, t_s=t),
        params,
        DRIVING,
    )
    assert abs(out.left_mm_s) <= v_max + 1e-9 and abs(out.right_mm_s) <= v_max + 1e-9
    if path_blocked(front, params.stop_distance_m):
        assert out.left_mm_s + out.right_mm_s <= 0.0  # no forward motion toward it
    assert len(SONAR_HEADINGS_DEG) >= 8


def test_keeper_holds_at_the_head_then_steers_by_the_bearing() -> None:
    from relayd.core.trail.estimate import EstimateParams, RangeModel
    from relayd.core.trail.keeper import TrailKeeper, TrailParams

    keeper = TrailKeeper(
        TrailParams(pursuit="trail", estimate=EstimateParams(range_model=RangeModel(-15, 2, 3)))
    )
    # A leader seen standing 2 m ahead (-15 - 20 log10 2 = -21 dBm), scan after scan.
    for k in range(10):
        keeper.scan(float(k), (0.0, 0.0, 0.0), 0.0, 2.0, -21.0, None)
    assert keeper.trail
    # The relay drove up to it: it holds there...
    got = keeper.steer(10.0, (1900.0, 0.0, 0.0), ring())
    assert got is not None and got.caught_up and keeper.view().source == "estimate"
    assert keeper.steer(15.0, (1900.0, 0.0, 0.0), ring()) is not None
    # ... but not for ever on a head that does not move: then the bearing steers.
    assert keeper.steer(17.0, (1900.0, 0.0, 0.0), ring()) is None
