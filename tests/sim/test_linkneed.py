"""How many relays a world needs: hand-checked budgets on a straight corridor and a wall."""

from __future__ import annotations

import math

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from relayd.sim.linkneed import MORE, NEED_HOP_DBM, along, relays_needed

Point = tuple[float, float]


def free_space(a: Point, b: Point) -> float:
    """-15 dBm at 1 m, exponent 3: a hop holds -60 dBm up to 10^1.5 = 31.6 m."""
    return -15.0 - 30.0 * math.log10(max(0.5, math.dist(a, b)))


def test_the_threshold_is_the_relays_own_rear_limit() -> None:
    assert NEED_HOP_DBM == -60.0


@pytest.mark.parametrize(
    ("length_m", "relays"),
    [(30.0, 0), (33.0, 1), (62.0, 1), (65.0, 2), (92.0, 2), (96.0, MORE)],
)
def test_a_straight_corridor_needs_a_relay_every_31_6_m(length_m: float, relays: int) -> None:
    """Relays stand on whole metres of the route, so k of them hold up to 31(k + 1) m."""
    route = [(0.0, 0.0), (length_m, 0.0)]
    assert relays_needed(free_space, (0.0, 0.0), route) == relays


def test_a_wall_on_the_way_costs_a_relay() -> None:
    """20 m of corridor alone needs none; a 15 dB wall at x = 10 m between the command
    center and the goal does, and one relay past it holds both hops (the wall is charged
    only to the hop that crosses it)."""

    def walled(a: Point, b: Point) -> float:
        crosses = (a[0] - 10.0) * (b[0] - 10.0) < 0
        return free_space(a, b) - (15.0 if crosses else 0.0)

    route = [(0.0, 0.0), (20.0, 0.0)]
    assert relays_needed(free_space, (0.0, 0.0), route) == 0
    assert relays_needed(walled, (0.0, 0.0), route) == 1


@settings(max_examples=60, deadline=None)
@example(49.5, -52.0)
@given(st.floats(min_value=5.0, max_value=120.0), st.floats(min_value=-75.0, max_value=-50.0))
def test_the_count_grows_with_the_route_and_the_threshold(length_m: float, hop_dbm: float) -> None:
    """On a straight corridor k relays hold k + 1 hops of at most r = 10^((-15 - t) / 30) m
    each, so the count is the least k with (k + 1) r >= L. Relays stand on the route's
    points, `along`'s spacing s apart (1-2 m): never fewer than that, and each of the two
    may stand up to s short of where it would hold, so as many as for L + 2 s (L = 49.5 m
    at -52 dBm: s = 1.01 m, three relays where the continuous count is two)."""
    r = 10 ** ((-15.0 - hop_dbm) / 30.0)
    route = [(0.0, 0.0), (length_m, 0.0)]
    got = relays_needed(free_space, (0.0, 0.0), route, hop_dbm)
    spacing = length_m / max(1, int(length_m))
    lo = max(0, math.ceil(length_m / r) - 1)
    hi = max(0, math.ceil((length_m + 2.0 * spacing) / r) - 1)
    assert min(lo, MORE) <= got <= min(hi, MORE)


def test_an_empty_route_is_an_error() -> None:
    with pytest.raises(ValueError, match="no points"):
        relays_needed(free_space, (0.0, 0.0), [])


def test_the_convoy_keeps_its_order() -> None:
    """The command center hears only the stretch 40-50 m along the route and the goal only
    the first 10 m; any two route points hear each other. Two relays would hold every hop
    only standing out of order (relay 2, by the command center, ahead of relay 1), which
    a convoy cannot do: more than two are needed."""
    cc, goal = (0.0, -100.0), (60.0, 0.0)

    def power(a: Point, b: Point) -> float:
        if cc in (a, b):
            other = b if a == cc else a
            return -50.0 if 40.0 <= other[0] <= 50.0 and other[1] == 0.0 else -90.0
        if goal in (a, b):
            other = b if a == goal else a
            return -50.0 if other[0] <= 10.0 else -90.0
        return -50.0

    assert relays_needed(power, cc, [(0.0, 0.0), goal]) == MORE


def test_along_keeps_the_ends_and_steps_a_metre() -> None:
    pts = along([(0.0, 0.0), (3.0, 0.0), (3.0, 2.0)])
    assert pts[0] == (0.0, 0.0) and pts[-1] == (3.0, 2.0)
    assert (3.0, 0.0) in pts and len(pts) == 6


def test_the_bench_counts_two_relays_for_a_generated_world() -> None:
    """bench/relayneed.py counts with the generator's own rule: a generated world reads
    "two" at the rear limit (and no fewer at a stricter threshold)."""
    from bench.relayneed import needs

    at_limit, stricter = needs("office", 0, [NEED_HOP_DBM, NEED_HOP_DBM + 5.0])
    assert at_limit == 2 and stricter >= 2
