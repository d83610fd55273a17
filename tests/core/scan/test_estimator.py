"""Unit and property tests for relayd.core.scan.estimator (docs/CONTROL.md sections 2-3, 6)."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from relayd.core.geometry import SONAR_HEADINGS_DEG, wrap_deg
from relayd.core.scan.estimator import (
    FRONT_RING,
    FRONT_SONARS,
    LOST_AFTER_SCANS,
    EstimatorParams,
    ScanSample,
    SonarReading,
    apply_prssi,
    avoidance_bearing,
    classify_situation,
    estimate_scan,
    front_readings,
    plan_scan,
    prssi_db,
    to_robot_frame,
    update_lost_count,
    wca_bearing,
)

LIMITS = (-90.0, 90.0)
#: Yagi model for the tests: G_r cos^2(off-axis) dB inside the +-90 degree beam (docs/SIMULATOR.md,
#: the paper's eq. for P_r), a back-lobe floor outside. 15 dB gives a 3 dB beamwidth of
#: about +-26 degrees, close to a small 2.4 GHz Yagi.
YAGI_GAIN_DB = 15.0
YAGI_FLOOR_DB = -10.0
P_DBM = -60.0

angles_st = st.floats(-180.0, 180.0, allow_nan=False)
rssi_st = st.floats(-120.0, 0.0, allow_nan=False)


def yagi_rssi(servo_world_deg: float, leader_world_deg: float) -> float:
    off = wrap_deg(servo_world_deg - leader_world_deg)
    if abs(off) < 90.0:
        return P_DBM + YAGI_GAIN_DB * math.cos(math.radians(off)) ** 2
    return P_DBM + YAGI_FLOOR_DB


def sonar_mm(**by_index: int | None) -> list[int | None]:
    ranges: list[int | None] = [None] * 16
    for key, value in by_index.items():
        ranges[int(key.lstrip("s"))] = value
    return ranges


def static_scan(leader_deg: float, angles: tuple[float, ...]) -> list[ScanSample]:
    return [ScanSample(a, yagi_rssi(a, leader_deg), 0.0) for a in angles]


# --- constants --------------------------------------------------------------------------


def test_sonar_table_matches_protocol_doc() -> None:
    # docs/PROTOCOLS.md 1.11, index order, ccw +.
    assert SONAR_HEADINGS_DEG == (
        90, 50, 30, 10, -10, -30, -50, -90, -90, -130, -150, -170, 170, 150, 130, 90,
    )  # fmt: skip
    assert FRONT_SONARS == (1, 2, 3, 4, 5, 6)
    assert [SONAR_HEADINGS_DEG[i] for i in FRONT_SONARS] == [50, 30, 10, -10, -30, -50]
    assert tuple(range(8)) == FRONT_RING
    assert LOST_AFTER_SCANS == 3


# --- plan_scan --------------------------------------------------------------------------


def test_plan_scan_default_full_sweep() -> None:
    angles = plan_scan(0.0, 180.0, 25, LIMITS, True)
    assert len(angles) == 25
    assert angles[0] == -90.0 and angles[-1] == 90.0
    assert angles[1] == pytest.approx(-82.5)
    assert plan_scan(0.0, 180.0, 25, LIMITS, False) == tuple(reversed(angles))


def test_plan_scan_shifts_window_inside_limits_keeping_width() -> None:
    assert plan_scan(60.0, 90.0, 5, LIMITS, True) == pytest.approx((0.0, 22.5, 45.0, 67.5, 90.0))
    assert plan_scan(-70.0, 60.0, 4, LIMITS, True) == pytest.approx((-90.0, -70.0, -50.0, -30.0))
    # A window that fits is left alone.
    assert plan_scan(10.0, 40.0, 3, LIMITS, False) == pytest.approx((30.0, 10.0, -10.0))


def test_plan_scan_clips_a_window_wider_than_the_servo() -> None:
    assert plan_scan(45.0, 270.0, 3, LIMITS, True) == pytest.approx((-90.0, 0.0, 90.0))


def test_plan_scan_single_sample_is_the_centre() -> None:
    assert plan_scan(12.5, 180.0, 1, LIMITS, True) == (12.5,)
    assert plan_scan(120.0, 180.0, 1, LIMITS, False) == (90.0,)


@pytest.mark.parametrize(
    ("center", "width", "samples", "limits"),
    [
        (0.0, 180.0, 0, LIMITS),
        (0.0, -1.0, 5, LIMITS),
        (math.nan, 180.0, 5, LIMITS),
        (0.0, math.inf, 5, LIMITS),
        (0.0, 180.0, 5, (90.0, -90.0)),
    ],
)
def test_plan_scan_rejects_bad_input(
    center: float, width: float, samples: int, limits: tuple[float, float]
) -> None:
    with pytest.raises(ValueError):
        plan_scan(center, width, samples, limits, True)


@given(
    center=st.floats(-400.0, 400.0, allow_nan=False),
    width=st.floats(0.0, 400.0, allow_nan=False),
    samples=st.integers(2, 60),
    lo=st.floats(-180.0, 0.0, allow_nan=False),
    span=st.floats(1.0, 360.0, allow_nan=False),
    ascending=st.booleans(),
)
def test_plan_scan_properties(
    center: float, width: float, samples: int, lo: float, span: float, ascending: bool
) -> None:
    hi = lo + span
    angles = plan_scan(center, width, samples, (lo, hi), ascending)
    assert len(angles) == samples
    assert all(lo <= a <= hi for a in angles)
    ordered = sorted(angles)
    assert list(angles) == (ordered if ascending else ordered[::-1])
    # Evenly spaced over the requested width, or over the whole servo range if wider.
    expected_width = min(width, span)
    assert ordered[-1] - ordered[0] == pytest.approx(expected_width, abs=1e-9)
    steps = [b - a for a, b in itertools.pairwise(ordered)]
    assert max(steps) - min(steps) == pytest.approx(0.0, abs=1e-9)
    # The window contains the (clamped) centre unless it had to be shifted off it.
    if lo + width / 2 <= center <= hi - width / 2:
        assert (ordered[0] + ordered[-1]) / 2 == pytest.approx(center, abs=1e-9)


# --- WCA --------------------------------------------------------------------------------


def test_wca_symmetric_scan_is_zero() -> None:
    angles = plan_scan(0.0, 180.0, 25, LIMITS, True)
    rssi = [yagi_rssi(a, 0.0) for a in angles]
    assert wca_bearing(angles, rssi, 10.0) == pytest.approx(0.0, abs=1e-9)


def test_wca_worked_numbers() -> None:
    # w = 10^0 = 1 at -10 deg, 10^-1 = 0.1 at +10 deg -> (-10 + 1) / 1.1.
    assert wca_bearing([-10.0, 10.0], [-50.0, -60.0], 10.0) == pytest.approx(-9.0 / 1.1)
    assert wca_bearing([33.0], [-70.0], 10.0) == 33.0
    # gamma = 1 sharpens: 10 dB difference is a factor 1e10.
    assert wca_bearing([-10.0, 10.0], [-50.0, -60.0], 1.0) == pytest.approx(-10.0, abs=1e-7)


@pytest.mark.parametrize(
    ("angles", "rssi", "gamma"),
    [
        ([], [], 10.0),
        ([0.0, 1.0], [-50.0], 10.0),
        ([0.0], [-50.0], 0.0),
        ([0.0], [-50.0], -10.0),
        ([0.0], [math.nan], 10.0),
        ([math.inf], [-50.0], 10.0),
    ],
)
def test_wca_rejects_bad_input(angles: list[float], rssi: list[float], gamma: float) -> None:
    with pytest.raises(ValueError):
        wca_bearing(angles, rssi, gamma)


@given(
    data=st.lists(st.tuples(angles_st, rssi_st), min_size=1, max_size=40),
    shift=st.floats(-200.0, 200.0, allow_nan=False),
    gamma=st.floats(0.5, 40.0),
)
def test_wca_invariant_to_constant_offset(
    data: list[tuple[float, float]], shift: float, gamma: float
) -> None:
    angles = [a for a, _ in data]
    rssi = [r for _, r in data]
    shifted = [r + shift for r in rssi]
    assert wca_bearing(angles, shifted, gamma) == pytest.approx(
        wca_bearing(angles, rssi, gamma), abs=1e-6
    )


@given(
    data=st.lists(
        st.tuples(angles_st, st.floats(-1e308, 1e308, allow_nan=False, allow_infinity=False)),
        min_size=1,
        max_size=40,
    ),
    gamma=st.floats(1e-3, 1e3),
)
def test_wca_stays_within_sampled_angles_and_never_overflows(
    data: list[tuple[float, float]], gamma: float
) -> None:
    angles = [a for a, _ in data]
    rssi = [r for _, r in data]
    bearing = wca_bearing(angles, rssi, gamma)
    assert math.isfinite(bearing)
    assert min(angles) <= bearing <= max(angles)


def test_wca_extreme_values() -> None:
    assert wca_bearing([-30.0, 30.0], [1e308, -1e308], 10.0) == -30.0
    assert wca_bearing([-30.0, 30.0], [-1e308, -1e308], 10.0) == pytest.approx(0.0)
    assert wca_bearing([-30.0, 30.0], [5000.0, 4999.0], 1e-3) == -30.0


@settings(deadline=None)
@given(
    leader=st.floats(-50.0, 50.0, allow_nan=False),
    start=st.floats(-90.0, 90.0, allow_nan=False),
)
def test_wca_converges_on_a_static_leader_in_the_servo_field(leader: float, start: float) -> None:
    """Robot standing still: within 5 degrees in at most 5 scans.

    A weighted mean of angles inside the servo's +-90 can never reach +-90, so a robot
    that does not turn sees a bias near the limits (about 6 degrees at 60 with this
    pattern); the closed-loop test below covers the whole -90..+90.
    """
    center, ascending, errors = start, True, []
    for _ in range(5):
        angles = plan_scan(center, 180.0, 25, LIMITS, ascending)
        ascending = not ascending
        estimate = estimate_scan(static_scan(leader, angles), 0.0, (), EstimatorParams())
        center = estimate.bearing_deg
        errors.append(abs(center - leader))
    assert min(errors) < 5.0
    assert errors[-1] < 5.0


def closed_loop_error(leader_deg: float, start_deg: float, scans: int = 5) -> float:
    """A robot turning in place toward its bearing estimate while it scans a static leader.

    Servo: 25 steps per scan, 0.1 s per step. The robot's yaw rate comes from the
    wheel law (v = 0) through the P3-AT's DiffConvFactor (0.0034, docs/PROTOCOLS.md 1.7),
    using the newest bearing corrected into the current frame by odometry, as the
    control task does. Returns |bearing - true leader angle| after the last scan.
    """
    from relayd.core.control.law import wheel_law

    heading, center, ascending = 0.0, start_deg, True
    bearing: float | None = None
    prev: float | None = None
    heading_at_bearing = 0.0
    dt, substeps = 0.1, 5
    for _ in range(scans):
        angles = plan_scan(center, 180.0, 25, LIMITS, ascending)
        ascending = not ascending
        samples = []
        for angle in angles:
            for _ in range(substeps):
                if bearing is not None:
                    now_bearing = bearing - (heading - heading_at_bearing)
                    now_prev = None if prev is None else prev - (heading - heading_at_bearing)
                    left, right = wheel_law(0.0, now_bearing, now_prev, 1.0, 0.3, 400.0)
                    yaw_deg_s = math.degrees((right - left) / 2.0 * 0.0034)
                    heading += yaw_deg_s * dt / substeps
            samples.append(ScanSample(angle, yagi_rssi(angle + heading, leader_deg), heading))
        estimate = estimate_scan(samples, heading, (), EstimatorParams())
        prev = None if bearing is None else bearing - (heading - heading_at_bearing)
        bearing, heading_at_bearing = estimate.bearing_deg, heading
        center = estimate.bearing_deg
    assert bearing is not None
    return abs(wrap_deg(bearing - (leader_deg - heading)))


@settings(deadline=None, max_examples=40)
@given(
    leader=st.floats(-90.0, 90.0, allow_nan=False),
    start=st.floats(-90.0, 90.0, allow_nan=False),
)
def test_bearing_converges_from_any_start_when_the_robot_turns(leader: float, start: float) -> None:
    assert closed_loop_error(leader, start) < 5.0


@pytest.mark.parametrize("leader", [-90.0, -75.0, 0.0, 80.0, 90.0])
def test_closed_loop_worked_cases(leader: float) -> None:
    assert closed_loop_error(leader, 0.0) < 5.0


# --- frames -----------------------------------------------------------------------------


def test_to_robot_frame_corrects_for_turning_during_the_scan() -> None:
    samples = [
        ScanSample(0.0, -50.0, 0.0),  # pointed straight ahead before the robot turned left 20
        ScanSample(10.0, -50.0, 10.0),
        ScanSample(-20.0, -50.0, 20.0),
    ]
    assert to_robot_frame(samples, 20.0) == pytest.approx((-20.0, 0.0, -20.0))


def test_to_robot_frame_wraps() -> None:
    assert to_robot_frame([ScanSample(170.0, -50.0, 30.0)], 0.0) == pytest.approx((-160.0,))
    assert to_robot_frame([ScanSample(90.0, -50.0, 90.0)], 0.0) == (180.0,)
    assert to_robot_frame([ScanSample(-90.0, -50.0, -90.0)], 0.0) == (180.0,)
    assert to_robot_frame([ScanSample(0.0, -50.0, 350.0)], -10.0) == (0.0,)


@given(angle=st.floats(-1e6, 1e6, allow_nan=False))
def test_wrap_range(angle: float) -> None:
    wrapped = wrap_deg(angle)
    assert -180.0 < wrapped <= 180.0
    assert math.cos(math.radians(wrapped)) == pytest.approx(math.cos(math.radians(angle)), abs=1e-6)


# --- sonar ------------------------------------------------------------------------------


def test_front_readings_converts_and_keeps_the_front_ring() -> None:
    readings = front_readings(sonar_mm(s0=700, s3=1500, s7=5000, s8=200, s12=300))
    assert [r.heading_deg for r in readings] == [90, 50, 30, 10, -10, -30, -50, -90]
    assert readings[0] == SonarReading(90.0, 0.7, index=0)
    assert readings[3] == SonarReading(10.0, 1.5, index=3)
    assert [r.index for r in readings] == list(range(8))  # the mounting pose, for the guard
    assert readings[7].range_m is None  # 5000 mm: the sonar's maximum, no echo
    assert readings[1].range_m is None


@pytest.mark.parametrize("ranges", [[None] * 15, [None] * 17, sonar_mm(s2=-5)])
def test_front_readings_rejects_bad_input(ranges: list[int | None]) -> None:
    with pytest.raises(ValueError):
        front_readings(ranges)


def test_situations() -> None:
    def sit(**kw: int | None) -> int:
        return classify_situation(front_readings(sonar_mm(**kw)), 0.8, 3.0)

    assert sit() == 0
    assert sit(s3=500) == 1
    assert sit(s6=799) == 1
    assert sit(s3=800) == 2  # threshold_o itself is situation 2
    assert sit(s3=2999) == 2
    assert sit(s3=3000) == 0  # detect_range is exclusive
    assert sit(s0=1500) == 2  # side sonars count for PRSSI
    # A corridor wall alongside (side sonars 0 and 7) never makes the robot avoid.
    assert sit(s0=400, s7=400) == 0
    assert sit(s0=400, s4=1200) == 2
    assert sit(s3=500, s4=1200) == 1
    # Rear sonars never count, even when the caller passes all 16.
    all16 = [SonarReading(h, 0.5) for h in SONAR_HEADINGS_DEG[9:15]]
    assert classify_situation(all16, 0.8, 3.0) == 0


def test_avoidance_bearing_steers_away_from_the_near_side() -> None:
    left_box = front_readings(sonar_mm(s1=400, s2=500))
    right_box = front_readings(sonar_mm(s5=500, s6=400))
    # Nearly all the weight on the four open sonars: (10 - 10 - 30 - 50) / 4 = -20.
    assert avoidance_bearing(left_box, 1.0) == pytest.approx(-20.0, abs=0.01)
    assert avoidance_bearing(right_box, 1.0) == pytest.approx(20.0, abs=0.01)
    assert avoidance_bearing(front_readings(sonar_mm()), 1.0) == pytest.approx(0.0)
    # Sideways sonars do not steer.
    assert avoidance_bearing(front_readings(sonar_mm(s0=200)), 1.0) == pytest.approx(0.0)


def test_avoidance_bearing_worked_numbers() -> None:
    # Two sonars: +30 at 1 m, -30 at 2 m -> weights 10 and 100 -> (300 - 3000) / 110.
    readings = [SonarReading(30.0, 1.0), SonarReading(-30.0, 2.0)]
    assert avoidance_bearing(readings, 1.0) == pytest.approx(-2700.0 / 110.0)
    # No echo counts as the maximum range; beyond it is clamped.
    far = [SonarReading(30.0, None), SonarReading(-30.0, 9.0)]
    assert avoidance_bearing(far, 1.0) == pytest.approx(0.0)
    with pytest.raises(ValueError):
        avoidance_bearing([], 1.0)
    with pytest.raises(ValueError):
        avoidance_bearing(readings, 0.0)


ranges_st = st.one_of(st.none(), st.integers(0, 6000))


@given(ranges=st.lists(ranges_st, min_size=16, max_size=16))
def test_avoidance_is_mirror_symmetric_and_bounded(ranges: list[int | None]) -> None:
    mirrored = list(ranges)
    for a, b in zip(FRONT_RING, reversed(FRONT_RING), strict=True):
        mirrored[a] = ranges[b]
    bearing = avoidance_bearing(front_readings(ranges), 1.0)
    assert -50.0 <= bearing <= 50.0
    assert avoidance_bearing(front_readings(mirrored), 1.0) == pytest.approx(-bearing, abs=1e-9)


@given(near=st.integers(100, 790), far=st.integers(800, 5000), index=st.sampled_from(FRONT_SONARS))
def test_avoidance_prefers_the_farther_side(near: int, far: int, index: int) -> None:
    assume(SONAR_HEADINGS_DEG[index] != 0)
    ranges: list[int | None] = [far] * 16
    ranges[index] = near
    bearing = avoidance_bearing(front_readings(ranges), 1.0)
    # Steer to the opposite side of the near sonar.
    assert bearing * SONAR_HEADINGS_DEG[index] < 0


# --- PRSSI ------------------------------------------------------------------------------


def test_prssi_numbers() -> None:
    assert prssi_db(1.5, 30.0, 1.0) == pytest.approx(30.0 * math.exp(-1.5))
    assert prssi_db(1.5, 30.0, 1.0) == pytest.approx(6.694, abs=1e-3)
    assert prssi_db(0.0, 30.0, 1.0) == 30.0
    with pytest.raises(ValueError):
        prssi_db(-0.1, 30.0, 1.0)


def test_apply_prssi_penalises_only_samples_in_the_beam() -> None:
    params = EstimatorParams()
    angles = (-90.0, 20.0, 35.0, 50.0, 65.0, 66.0, 90.0)
    rssi = (-50.0,) * len(angles)
    out = apply_prssi(angles, rssi, [SonarReading(50.0, 1.5)], params)
    p = prssi_db(1.5, 30.0, 1.0)
    assert out == pytest.approx((-50.0, -50.0, -50.0 - p, -50.0 - p, -50.0 - p, -50.0, -50.0))


def test_apply_prssi_overlapping_beams_take_the_larger_penalty() -> None:
    params = EstimatorParams()
    readings = [SonarReading(30.0, 2.0), SonarReading(10.0, 1.0)]
    out = apply_prssi((20.0, 40.0), (-50.0, -50.0), readings, params)
    assert out == pytest.approx((-50.0 - prssi_db(1.0, 30, 1), -50.0 - prssi_db(2.0, 30, 1)))


def test_apply_prssi_ignores_ranges_outside_situation_two() -> None:
    params = EstimatorParams()
    readings = [SonarReading(0.0, 0.5), SonarReading(0.0, 3.5), SonarReading(0.0, None)]
    assert apply_prssi((0.0, 5.0), (-50.0, -51.0), readings, params) == (-50.0, -51.0)
    with pytest.raises(ValueError):
        apply_prssi((0.0,), (), readings, params)


@pytest.mark.parametrize("index", [0, 1, 2])
def test_prssi_moves_the_bearing_away_from_a_wall_on_the_left(index: int) -> None:
    angles = plan_scan(0.0, 180.0, 25, LIMITS, True)
    samples = static_scan(0.0, angles)
    clear = estimate_scan(samples, 0.0, front_readings(sonar_mm()), EstimatorParams())
    wall = estimate_scan(
        samples, 0.0, front_readings(sonar_mm(**{f"s{index}": 1500})), EstimatorParams()
    )
    assert clear.situation == 0 and clear.bearing_deg == pytest.approx(0.0, abs=1e-9)
    assert wall.situation == 2
    assert wall.bearing_deg < -0.5  # moved right, away from the wall
    assert wall.rssi_dbm == clear.rssi_dbm
    assert wall.rssi_leader_dbm == clear.rssi_leader_dbm  # RSSI^l stays raw
    penalised = [
        a for a, n, r in zip(wall.angles_deg, wall.nrssi_dbm, wall.rssi_dbm, strict=True) if n < r
    ]
    heading = SONAR_HEADINGS_DEG[index]
    assert penalised and all(abs(a - heading) <= 15.0 for a in penalised)


# --- estimate_scan ----------------------------------------------------------------------


def test_estimate_scan_fields() -> None:
    samples = [
        ScanSample(-10.0, -60.0, 5.0),
        ScanSample(0.0, -50.0, 5.0),
        ScanSample(10.0, -70.0, 5.0),
    ]
    est = estimate_scan(samples, 10.0, front_readings(sonar_mm(s3=500)), EstimatorParams())
    assert est.situation == 1
    assert est.angles_deg == pytest.approx((-15.0, -5.0, 5.0))
    assert est.rssi_dbm == (-60.0, -50.0, -70.0)
    assert est.nrssi_dbm == est.rssi_dbm  # no PRSSI outside situation 2
    assert est.rssi_leader_dbm == -50.0
    assert est.bearing_deg == pytest.approx(wca_bearing(est.angles_deg, est.rssi_dbm, 10.0))
    with pytest.raises(ValueError):
        estimate_scan([], 0.0, (), EstimatorParams())


# --- leader lost ------------------------------------------------------------------------


def test_update_lost_count() -> None:
    count = 0
    seen = []
    for rssi in (-90.0, -88.0, -86.0, -84.0, -90.0, -90.0, -90.0, -90.0):
        count = update_lost_count(count, rssi, -85.0)
        seen.append(count)
    assert seen == [1, 2, 3, 0, 1, 2, 3, 4]
    assert update_lost_count(2, -85.0, -85.0) == 0  # at the threshold is not lost
    with pytest.raises(ValueError):
        update_lost_count(0, math.nan, -85.0)


@given(st.lists(rssi_st, max_size=30))
def test_lost_count_counts_the_trailing_weak_run(values: list[float]) -> None:
    count = 0
    for v in values:
        count = update_lost_count(count, v, -85.0)
    run = 0
    for v in reversed(values):
        if v >= -85.0:
            break
        run += 1
    assert count == run
