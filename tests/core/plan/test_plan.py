"""The sonar map, A* on it, the navigator's detours and the law along them."""

from __future__ import annotations

import itertools
import math

from hypothesis import given, settings
from hypothesis import strategies as st

from relayd.core.avoid.ring import path_blocked
from relayd.core.control.law import ControlInputs, ControlMemory, ControlParams, control_step
from relayd.core.geometry import SONAR_HEADINGS_DEG, SONAR_POSES
from relayd.core.plan.astar import PlanParams, plan
from relayd.core.plan.grid import GridParams, SonarGrid
from relayd.core.plan.navigator import Navigator, NavParams
from relayd.core.scan.estimator import front_readings
from relayd.core.vocab import DriveState, Mode

PP = PlanParams()


def wall(grid: SonarGrid, a: tuple[float, float], b: tuple[float, float]) -> None:
    """A wall straight onto the map, occupied cell by cell (the planner's tests need a
    known map, not the sonar's way of learning one)."""
    n = int(math.dist(a, b) / (grid.p.cell_m / 2)) + 1
    for i in range(n + 1):
        f = i / n
        grid.set_occupied(grid.cell(a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])), grid.now_s)


def min_clearance(grid: SonarGrid, path: tuple[tuple[float, float], ...]) -> float:
    """The least distance from the path's segments (sampled) to an occupied cell's centre."""
    occ = [grid.centre(c) for c in grid.occupied_cells()]
    best = math.inf
    for (ax, ay), (bx, by) in itertools.pairwise(path):
        n = max(1, int(math.dist((ax, ay), (bx, by)) / 0.02))
        for i in range(n + 1):
            f = i / n
            x, y = ax + f * (bx - ax), ay + f * (by - ay)
            best = min(best, *(math.dist((x, y), o) for o in occ))
    return best


# --- the map ---------------------------------------------------------------------------


def ring(front_m: float | None, others_m: float | None = None) -> list[tuple[int, int]]:
    """A SIP's 16 readings (index, mm): sonars 3 and 4 (+-10 deg) at front_m, the rest at
    others_m (None: no echo)."""
    out: list[tuple[int, int]] = []
    for i in range(16):
        r = front_m if i in (3, 4) else others_m
        out.append((i, 5000 if r is None else int(r * 1000)))
    return out


def test_an_echo_ahead_maps_the_wall_and_the_beam_clears_the_way_to_it() -> None:
    grid = SonarGrid()
    for k in range(3):
        grid.update(0.4 * k, (0.0, 0.0, 0.0), ring(2.0))
        grid.update(0.4 * k + 0.2, (1.0, 0.0, 0.0), ring(2.0 - 0.001))  # moved 1 mm
    # Sonar 3 sits 0.245 m ahead of the centre: its echo lies near x = 2.245.
    assert grid.occupied_near(2.25, 0.35, 0.15)
    assert grid.occupied_near(2.25, -0.35, 0.15)
    assert not grid.occupied_near(1.2, 0.0, 0.25)  # the beam passed here: free
    assert grid.logodds[grid.cell(1.2, 0.0)] < 0.0


def test_one_far_reading_is_not_yet_an_obstacle_two_are_and_each_is_laid_once() -> None:
    grid = SonarGrid()
    grid.update(0.0, (0.0, 0.0, 0.0), ring(1.5))
    assert not any(True for _ in grid.occupied_cells())  # one reading spread over its arc
    before = dict(grid.logodds)
    grid.update(0.1, (0.0, 0.0, 0.0), [])  # a SIP that read no sonar: nothing to lay
    assert grid.logodds == before
    grid.update(0.1, (0.0, 0.0, 0.0), ring(1.5))  # held: within every_s of the last
    assert grid.logodds == before
    grid.update(0.2, (0.0, 0.0, 0.0), [])  # laid now, once, at this pose
    assert any(True for _ in grid.occupied_cells())
    after = dict(grid.logodds)
    grid.update(0.4, (0.0, 0.0, 0.0), [])  # nothing new: the old readings are not laid again
    assert grid.logodds == after


def test_a_near_reading_counts_at_once_a_far_one_is_spread_thin() -> None:
    # At 0.4 m the arc is 0.17 m wide: its points fall in a cell or two, each summing
    # their shares; at 2.5 m it is 1 m wide and each cell gets a fifth.
    near, far = SonarGrid(), SonarGrid()
    near.update(0.0, (0.0, 0.0, 0.0), [(3, 400)])
    far.update(0.0, (0.0, 0.0, 0.0), [(3, 2500)])
    assert max(near.logodds.values()) >= GridParams().occupied
    assert max(far.logodds.values()) < GridParams().occupied


def test_no_echo_clears_only_weakly_so_a_wall_seen_once_survives_a_grazing_miss() -> None:
    grid = SonarGrid()
    wall(grid, (2.0, -1.0), (2.0, 1.0))
    for k in range(5):
        grid.update(0.2 * k, (float(k), 0.0, 0.0), ring(None))  # poses in mm: hardly moving
    assert grid.occupied_near(2.0, 0.0, 0.1)


def test_an_echo_not_seen_again_for_ttl_s_no_longer_blocks() -> None:
    grid = SonarGrid()
    wall(grid, (2.0, -1.0), (2.0, 1.0))  # seen at t = 0
    grid.update(GridParams().ttl_s - 1.0, (0.0, 0.0, 180.0), ring(None))
    assert grid.occupied_near(2.0, 0.0, 0.1)
    grid.update(GridParams().ttl_s + 1.0, (0.0, 0.0, 180.0), ring(None))
    assert not grid.occupied_near(2.0, 0.0, 0.1)


def test_forget_keeps_only_the_cells_round_the_robot() -> None:
    grid = SonarGrid()
    wall(grid, (0.0, 0.0), (1.0, 0.0))
    wall(grid, (50.0, 0.0), (51.0, 0.0))
    grid.forget(0.0, 0.0, keep_m=10.0)
    assert grid.occupied_near(0.5, 0.0, 0.1)
    assert not grid.occupied_near(50.5, 0.0, 0.2)


# --- A* --------------------------------------------------------------------------------


def test_a_straight_way_is_one_segment() -> None:
    path = plan(SonarGrid(), (0.0, 0.0), (5.0, 0.0), PP)
    assert path is not None and len(path) == 2
    assert math.dist(path[-1], (5.0, 0.0)) < 0.1


def test_a_wall_with_a_door_the_path_goes_through_the_door_clear_of_its_jambs() -> None:
    grid = SonarGrid()
    # A wall at x = 3 from y = -4 to 4, its door 0.9 m wide at y 1.0 .. 1.9.
    wall(grid, (3.0, -4.0), (3.0, 1.0))
    wall(grid, (3.0, 1.9), (3.0, 4.0))
    path = plan(grid, (0.0, 0.0), (6.0, 0.0), PP)
    assert path is not None and math.dist(path[-1], (6.0, 0.0)) < 0.15
    # It crosses x = 3 inside the door.
    for (ax, ay), (bx, by) in itertools.pairwise(path):
        if ax < 3.0 <= bx:
            y = ay + (3.0 - ax) / (bx - ax) * (by - ay)
            assert 1.0 + 0.25 < y < 1.9 - 0.25, y
    assert min_clearance(grid, path) >= PP.inflate_m - 0.08


def test_a_u_trap_is_left_by_its_mouth_and_rounded() -> None:
    grid = SonarGrid()
    # The U opens toward the robot (x < 2): its back at x = 3.5, its arms at y = +-1.25.
    wall(grid, (2.0, 1.25), (3.5, 1.25))
    wall(grid, (3.5, 1.25), (3.5, -1.25))
    wall(grid, (3.5, -1.25), (2.0, -1.25))
    path = plan(grid, (3.0, 0.0), (8.0, 0.0), PP)
    assert path is not None and math.dist(path[-1], (8.0, 0.0)) < 0.15
    assert min(x for x, _ in path) < 2.0 - PP.inflate_m + 0.1  # out through the mouth
    assert max(abs(y) for _, y in path) > 1.25 + PP.inflate_m - 0.1  # round an arm
    assert min_clearance(grid, path) >= PP.inflate_m - 0.08


def test_a_goal_inside_a_closed_room_gives_the_path_to_its_nearest_reachable_point() -> None:
    grid = SonarGrid()
    for a, b in (((3, -1), (5, -1)), ((5, -1), (5, 1)), ((5, 1), (3, 1)), ((3, 1), (3, -1))):
        wall(grid, (float(a[0]), float(a[1])), (float(b[0]), float(b[1])))
    path = plan(grid, (0.0, 0.0), (4.0, 0.0), PP)
    assert path is not None
    end = path[-1]
    assert 3.0 - PP.inflate_m - 0.2 < end[0] < 3.0 - PP.inflate_m + 0.05
    assert abs(end[1]) < 0.2


def test_no_way_nearer_gives_none() -> None:
    grid = SonarGrid()
    # Boxed in on every side closer than the inflation: no cell to move to.
    for a, b in (((0.3, -0.3), (0.3, 0.3)), ((-0.3, 0.3), (0.3, 0.3))):
        wall(grid, a, b)
    for a, b in (((-0.3, -0.3), (0.3, -0.3)), ((-0.3, -0.3), (-0.3, 0.3))):
        wall(grid, a, b)
    assert plan(grid, (0.0, 0.0), (3.0, 0.0), PP) is None


# --- the navigator ---------------------------------------------------------------------


def test_the_navigator_stays_out_of_the_way_while_the_straight_way_is_clear() -> None:
    nav = Navigator()
    assert nav.steer(0.0, (0.0, 0.0, 0.0), (6.0, 0.0)) is None
    wall(nav.grid, (5.5, -1.0), (5.5, 1.0))  # just before the goal: the leader's own echo
    assert nav.steer(0.1, (0.0, 0.0, 0.0), (6.0, 0.0)) is None
    assert nav.plans == 0


def test_a_wall_in_the_way_gives_a_detour_round_it_then_straight_on_after_the_hold() -> None:
    nav = Navigator()
    wall(nav.grid, (2.0, -3.0), (2.0, 0.8))  # the way round is to the left (y > 0.8)
    got = nav.steer(0.0, (0.0, 0.0, 0.0), (6.0, 0.0))
    assert got is not None and got.steer_deg > 20.0
    assert nav.plans == 1
    nav.steer(nav.p.replan_s / 2, (0.0, 0.0, 0.0), (6.0, 0.0))
    assert nav.plans == 1  # not yet due
    nav.steer(nav.p.replan_s, (0.0, 0.0, 0.0), (6.0, 0.0))
    assert nav.plans == 2  # replanned each replan_s
    # Beyond the wall with the way clear: the detour holds hold_s, then lets go.
    assert nav.steer(2.0, (3000.0, 1500.0, 0.0), (6.0, 0.0)) is not None
    assert nav.steer(2.0 + nav.p.hold_s + 0.1, (3000.0, 1500.0, 0.0), (6.0, 0.0)) is None
    assert nav.path is None


def test_the_navigator_off_never_steers_and_maps_nothing() -> None:
    nav = Navigator(NavParams(enabled=False))
    nav.sonar(0.0, (0.0, 0.0, 0.0), ring(1.0, 1.0))
    assert nav.grid.logodds == {}
    wall(nav.grid, (2.0, -3.0), (2.0, 3.0))
    assert nav.steer(0.0, (0.0, 0.0, 0.0), (6.0, 0.0)) is None


# --- the law along a detour -----------------------------------------------------------


def follow_inputs(sonar_mm: list[int | None], detour_deg: float | None) -> ControlInputs:
    return ControlInputs(
        mode=Mode.FOLLOW,
        sip_age_s=0.0,
        rssi_age_s=0.0,
        scan_servo_ok=True,
        bearing_deg=0.0,
        prev_bearing_deg=None,
        rssi_leader_dbm=-60.0,
        rssi_behind_dbm=-40.0,
        rear_age_s=0.0,
        front_sonar=front_readings(sonar_mm),
        leader_lost=False,
        t_s=10.0,
        odom=(0.0, 0.0, 0.0),
        detour_steer_deg=detour_deg,
    )


def test_a_detour_drives_along_its_path_and_says_so() -> None:
    out = control_step(follow_inputs([5000] * 16, 30.0), ControlParams(), ControlMemory())
    assert out.state is DriveState.DRIVING and out.reason == "detour"
    assert out.right_mm_s > out.left_mm_s  # turning left, onto the path


def test_between_jambs_a_detour_crawls_on_instead_of_escaping() -> None:
    # A door's jambs beside the robot (inside the stop distance, outside its path).
    sonar = [5000] * 16
    sonar[1] = sonar[6] = 260
    sonar[0] = sonar[7] = 150
    p = ControlParams()
    out = control_step(follow_inputs(sonar, 0.0), p, ControlMemory())
    assert out.reason == "detour"
    assert 0 < (out.left_mm_s + out.right_mm_s) / 2 <= p.avoid.door_speed_mm_s
    # Without a detour the same jambs start the escape.
    assert control_step(follow_inputs(sonar, None), p, ControlMemory()).reason != "detour"


readings = st.one_of(st.none(), st.integers(min_value=0, max_value=5000))


@settings(max_examples=300, deadline=None)
@given(
    sonar=st.lists(readings, min_size=16, max_size=16),
    detour=st.floats(min_value=-180.0, max_value=180.0),
    v_max=st.floats(min_value=50.0, max_value=1000.0),
)
def test_a_detour_never_exceeds_v_max_nor_drives_into_a_near_echo(
    sonar: list[int | None], detour: float, v_max: float
) -> None:
    p = ControlParams(v_max_mm_s=v_max)
    out = control_step(follow_inputs(sonar, detour), p, ControlMemory())
    assert max(abs(out.left_mm_s), abs(out.right_mm_s)) <= v_max + 1e-6
    forward = (out.left_mm_s + out.right_mm_s) / 2.0
    if path_blocked(front_readings(sonar), p.stop_distance_m):
        assert forward <= 1e-9


def test_sonar_poses_and_headings_agree() -> None:
    # The map lays echoes from SONAR_POSES; the law reads SONAR_HEADINGS_DEG: one ring.
    assert tuple(float(p.heading_deg) for p in SONAR_POSES) == SONAR_HEADINGS_DEG
    assert GridParams().cell_m <= 0.1 + 1e-9  # a 0.8 m door keeps free cells between jambs


def test_a_detour_tries_again_after_the_escape_stood_blocked_for_a_while() -> None:
    from dataclasses import replace

    from relayd.core.avoid.state import AvoidMode, AvoidState
    from relayd.core.control.steer import DETOUR_RETRY_S

    blocked = ControlMemory(avoid=AvoidState(mode=AvoidMode.BLOCKED, mode_t=10.0 - 1.0))
    p = ControlParams()
    # The path turns 60 deg off the nose: the escape's hold waits for a bearing within 30.
    out = control_step(follow_inputs([5000] * 16, 60.0), p, blocked)
    assert out.reason == "blocked" and out.left_mm_s == out.right_mm_s == 0.0
    # Blocked for DETOUR_RETRY_S: the detour drives (turns onto) its path again.
    waited = replace(blocked, avoid=replace(blocked.avoid, mode_t=10.0 - DETOUR_RETRY_S))
    out = control_step(follow_inputs([5000] * 16, 60.0), p, waited)
    assert out.reason == "detour" and out.right_mm_s > out.left_mm_s
    assert out.memory.avoid.mode is AvoidMode.FOLLOW
