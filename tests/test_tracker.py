"""The bearing filter (relayd.tracker): bounded variance, convergence, no trust in stale data."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from relayd import tracker
from relayd.tracker import TrackerParams

P = TrackerParams()


@settings(max_examples=200, deadline=None)
@given(steps=st.lists(st.tuples(st.floats(0.3, 6.0), st.floats(1.0, 10.0), st.floats(-30.0, 30.0),
                                st.floats(-60.0, 60.0)), min_size=1, max_size=40))
def test_variance_stays_bounded_and_the_covariance_valid(steps) -> None:
    tr = tracker.start(0.0, 0.0, 0.0, 5.0, P)
    t = heading = 0.0
    for dt, sd, dh, z in steps:
        t += dt
        heading += dh
        tr, _ = tracker.update(tr, t, heading, z, sd, P)
        assert tr.p_bb > 0 and tr.p_ww > 0
        assert tr.p_bw * tr.p_bw <= tr.p_bb * tr.p_ww * (1 + 1e-9)  # positive semi-definite
        if not tracker.is_lost(tr, P):
            # After an accepted update the bearing is never less certain than the
            # prediction and the measurement together allow.
            assert tr.sd_deg <= max(P.lost_sd_deg, sd) + 1e-9
        assert -180.0 <= tr.bearing_deg <= 180.0


@settings(max_examples=100, deadline=None)
@given(b0=st.floats(-60.0, 60.0), rate=st.floats(-4.0, 4.0), seed=st.integers(0, 10_000))
def test_converges_on_a_constant_rate_track(b0, rate, seed) -> None:
    rng = random.Random(seed)
    tr = tracker.start(0.0, 0.0, b0 + rng.gauss(0.0, 3.0), 3.0, P)
    t = 0.0
    for _ in range(25):
        t += 2.5
        tr, _ = tracker.update(tr, t, 0.0, b0 + rate * t + rng.gauss(0.0, 3.0), 3.0, P)
    # Consistent: the error is within what the filter itself claims (4.5 sigma); after an
    # update it claims less than one measurement's uncertainty (a Kalman update always
    # does), and it knows the rate to a few deg/s (more right after a manoeuvre update).
    assert abs(math.remainder(tr.bearing_deg - (b0 + rate * t), 360.0)) < 4.5 * tr.sd_deg
    assert abs(tr.rate_deg_s - rate) < 4.5 * tr.rate_sd_deg_s
    assert tr.sd_deg < 3.0 and tr.rate_sd_deg_s < math.sqrt(P.manoeuvre_q * 2.5)


@given(turn=st.floats(-170.0, 170.0), b=st.floats(-80.0, 80.0))
def test_the_heading_change_is_the_control_input(turn, b) -> None:
    tr = tracker.start(0.0, 10.0, b, 2.0, P)
    moved = tracker.predict(tr, 0.0, 10.0 + turn, P)
    assert math.remainder(moved.bearing_deg - (b - turn), 360.0) == pytest.approx(0.0, abs=1e-9)
    assert moved.sd_deg >= tr.sd_deg  # odometry is not perfect either


def test_headings_wrapping_at_180_are_one_small_turn() -> None:
    tr = tracker.start(0.0, 179.0, 0.0, 2.0, P)
    moved = tracker.predict(tr, 0.0, -179.0, P)
    assert moved.bearing_deg == pytest.approx(-2.0) and moved.sd_deg == pytest.approx(tr.sd_deg, abs=0.01)


@given(t=st.floats(0.1, 600.0))
def test_uncertainty_grows_with_staleness_until_the_track_is_lost(t) -> None:
    tr = tracker.start(0.0, 0.0, 20.0, 2.0, P)
    a = tracker.predict(tr, t, 0.0, P)
    b = tracker.predict(tr, t * 1.5, 0.0, P)
    assert tr.sd_deg < a.sd_deg < b.sd_deg
    assert tracker.is_lost(tracker.predict(tr, 600.0, 0.0, P), P)


def test_scans_without_a_lobe_lose_the_leader() -> None:
    tr = tracker.start(0.0, 0.0, 20.0, 2.0, P)
    for i in range(P.lost_after_misses):
        assert not tracker.is_lost(tr, P)
        tr = tracker.miss(tr, 2.0 * (i + 1), 0.0, P)
    assert tracker.is_lost(tr, P)
    # The next good measurement starts a fresh track there, with no memory of the old one.
    tr, ok = tracker.update(tr, 10.0, 0.0, -50.0, 2.0, P)
    assert ok and tr.bearing_deg == -50.0 and tr.rate_deg_s == 0.0 and not tracker.is_lost(tr, P)


def test_an_outlier_is_gated_and_a_real_jump_is_reacquired() -> None:
    tr = tracker.start(0.0, 0.0, 0.0, 1.0, P)
    for k in range(1, 6):
        tr, _ = tracker.update(tr, 2.0 * k, 0.0, 0.0, 1.0, P)
    before = tr.bearing_deg
    tr, ok = tracker.update(tr, 12.0, 0.0, 60.0, 1.0, P)  # one reflection
    assert not ok and tr.bearing_deg == pytest.approx(before, abs=0.5)
    tr, ok = tracker.update(tr, 14.0, 0.0, 61.0, 1.0, P)  # it is really there
    assert ok and tr.bearing_deg == pytest.approx(61.0, abs=1.0)


@settings(max_examples=100, deadline=None)
@given(rate=st.floats(-30.0, 30.0), turn=st.floats(-40.0, 40.0), off=st.floats(40.0, 120.0))
def test_a_rejected_measurement_stops_the_prediction_running_on_at_its_rate(rate, turn, off) -> None:
    # A track that learnt a rate (perhaps from a leader that jumped) and then sees the
    # leader far from its prediction: it holds its last bearing (in today's frame)
    # instead of extrapolating further, until the next scan decides.
    tr = tracker.Track(t=10.0, heading_deg=0.0, bearing_deg=0.0, rate_deg_s=rate, p_bb=4.0, p_bw=0.0,
                       p_ww=0.25, updates=5)
    predicted = tracker.predict(tr, 12.0, turn, P).bearing_deg
    held, ok = tracker.update(tr, 12.0, turn, predicted + off, 1.0, P)
    assert not ok and held.rejects == 1
    assert held.rate_deg_s == 0.0
    assert held.bearing_deg == pytest.approx(-turn, abs=1e-9)  # the last bearing, seen after the turn
    later = tracker.predict(held, 20.0, turn, P)
    assert later.bearing_deg == pytest.approx(-turn, abs=1e-9)


def test_non_finite_input_is_refused() -> None:
    tr = tracker.start(0.0, 0.0, 0.0, 1.0, P)
    with pytest.raises(ValueError):
        tracker.update(tr, 1.0, 0.0, math.nan, 1.0, P)
    with pytest.raises(ValueError):
        tracker.predict(tr, math.inf, 0.0, P)
