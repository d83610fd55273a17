"""The escape leaving by the lane test ([avoidance] leave_by_lane): a corridor's wall beside
the way to the leader does not keep the robot avoiding; anything in that way does."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from relayd.core.avoid.ring import POSE_M, lane_clear, leader_clear
from relayd.core.avoid.state import AvoidParams
from relayd.core.control.params import ControlParams
from relayd.core.geometry import HALF_WIDTH_M
from relayd.sim.model import run_model
from relayd.sim.scenario import load_scenario

HEADINGS = (-90.0, -50.0, -30.0, -10.0, 10.0, 30.0, 50.0, 90.0)
LANE_HALF_M = HALF_WIDTH_M + AvoidParams().leave_lane_margin_m


#: A box in the robot frame: (centre x, centre y, half side), m.
Post = tuple[float, float, float]


def _cone_range(h: float, walls_y: tuple[float, float], post: Post | None) -> float:
    """The nearest echo across sonar h's 30 degree cone: two walls parallel to the heading
    at y = walls_y (robot frame, m) and optionally a square post."""
    x0, y0 = POSE_M[h]
    best = 5.0
    for k in range(-15, 16):
        a = math.radians(h + k)
        c, s = math.cos(a), math.sin(a)
        for wy in walls_y:
            if s * (wy - y0) > 0:
                best = min(best, (wy - y0) / s)
        if post is None:
            continue
        cx, cy, half = post
        for fx in (cx - half, cx + half):
            if abs(c) > 1e-9 and (d := (fx - x0) / c) > 0 and abs(y0 + d * s - cy) <= half:
                best = min(best, d)
        for fy in (cy - half, cy + half):
            if abs(s) > 1e-9 and (d := (fy - y0) / s) > 0 and abs(x0 + d * c - cx) <= half:
                best = min(best, d)
    return best


def _ring(
    y_offset_m: float, post: Post | None = None, half_width_m: float = 1.0
) -> dict[float, float]:
    """The front ring in a corridor `2 half_width_m` wide, the robot `y_offset_m` left of
    its middle."""
    walls = (half_width_m - y_offset_m, -half_width_m - y_offset_m)
    return {h: round(_cone_range(h, walls, post), 3) for h in HEADINGS}


@pytest.mark.parametrize("bearing", [-8.0, 0.0, 8.0])
def test_a_corridor_wall_beside_the_way_is_not_in_the_lane(bearing: float) -> None:
    # 0.35 m left of the middle of a 2 m corridor (where the lane change leaves a robot
    # that passed a person standing in the middle): the left wall is 0.65 m off.
    r = _ring(0.35)
    assert lane_clear(r, bearing, 1.2, LANE_HALF_M)
    if bearing > 0:
        # The old test: the +30 degree sonar sees that wall at under 1.2 m, so the way to
        # a leader a little to the left is never "clear", however long the corridor.
        assert not leader_clear(r, bearing, 1.2)


@pytest.mark.parametrize("y_box", [-0.3, 0.0, 0.3])
def test_a_box_in_the_way_closes_the_lane(y_box: float) -> None:
    r = _ring(0.0, post=(1.25, y_box, 0.25))
    assert not lane_clear(r, 0.0, 1.2, LANE_HALF_M)
    # Beyond clear_m it does not.
    far = _ring(0.0, post=(2.05, y_box, 0.25))
    assert lane_clear(far, 0.0, 1.2, LANE_HALF_M)


@settings(max_examples=150, deadline=None)
@given(
    bearing=st.floats(-30.0, 30.0),
    along_m=st.floats(0.45, 1.0),
    across_m=st.floats(-0.25, 0.25),
    side_m=st.floats(0.1, 0.4),
    corridor=st.booleans(),
)
def test_an_obstacle_in_the_lane_always_closes_it(
    bearing: float, along_m: float, across_m: float, side_m: float, corridor: bool
) -> None:
    # A square post in the lane toward the leader, open space or a 2 m corridor round it:
    # the ring is worked out from that geometry (each sonar's nearest echo across its
    # cone), not from the code's own sums, and the lane is never clear.
    b = math.radians(bearing)
    cx = along_m * math.cos(b) - across_m * math.sin(b)
    cy = along_m * math.sin(b) + across_m * math.cos(b)
    r = _ring(0.0, post=(cx, cy, side_m / 2.0), half_width_m=1.0 if corridor else 50.0)
    if min(r.values()) < 0.05:
        return  # the post is on a transducer: not a pose the robot can be in
    assert not lane_clear(r, bearing, 1.2, LANE_HALF_M), r


@pytest.mark.parametrize(("heading", "range_m"), [(30.0, 0.4), (-30.0, 0.45), (10.0, 0.9)])
def test_a_lone_echo_is_not_taken_for_a_wall(heading: float, range_m: float) -> None:
    # One side sonar hearing something near, nothing else: no boundary explains it, so
    # it is where its beam says, and it is in the lane.
    r = dict.fromkeys(HEADINGS, 5.0)
    r[heading] = range_m
    assert not lane_clear(r, 0.0, 1.2, LANE_HALF_M)


@pytest.mark.parametrize("seed", [1, 2])
def test_past_a_person_in_a_corridor_the_relay_leaves_the_lane_and_follows(seed: int) -> None:
    # The shipped person-in-corridor scenario (0.75 m each side of a person standing in a
    # 2 m corridor). By default the lane change never hands back: its far-side test wants
    # 1.2 m of open space, and the corridor's other wall is nearer, so the relay crawls on
    # "avoiding" and is 8 m down the corridor at no time within 120 s. With the lane test
    # it hands back once past, and keeps 0.1 m from everything.
    sc = load_scenario("person-in-corridor")
    lane = ControlParams(rear_link_required=False, avoid=AvoidParams(leave_by_lane=True))
    out = run_model(sc, seed=seed, past_m=8.0, seconds=120.0, params=lane)
    assert out.passed_at_s is not None and out.passed_at_s < 100.0, out
    assert out.collisions == 0 and out.min_clearance_m >= 0.1, out


def test_leave_by_lane_reaches_the_escape_from_config_and_from_a_scenario() -> None:
    from relayd.config.model import Settings
    from relayd.config.params import control_params
    from relayd.sim.relay import relay_settings
    from relayd.sim.scenario import ScenarioError, parse_scenario

    doc = relay_settings(
        robot_port="/dev/null",
        servo_port="/dev/null",
        procfs_path="/proc/net/wireless",
        rear_url="http://rear",
        front_url="http://front",
        control={},
        scan={},
        avoidance={"leave_by_lane": True, "leave_lane_margin_m": 0.15},
    )
    avoid = control_params(Settings.model_validate(doc)).avoid
    assert avoid.leave_by_lane and avoid.leave_lane_margin_m == 0.15
    assert not control_params(Settings()).avoid.leave_by_lane
    base = {
        "name": "x",
        "environment": "indoor",
        "command_center": {"x": -1.0, "y": 0.0},
        "leader": {"waypoints": [{"x": 5.0, "y": 0.0}]},
        "relay": [{"name": "r", "x": 0.0, "y": 0.0}],
    }
    assert parse_scenario({**base, "avoidance": {"leave_by_lane": True}}).avoidance == {
        "leave_by_lane": True
    }
    with pytest.raises(ScenarioError, match=r"avoidance\.leave_by_lan"):
        parse_scenario({**base, "avoidance": {"leave_by_lan": True}})
