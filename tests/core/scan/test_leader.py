"""The bearing models in the brain (relayd.core.scan.leader): selection, the adaptive window, lost leaders.

Driven through `bench.brainrig.BrainRig`: the real brain on virtual time, fed SIPs,
RSSI and step-mode sweeps timed like the scanner's, in a small kinematic world.
"""

from __future__ import annotations

import math
import random
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from bench.brainrig import BrainRig, cos_n_pattern, still
from relayd.config.model import Settings
from relayd.core.scan import tracker
from relayd.core.scan.bearing import LobeFit, fit_main_lobe
from relayd.core.scan.estimator import ScanEstimate
from relayd.core.scan.leader import LeaderParams, TrackingModel, make_model
from relayd.core.scan.pool import PooledScan, PoolParams, ScanPool
from relayd.core.scan.window import Window
from relayd.core.vocab import DriveState, Mode
from relayd.runtime.state import RelayState


def leader_at(bearing_deg: float, distance_m: float = 5.0) -> tuple[float, float]:
    return (
        distance_m * math.cos(math.radians(bearing_deg)),
        distance_m * math.sin(math.radians(bearing_deg)),
    )


def rig(estimator: str, window: str, bearing_deg: float, **kw: object) -> BrainRig:
    r = BrainRig(
        scan={"estimator": estimator, "window": window},
        leader=still(*leader_at(bearing_deg)),
        pattern=cos_n_pattern(45.0, 15.0),
        **kw,
    )  # type: ignore[arg-type]
    r.start()
    return r


@pytest.mark.parametrize("bearing", [-85.0, -60.0, 0.0, 45.0, 80.0])
def test_standing_still_the_lobe_estimator_finds_a_leader_near_the_servo_limit(
    bearing: float,
) -> None:
    lobe, wca = rig("lobe", "adaptive", bearing), rig("wca", "full", bearing)
    lobe.run_scans(5)
    wca.run_scans(5)
    est = lobe.results[-1][1].estimate
    assert abs(est.bearing_deg - bearing) <= 1.5
    assert est.bearing_sd_deg is not None and 0.0 < est.bearing_sd_deg < 5.0
    if abs(bearing) >= 60.0:  # the centroid is pulled toward the middle there
        assert abs(wca.results[-1][1].estimate.bearing_deg - bearing) > 5.0
    assert wca.results[-1][1].estimate.bearing_sd_deg is None


def test_a_confident_filter_narrows_the_window_and_sweeps_faster() -> None:
    r = rig("lobe", "adaptive", 20.0)
    r.run_scans(6)
    first, last = r.results[0][1].record, r.results[-1][1].record
    assert len(first.angles_deg) == 25 and max(first.angles_deg) - min(
        first.angles_deg
    ) == pytest.approx(180.0)
    assert len(last.angles_deg) < 20
    assert min(last.angles_deg) < 20.0 < max(last.angles_deg)  # around the leader
    assert (
        last.period_s is not None
        and first.period_s is not None
        and last.period_s < 0.7 * first.period_s
    )
    # The same filter with window = "full" keeps sweeping the configured width.
    full = rig("lobe", "full", 20.0)
    full.run_scans(6)
    assert all(len(res.record.angles_deg) == 25 for _, res in full.results)


def test_a_leader_that_goes_silent_is_lost_wheels_zero_and_the_window_goes_full() -> None:
    r = BrainRig(
        scan={"estimator": "lobe", "window": "adaptive"},
        leader=still(*leader_at(10.0, 3.0)),
        pattern=cos_n_pattern(45.0, 15.0),
        mode=Mode.FOLLOW,
        control={"threshold_l_dbm": -10.0},
    )  # never "leader near": it drives toward the leader
    r.start()
    r.run_scans(6)
    assert r.brain.last_output is not None and r.brain.last_output.state is DriveState.DRIVING
    assert len(r.results[-1][1].record.angles_deg) < 25
    # Every direction hears the leader equally well (a reflection-filled room, an antenna
    # knocked off): RSSI^l stays high, so only the filter can tell the bearing is gone.
    r.pattern = lambda off: 0.0
    r.run_scans(4)
    assert r.brain.scans.lost_count == 0  # not the RSSI rule
    out = r.brain.last_output
    assert (
        out is not None
        and out.state is DriveState.LEADER_LOST
        and (out.left_mm_s, out.right_mm_s) == (0, 0)
    )
    assert r.brain.inputs(r.t).bearing_deg is None or r.brain.inputs(r.t).leader_lost
    assert len(r.results[-1][1].record.angles_deg) == 25  # searching the whole servo range


def test_the_filter_steers_by_its_prediction_between_scans() -> None:
    r = rig("lobe", "full", 30.0)
    r.run_scans(3)
    before = r.bearing_now()
    # The robot turns 20 degrees left (odometry only, no new scan yet): the bearing follows.
    r.theta_deg += 20.0
    r.run_until(r.t + 0.1)
    after = r.bearing_now()
    assert before is not None and after is not None
    assert after == pytest.approx(before - 20.0, abs=1.0)


def test_selection_is_strict() -> None:
    Settings.model_validate({"scan": {"estimator": "wca", "window": "full"}})
    with pytest.raises(ValidationError):
        Settings.model_validate({"scan": {"estimator": "wca", "window": "adaptive"}})
    with pytest.raises(ValidationError):
        Settings.model_validate({"scan": {"estimator": "music"}})
    with pytest.raises(ValueError):
        LeaderParams(estimator="wca", window="adaptive")


def test_status_shows_the_uncertainty() -> None:
    st = RelayState()
    assert "bearing_sd_deg" in st.snapshot(0.0) and st.snapshot(0.0)["bearing_sd_deg"] is None


def test_a_lobe_carved_up_by_the_prssi_penalty_still_gives_the_leader() -> None:
    """A relay 1 m behind its leader robot: the sonars see the leader and PRSSI cuts the lobe."""
    from relayd.core.scan.estimator import (
        EstimatorParams,
        ScanEstimate,
        SonarReading,
        apply_prssi,
        plan_scan,
    )
    from relayd.core.scan.leader import TrackingModel

    angles = plan_scan(0.0, 180.0, 25, (-90.0, 90.0), True)
    pattern = cos_n_pattern(90.0, 20.0)
    rssi = tuple(-30.0 + pattern(a) for a in angles)
    sonar = [SonarReading(h, 1.0) for h in (30.0, 10.0, -10.0, -30.0)]
    nrssi = apply_prssi(angles, rssi, sonar, EstimatorParams())
    assert min(n - r for n, r in zip(nrssi, rssi, strict=True)) < -10.0
    est = ScanEstimate(
        bearing_deg=0.0,
        rssi_leader_dbm=max(rssi),
        situation=2,
        angles_deg=angles,
        rssi_dbm=rssi,
        nrssi_dbm=nrssi,
    )
    model = TrackingModel(LeaderParams(estimator="lobe"))
    for k in range(5):
        out = model.scan_done(2.5 * k, 0.0, est, [2.5 * k] * len(angles))
        assert abs(out.bearing_deg) < 5.0
    assert not model.lost(12.0, 0.0)


def _faded_scan(
    rng: random.Random, bearing_deg: float, sd_db: float = 3.0
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    pattern = cos_n_pattern(90.0, 20.0)
    angles = tuple(-90.0 + 7.5 * i for i in range(25))
    return angles, tuple(-50.0 + pattern(a - bearing_deg) + rng.gauss(0.0, sd_db) for a in angles)


def _pooled(
    angles: tuple[float, ...],
    rssi: tuple[float, ...],
    t: float,
    heading: float,
    before: tracker.Track | None,
) -> PooledScan:
    fit = fit_main_lobe(angles, rssi)
    assert fit is not None
    return PooledScan(angles, rssi, t, heading, before, fit)


def _still_leader_pool(
    turn: list[float],
) -> tuple[tuple[LobeFit, tracker.Track | None] | None, float]:
    """(the pool's fit of a still leader's last scans, the leader's bearing in the newest frame).

    The relay turns `turn[k]` deg between scans (odometry heading); the leader stands at
    20 deg of the first frame; noise-free scans of the test's cos^n antenna.
    """
    rng = random.Random(0)
    params = LeaderParams(estimator="lobe")
    pool = ScanPool(params.pool)
    heading, t = 0.0, 0.0
    track = tracker.start(0.0, 0.0, 20.0, 2.0, params.tracker)
    for dh in turn:
        angles, rssi = _faded_scan(rng, 20.0 - heading, 0.0)
        pool.add(_pooled(angles, rssi, t, heading, track))
        heading, t = heading + dh, t + 2.5
    angles, rssi = _faded_scan(rng, 20.0 - heading, 0.0)
    newest = _pooled(angles, rssi, t, heading, track)
    out = pool.fit(
        replace(track, t=t - 2.5, heading_deg=heading - turn[-1]), newest, params.lobe, None
    )
    if out is not None:
        assert out[1] is track
        assert out[0].used > len(angles)  # more than one scan's samples
    return out, 20.0 - heading


@settings(max_examples=60, deadline=None)
@given(steps=st.lists(st.integers(-2, 2), min_size=4, max_size=4))
def test_a_still_leader_is_fitted_over_several_scans_in_the_newest_frame(steps: list[int]) -> None:
    # The relay turns between scans by whole sample steps (7.5 deg), the leader stands
    # still: every scan sees the lobe at the same place against its samples, so every
    # scan's fit has the same small bias (the antenna is not a parabola in dB) and they
    # agree. The pool carries each older scan into the newest frame, so it must pool them,
    # and the pooled bearing is the newest frame's.
    out, truth_deg = _still_leader_pool([7.5 * k for k in steps])
    assert out is not None
    assert abs(out[0].bearing_deg - truth_deg) <= 4.0


@settings(max_examples=60, deadline=None)
@given(turn=st.lists(st.floats(-10.0, 10.0), min_size=4, max_size=4))
def test_whatever_the_turns_a_pooled_still_leader_is_where_the_newest_frame_sees_it(
    turn: list[float],
) -> None:
    # A turn by a fraction of a sample step moves the lobe against the samples, and one
    # scan's fit of this antenna moves by up to 2 deg with it: two scans may then disagree
    # by more than the agreement test allows (1.5 sd of the two), and the pool refuses, on
    # purpose (the newest scan's own fit is used). Whenever it does pool, the bearing is
    # the newest frame's.
    out, truth_deg = _still_leader_pool(turn)
    if out is not None:
        assert abs(out[0].bearing_deg - truth_deg) <= 4.0


def test_a_moving_bearing_or_a_disagreeing_scan_is_not_pooled() -> None:
    rng = random.Random(3)
    params = LeaderParams(estimator="lobe")
    pool = ScanPool(params.pool)
    track = tracker.start(0.0, 0.0, 0.0, 2.0, params.tracker)
    pool.add(_pooled(*_faded_scan(rng, 0.0, 0.0), 0.0, 0.0, track))
    newest = _pooled(*_faded_scan(rng, 0.0, 0.0), 2.5, 0.0, track)
    assert pool.fit(track, newest, params.lobe, None) is not None
    # The filter says the bearing moves (10 deg/s): the older scan is elsewhere now.
    assert pool.fit(replace(track, rate_deg_s=10.0), newest, params.lobe, None) is None
    # The newest scan sees the leader 40 deg away from the older one: no pooling.
    assert (
        pool.fit(track, _pooled(*_faded_scan(rng, 40.0, 0.0), 2.5, 0.0, track), params.lobe, None)
        is None
    )
    pool.clear()
    assert pool.fit(track, newest, params.lobe, None) is None


def test_standing_still_under_fading_the_pooled_estimate_is_better_than_one_scan_at_a_time() -> (
    None
):
    # The same faded scans of a leader at 60 deg (a 90 deg lobe cut by the servo limit),
    # through the brain's model with and without pooling.
    def run(scans: int, seed: int) -> float:
        rng = random.Random(seed)
        model = TrackingModel(LeaderParams(estimator="lobe", pool=PoolParams(scans=scans)))
        out = None
        for k in range(5):
            angles, rssi = _faded_scan(rng, 60.0)
            est = ScanEstimate(
                bearing_deg=0.0,
                rssi_leader_dbm=max(rssi),
                situation=0,
                angles_deg=angles,
                rssi_dbm=rssi,
                nrssi_dbm=rssi,
            )
            out = model.scan_done(
                2.5 * (k + 1), 0.0, est, [2.5 * k + 0.1 * i for i in range(len(angles))]
            )
        assert out is not None
        return out.bearing_deg - 60.0

    pooled = [run(5, s) for s in range(40)]
    alone = [run(1, s) for s in range(40)]

    def rms(xs: list[float]) -> float:
        return math.sqrt(sum(x * x for x in xs) / len(xs))

    assert rms(pooled) < 0.8 * rms(alone)


def test_a_moving_leader_gets_a_shorter_coarser_sweep_a_still_one_every_sample_of_the_lobe() -> (
    None
):
    # A 90 deg antenna: the full window's 7.5 deg spacing is finer than a lobe that wide
    # needs. While the bearing moves the sweep is for speed, while it stands for accuracy.
    model = TrackingModel(LeaderParams(estimator="lobe", window="adaptive"))
    model._beamwidths.extend([80.0] * 3)
    model._sweep_s = 1.5
    full = Window(0.0, 180.0, 25)
    still_track = tracker.start(10.0, 0.0, 20.0, 2.0, model.params.tracker)
    model.track = still_track
    still = model.window(10.0, 0.0, full)
    model.track = replace(still_track, rate_deg_s=8.0)
    moving = model.window(10.0, 0.0, full)
    assert still is not None and moving is not None
    assert still.width_deg / (still.samples - 1) == pytest.approx(7.5)
    assert moving.width_deg / (moving.samples - 1) >= 80.0 / 8.0 - 1e-9
    assert moving.samples <= 0.7 * still.samples
    assert moving.centre_deg > still.centre_deg  # led by the rate


def test_a_fit_whose_few_residuals_happen_to_be_small_is_not_trusted_beyond_the_channels_noise() -> (
    None
):
    rng = random.Random(5)
    model = TrackingModel(LeaderParams(estimator="lobe", pool=PoolParams(scans=1)))
    for k in range(6):  # the channel: 3 dB of fading
        angles, rssi = _faded_scan(rng, 0.0)
        model.scan_done(2.5 * (k + 1), 0.0, ScanEstimate(0.0, max(rssi), 0, angles, rssi, rssi), [])
    angles, clean = _faded_scan(rng, 0.0, 0.0)
    alone = fit_main_lobe(angles, clean)
    assert alone is not None
    model.scan_done(20.0, 0.0, ScanEstimate(0.0, max(clean), 0, angles, clean, clean), [])
    assert model.last_fit is not None and model.last_fit.sd_deg > 3.0 * alone.sd_deg


def test_near_a_servo_limit_the_adaptive_window_is_clipped_not_shifted_inside() -> None:
    # Beyond the limit there is no lobe to see: the sweep is shorter, not moved inward.
    model = TrackingModel(LeaderParams(estimator="lobe", window="adaptive"))
    model._beamwidths.extend([80.0] * 3)
    full = Window(0.0, 180.0, 25)
    model.track = tracker.start(10.0, 0.0, 0.0, 2.0, model.params.tracker)
    middle = model.window(10.0, 0.0, full)
    model.track = tracker.start(10.0, 0.0, 75.0, 2.0, model.params.tracker)
    edge = model.window(10.0, 0.0, full)
    assert middle is not None and edge is not None
    assert edge.centre_deg + edge.width_deg / 2.0 <= 90.0 + 1e-9
    assert edge.centre_deg - edge.width_deg / 2.0 <= 75.0 - 40.0  # the near flank is in
    assert edge.samples < middle.samples


def test_the_default_is_the_lobe_fit_with_the_adaptive_window_and_wca_alone_is_the_papers() -> None:
    assert (Settings().scan.estimator, Settings().scan.window) == ("lobe", "adaptive")
    wca = Settings.model_validate({"scan": {"estimator": "wca"}}).scan
    assert (wca.estimator, wca.window) == ("wca", "full")
    with pytest.raises(ValidationError):
        Settings.model_validate({"scan": {"estimator": "wca", "window": "adaptive"}})


def test_the_steered_bearing_stays_where_a_scan_could_have_put_it() -> None:
    model = TrackingModel(LeaderParams(estimator="lobe", window="adaptive"))
    model.track = replace(tracker.start(0.0, 0.0, 80.0, 2.0, model.params.tracker), rate_deg_s=20.0)
    model.window(0.0, 0.0, Window(0.0, 180.0, 25))  # the brain plans with the servo's range
    now = model.bearing_now(3.0, 0.0)  # 80 + 3 s x 20 deg/s = 140 predicted
    assert now == pytest.approx(90.0 + model.params.lobe.max_extrapolation_deg)


def test_a_leader_at_the_servo_limit_gets_a_narrow_window_without_a_two_sided_fit() -> None:
    # At -80 deg the 90 deg lobe is cut by the -90 deg limit on every scan: no beamwidth is
    # ever learnt from a two-sided fit, and the window used to stay the full range (2.45 s
    # a sweep: a leader that starts walking from there moved 35 deg before the next fit).
    r = BrainRig(scan={"estimator": "lobe", "window": "adaptive"}, leader=still(*leader_at(-80.0)))
    r.start()
    r.run_scans(6)
    model = r.brain.scans.model
    assert isinstance(model, TrackingModel) and model.beamwidth_deg is None
    last = r.results[-1][1].record
    assert len(last.angles_deg) < 25 and min(last.angles_deg) == pytest.approx(-90.0)
    assert (
        abs(r.results[-1][1].estimate.bearing_deg + 80.0) <= 5.0
    )  # 8.9 deg with the full-range sweeps


@settings(max_examples=300, deadline=None)
@given(
    step=st.floats(1.0, 40.0),
    slew=st.floats(30.0, 600.0),
    settle=st.floats(0.0, 0.2),
    hz=st.floats(2.0, 100.0),
)
def test_a_clocked_step_never_sweeps_slower_and_stays_near_the_step_asked(
    step, slew, settle, hz
) -> None:
    from relayd.core.scan.window import WindowParams, clocked_step_deg

    wp = WindowParams(servo_deg_s=slew, settle_s=settle, sample_period_s=1.0 / hz)

    def speed(s: float) -> float:  # the scanner's step mode: travel + settle, then the next reading
        return s / (max(1, math.ceil((s / slew + settle) * hz - 1e-9)) / hz)

    got = clocked_step_deg(step, wp)
    assert wp.min_fraction * step - 1e-9 <= got <= wp.max_stretch * step + 1e-9
    assert speed(got) >= speed(step) - 1e-9
    assert clocked_step_deg(step, WindowParams()) == step  # timing unknown: as planned


def test_relayds_default_clock_sweeps_9_deg_steps_and_continuous_mode_is_left_alone() -> None:
    from relayd.config.params import brain_params
    from relayd.core.scan.window import clocked_step_deg

    wp = brain_params(Settings.model_validate({})).leader.adaptive
    # 180 deg/s, 50 ms settle, 20 Hz: 7.5 and 11.25 deg steps take 2 and 3 readings
    # (75 deg/s); 9 deg ones take 2 (90 deg/s).
    assert clocked_step_deg(7.5, wp) == pytest.approx(9.0) and clocked_step_deg(
        11.25, wp
    ) == pytest.approx(9.0)
    continuous = brain_params(
        Settings.model_validate({"scan": {"mode": "continuous"}})
    ).leader.adaptive
    assert continuous.sample_period_s is None and clocked_step_deg(7.5, continuous) == 7.5


def test_the_adaptive_sweep_runs_on_the_scanners_clock() -> None:
    r = rig("lobe", "adaptive", 20.0)
    r.run_scans(6)
    last = r.results[-1][1].record
    steps = sorted(last.angles_deg)
    assert steps[1] - steps[0] == pytest.approx(9.0)
    assert (
        last.period_s is not None and last.period_s / len(last.angles_deg) <= 0.11
    )  # 2 readings a sample


@pytest.mark.parametrize(("start", "ascending"), [(50.0, True), (70.0, True), (-20.0, False)])
def test_a_leader_moving_during_the_sweep_is_fitted_in_its_own_frame(
    start: float, ascending: bool
) -> None:
    # 12 deg/s against a 1.2 s sweep: the beam meets the leader 14 deg before or after
    # where it was, and the lobe looks 15 % wider or narrower than the antenna's. Where
    # the window cuts the lobe, the curvature the beamwidth prior then asks for moves the
    # centre; fitted in the leader's frame the lobe has the antenna's width again.
    rate, pattern = 12.0, cos_n_pattern(60.0, 20.0)
    angles = [-30.0 + 9.0 * i for i in range(13)]
    if not ascending:
        angles.reverse()
    times = [10.0 + 0.1 * i for i in range(13)]

    def truth(t: float) -> float:
        return start + rate * (t - 10.0)

    rssi = tuple(-50.0 + pattern(a - truth(ti)) for a, ti in zip(angles, times, strict=True))
    still = tuple(-50.0 + pattern(a - 20.0) for a in angles)
    errors = {}
    for compensate in (True, False):
        model = TrackingModel(LeaderParams(estimator="lobe", compensate_motion=compensate))
        for k in range(6):  # the beamwidth, learnt from a still leader
            model.scan_done(
                1.5 * k, 0.0, ScanEstimate(0.0, -50.0, 0, tuple(angles), still, still), []
            )
        model.track = replace(
            tracker.start(9.9, 0.0, truth(9.9) + 2.0, 2.0, model.params.tracker),
            rate_deg_s=rate - 1.0,
        )  # a filter that knows the rate roughly
        model.scan_done(
            times[-1], 0.0, ScanEstimate(0.0, max(rssi), 0, tuple(angles), rssi, rssi), times
        )
        assert model.last_fit is not None and model.track is not None
        errors[compensate] = abs(model.last_fit.bearing_deg - truth(model.track.t))
    assert errors[True] < 2.5
    assert errors[True] < 0.6 * errors[False]


def test_a_lost_track_says_where_the_scans_last_put_the_leader_in_todays_frame() -> None:
    # The search turn's evidence (relayd/core/control/search.py): the last fit however unsure, or with
    # no fit the strongest sample at a servo limit; only while the track is lost.
    model = TrackingModel(LeaderParams(estimator="lobe", window="adaptive"))
    model.window(0.0, 0.0, Window(0.0, 180.0, 25))  # the servo's range
    angles = tuple(-90.0 + 7.5 * i for i in range(25))
    flat = tuple(-60.0 for _ in angles)
    model.track = tracker.start(0.0, 0.0, 80.0, 2.0, model.params.tracker)
    assert model.search_bearing(0.0, 0.0) is None  # not lost: nothing to search for
    # No lobe, the strongest sample at the +90 limit (the lobe's flank), three times: lost.
    edge = (*flat[:-1], -50.0)
    for k in range(1, 4):
        model.scan_done(2.0 * k, 10.0, ScanEstimate(0.0, -50.0, 0, angles, edge, edge), [])
    assert model.last_fit is None and model.lost(6.0, 10.0)
    assert model.search_bearing(6.0, 10.0) == pytest.approx(90.0)
    assert model.search_bearing(6.0, 40.0) == pytest.approx(60.0)  # turned 30 deg toward it
    # A scan with its strongest sample in the middle and no lobe says nothing new.
    middle = tuple(-50.0 if i == 12 else -60.0 for i in range(25))
    model.scan_done(8.0, 40.0, ScanEstimate(0.0, -50.0, 0, angles, middle, middle), [])
    assert model.search_bearing(8.0, 40.0) == pytest.approx(60.0)
    # The centroid model never searches: the paper's relay stands and rescans.
    assert make_model(LeaderParams()).search_bearing(8.0, 40.0) is None
    # Evidence ages: a few scan periods after the scan that gave it, it says nothing.
    age = model.params.evidence_max_age_s
    assert model.search_bearing(6.0 + age, 40.0) == pytest.approx(60.0)
    assert model.lost(6.1 + age, 40.0) and model.search_bearing(6.1 + age, 40.0) is None


@settings(max_examples=60, deadline=None)
@given(
    noise=st.lists(st.floats(-1.5, 1.5), min_size=75, max_size=75), limit=st.sampled_from([0, 24])
)
def test_a_leader_that_faded_into_noise_leaves_no_evidence_to_turn_toward(
    noise: list[float], limit: int
) -> None:
    """Three scans of noise at -88 dBm (below lost_rssi, -85) whose strongest sample lies at a
    servo limit: a faint, far leader, not one behind; the relay stands (docs/CONTROL.md 6.1)."""
    model = TrackingModel(LeaderParams(estimator="lobe", window="adaptive"))
    model.window(0.0, 0.0, Window(0.0, 180.0, 25))
    angles = tuple(-90.0 + 7.5 * i for i in range(25))
    model.track = tracker.start(0.0, 0.0, 80.0, 2.0, model.params.tracker)
    for k in range(3):
        scan = [-88.0 + n for n in noise[25 * k : 25 * (k + 1)]]
        scan[limit] = max(scan) + 0.5  # the strongest at the limit (as in ~40 % of such scans)
        model.scan_done(
            2.0 * (k + 1),
            0.0,
            ScanEstimate(0.0, max(scan), 0, angles, tuple(scan), tuple(scan)),
            [],
        )
    assert model.last_fit is None and model.lost(6.0, 0.0)
    assert model.search_bearing(6.0, 0.0) is None


def test_the_daemon_takes_the_evidence_limits_from_lost_rssi_and_the_scan_period() -> None:
    from relayd.config.params import EVIDENCE_SCANS, brain_params, nominal_scan_period_s

    s = Settings.model_validate({"control": {"lost_rssi_dbm": -80}})
    p = brain_params(s).leader
    assert p.evidence_min_rssi_dbm == -80.0
    assert p.evidence_max_age_s == pytest.approx(EVIDENCE_SCANS * nominal_scan_period_s(s))


def test_with_a_pattern_a_fast_leaders_scan_is_fitted_by_the_parabola_moved_to_the_leader() -> None:
    """A measured pattern is matched to a still leader's scan; a fast one's (carried by the
    filter's estimated rate, its lobe stretched or squeezed) gets the parabola, moved by
    where the pattern's 3 dB points are centred: a squinted lobe's parabola sits there."""
    from relayd.core.scan.moving import fit_moving, lobe_centre_deg
    from relayd.core.scan.patternfit import fit_pattern
    from relayd.sim.antennas import family_pattern

    angles = [-90.0 + 7.5 * i for i in range(25)]
    # The builtin lobe 1.3 times as wide as the antenna's (the leader moved with the
    # sweep); the asymmetric one as it is, its parabola 11 deg from the leader.
    for name, stretch in (("builtin", 1.3), ("asymmetric", 1.0)):
        pattern = family_pattern(name)
        model = TrackingModel(LeaderParams(estimator="lobe", window="adaptive", pattern=pattern))
        values = [-50.0 + pattern.gain_db((20.0 - a) / stretch) for a in angles]
        still, fast = model._fit(angles, values, False), model._fit(angles, values, True)
        assert still == fit_pattern(angles, values, pattern, model.params.pattern_fit)
        assert fast == fit_moving(angles, values, pattern, model.params.lobe)
        plain = fit_main_lobe(angles, values, beamwidth_prior_deg=pattern.beamwidth_deg())
        assert fast is not None and plain is not None
        assert fast.bearing_deg == pytest.approx(plain.bearing_deg + lobe_centre_deg(pattern))
        assert abs(fast.bearing_deg - 20.0) < 3.0, name
        assert fast.beamwidth_deg > 100.0 or stretch == 1.0  # its own width, not the file's
    assert abs(plain.bearing_deg - 20.0) > 8.0  # the asymmetric lobe's, unmoved
    # The asymmetric lobe: peak 8 deg off axis, 3 dB points 22 and 28 deg either side.
    assert lobe_centre_deg(family_pattern("asymmetric")) == pytest.approx(11.0, abs=0.3)
