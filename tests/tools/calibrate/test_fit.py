"""The path-loss fit (relayd/calibrate/fit.py): recovery on synthetic drives, robustness, thresholds."""

from __future__ import annotations

import dataclasses
import math
import random
from statistics import NormalDist

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from relayd.calibrate.fit import (
    FitError,
    PathLossFit,
    fit_path_loss,
    huber_line,
    required_rssi_dbm,
    threshold_for_hop_length,
    threshold_for_throughput,
)


def synthetic_drive(
    l0: float,
    n: float,
    sigma: float,
    seed: int,
    *,
    points: int = 400,
    far_m: float = 30.0,
    outliers: float = 0.0,
) -> tuple[list[float], list[float]]:
    """A robot pushed from 1 m to `far_m` away from the node, one reading every few cm:
    log-normal shadowing per reading, integer dBm as a radio reports, and a share of
    wild readings (a person walking between the antennas: 15-30 dB down)."""
    rng = random.Random(seed)
    d = [1.0 + (far_m - 1.0) * i / (points - 1) for i in range(points)]
    rssi = []
    for di in d:
        r = l0 - 10.0 * n * math.log10(di) + rng.gauss(0.0, sigma)
        if rng.random() < outliers:
            r -= rng.uniform(15.0, 30.0)
        rssi.append(float(round(r)))
    return d, rssi


@pytest.mark.parametrize("seed", range(10))
def test_recovers_n_within_0_2_and_l0_within_2_db(seed: int) -> None:
    rng = random.Random(1000 + seed)
    l0, n, sigma = rng.uniform(-25.0, -10.0), rng.uniform(2.0, 4.0), rng.uniform(2.0, 6.0)
    d, r = synthetic_drive(l0, n, sigma, seed)
    fit = fit_path_loss(d, r, resamples=60, seed=seed)
    assert fit.n == pytest.approx(n, abs=0.2)
    assert fit.l0_dbm == pytest.approx(l0, abs=2.0)
    assert fit.sigma_db == pytest.approx(sigma, rel=0.25)
    assert fit.n_ci.low <= fit.n <= fit.n_ci.high
    assert fit.l0_ci.low <= fit.l0_dbm <= fit.l0_ci.high


@pytest.mark.parametrize("seed", range(5))
def test_robust_to_a_tenth_of_wild_readings(seed: int) -> None:
    d, r = synthetic_drive(-15.0, 3.0, 4.0, seed, outliers=0.1)
    fit = fit_path_loss(d, r, resamples=40, seed=seed)
    assert fit.n == pytest.approx(3.0, abs=0.2)
    assert fit.l0_dbm == pytest.approx(-15.0, abs=2.0)
    assert fit.sigma_db == pytest.approx(4.0, rel=0.25)  # the wild readings do not inflate sigma


@settings(max_examples=30, deadline=None)
@given(
    a=st.floats(-40, 0),
    b=st.floats(-5, -1),
    xs=st.lists(st.floats(0, 20), min_size=3, max_size=30, unique=True),
)
def test_huber_is_exact_on_a_line(a: float, b: float, xs: list[float]) -> None:
    if max(xs) - min(xs) < 1.0:
        return
    ys = [a + b * x for x in xs]
    fa, fb, sd = huber_line(xs, ys)
    assert fa == pytest.approx(a, abs=1e-6) and fb == pytest.approx(b, abs=1e-6) and sd < 1e-6


def test_refuses_data_without_a_slope() -> None:
    with pytest.raises(FitError, match="usable readings"):
        fit_path_loss([1.0, 2.0, 3.0], [-20.0, -28.0, -33.0])
    with pytest.raises(FitError, match="drive to at least"):
        fit_path_loss([4.0 + 0.01 * i for i in range(50)], [-40.0] * 50)
    with pytest.raises(FitError, match="differ"):
        fit_path_loss([1.0], [])


def test_near_field_and_noise_floor_are_left_out() -> None:
    d, r = synthetic_drive(-15.0, 3.0, 2.0, 1)
    fit = fit_path_loss(
        [0.1, 0.2, *d, 25.0], [-5.0, -5.0, *r, -95.0], floor_dbm=-95.0, resamples=20
    )
    assert fit.dropped == 3
    assert fit.n == pytest.approx(3.0, abs=0.2)


def test_thresholds() -> None:
    d, r = synthetic_drive(-15.0, 3.0, 4.0, 2)
    fit = fit_path_loss(d, r, resamples=20)
    # Median RSSI at 10 m is L0 - 10 n; a 10 % outage raises it by 1.28 sigma.
    want = fit.l0_dbm - 10.0 * fit.n + 1.2816 * fit.sigma_db
    assert threshold_for_hop_length(fit, 10.0, 0.1) == pytest.approx(want, abs=0.01)
    # 10 Mbit/s after a MAC efficiency of 0.5 needs 802.11g's 24 Mbit/s rate: -74 dBm.
    assert required_rssi_dbm(10.0) == -74.0
    assert required_rssi_dbm(10.0, "802.11n-1x1") == -74.0
    assert threshold_for_throughput(fit, 10.0, 0.05) == pytest.approx(
        -74.0 + 1.6449 * fit.sigma_db, abs=0.01
    )
    with pytest.raises(ValueError, match="more than"):
        required_rssi_dbm(40.0)
    assert fit.distance_at(fit.rssi_at(7.0)) == pytest.approx(7.0)


@given(
    l0=st.floats(-40.0, 0.0),
    n=st.floats(1.0, 5.0),
    sigma=st.floats(0.0, 10.0),
    hop=st.floats(0.5, 100.0),
    outage=st.floats(0.001, 0.4),
)
@settings(max_examples=100, deadline=None)
def test_a_known_model_gives_the_fits_thresholds(
    l0: float, n: float, sigma: float, hop: float, outage: float
) -> None:
    """A model given (a simulator's radio) answers the threshold questions with the same
    arithmetic as a fitted one: the median at the hop raised by z sigma, and back again."""
    fit = PathLossFit.known(l0, n, sigma)
    assert fit.rssi_at(1.0) == pytest.approx(l0)
    assert fit.distance_at(fit.rssi_at(hop)) == pytest.approx(hop, rel=1e-9)
    thr = threshold_for_hop_length(fit, hop, outage)
    assert thr == pytest.approx(
        l0 - 10.0 * n * math.log10(hop) + NormalDist().inv_cdf(1.0 - outage) * sigma
    )
    # A stricter outage never lowers the threshold (the robot stops sooner, not later).
    assert threshold_for_hop_length(fit, hop, outage / 2.0) >= thr
    assert l0 in fit.l0_ci and n in fit.n_ci


@pytest.mark.parametrize(
    ("l0", "n", "sigma"),
    [(math.nan, 2.0, 3.0), (-20.0, 0.0, 3.0), (-20.0, 2.0, -1.0), (-20.0, math.inf, 3.0)],
)
def test_a_known_model_refuses_nonsense(l0: float, n: float, sigma: float) -> None:
    with pytest.raises(ValueError):
        PathLossFit.known(l0, n, sigma)


#: A corridor recording's rear-link readings (relayd sim --scenario corridor --seconds 120
#: --record, relay1): the robot stands at the start distance for 83 polls, then drives.
CORRIDOR_DISTANCE_M = [1.0] * 83 + [
    1.117,
    1.297,
    1.477,
    1.648,
    1.809,
    1.987,
    2.149,
    2.216,
    2.216,
    2.216,
    2.216,
    2.3,
    2.517,
    2.716,
    2.913,
    3.119,
    3.342,
    3.565,
    3.799,
    4.038,
    4.271,
    4.508,
    4.748,
    4.976,
    5.211,
    5.466,
    5.716,
    5.966,
    6.202,
    6.429,
    6.659,
    6.881,
    7.128,
    7.35,
    7.583,
    7.827,
    8.061,
]
CORRIDOR_RSSI_DBM = [
    -16,
    -14,
    -12,
    -16,
    -14,
    -15,
    -12,
    -12,
    -16,
    -14,
    -13,
    -14,
    -13,
    -13,
    -14,
    -14,
    -13,
    -12,
    -12,
    -14,
    -13,
    -17,
    -13,
    -11,
    -12,
    -13,
    -15,
    -16,
    -13,
    -14,
    -15,
    -13,
    -12,
    -11,
    -15,
    -13,
    -14,
    -13,
    -11,
    -14,
    -11,
    -13,
    -16,
    -12,
    -11,
    -15,
    -12,
    -16,
    -14,
    -14,
    -15,
    -15,
    -12,
    -12,
    -12,
    -12,
    -13,
    -16,
    -13,
    -12,
    -13,
    -14,
    -15,
    -12,
    -11,
    -14,
    -13,
    -14,
    -13,
    -14,
    -13,
    -12,
    -14,
    -13,
    -13,
    -14,
    -13,
    -15,
    -13,
    -13,
    -16,
    -13,
    -15,
    -15,
    -15,
    -15,
    -16,
    -18,
    -15,
    -18,
    -16,
    -15,
    -16,
    -19,
    -18,
    -19,
    -19,
    -21,
    -19,
    -22,
    -20,
    -24,
    -25,
    -24,
    -24,
    -24,
    -26,
    -27,
    -27,
    -29,
    -27,
    -24,
    -26,
    -25,
    -27,
    -27,
    -26,
    -28,
    -26,
    -31,
]


def test_the_intervals_hold_their_own_estimates_on_a_corridor_recording() -> None:
    """The bootstrap once drew its blocks only where a whole block fits, so the readings at
    the start distance were never drawn: L0 -13.3 [-12.9 .. -9.1], n 1.60 [1.72 .. 2.36]."""
    fit = fit_path_loss(CORRIDOR_DISTANCE_M, [float(v) for v in CORRIDOR_RSSI_DBM])
    assert fit.l0_dbm in fit.l0_ci, (fit.l0_dbm, fit.l0_ci)
    assert fit.n in fit.n_ci, (fit.n, fit.n_ci)
    assert fit.sigma_db in fit.sigma_ci


def test_a_flat_fit_is_refused_and_no_distance_divides_by_zero() -> None:
    d = [1.0 + 0.5 * i for i in range(40)]
    with pytest.raises(FitError, match="does not fall with distance"):
        fit_path_loss(d, [-55.0] * 40)
    with pytest.raises(FitError, match="does not fall with distance"):
        fit_path_loss(d, [-55.0 + 0.1 * i for i in range(40)])  # rising: n < 0
    flat = PathLossFit.known(-40.0, 2.0, 1.0)
    flat = dataclasses.replace(flat, n=0.0)
    with pytest.raises(FitError):
        flat.distance_at(-70.0)


def test_distances_past_twice_the_drive_are_not_given_as_figures() -> None:
    d = [1.0 + 0.25 * i for i in range(40)]  # 1 .. 10.75 m
    fit = fit_path_loss(d, [-30.0 - 20.0 * math.log10(x) for x in d])
    assert fit.measured_distance_at(fit.rssi_at(20.0)) == pytest.approx(20.0)
    assert fit.measured_distance_at(fit.rssi_at(30.0)) is None
    assert fit.measured_distance_at(-400.0) is None  # no overflow
