"""bench/lobebound.py: the oracle and the two-point bound behind docs/CONTROL.md 10.8."""

from __future__ import annotations

import numpy as np
import pytest

from bench.lobebound import (
    ANGLES_DEG,
    SCANS,
    Lobe,
    _probs,
    class_bank,
    oracle,
    readings,
    templates,
    total_variation,
)


def test_a_reading_is_whole_db_within_one_of_the_mean_and_its_law_sums_to_one() -> None:
    mean = np.array([-60.3, -61.5, -70.0, -59.99])
    r = readings(mean, np.random.default_rng(0), scans=2000)
    assert np.all(r == np.round(r)) and np.all(np.abs(r - mean) <= 1.5)
    ks = np.arange(-75.0, -55.0)
    p = _probs(mean, ks)
    assert np.allclose(p.sum(axis=1), 1.0)
    # The law matches the draws: the share of each whole dB, within sampling error.
    for i in range(mean.size):
        seen = np.array([np.mean(r[:, i] == k) for k in ks])
        assert np.abs(seen - p[i]).max() < 0.04


def test_identical_lobes_cannot_be_told_apart_and_far_ones_can() -> None:
    a = Lobe("cos^n", 60.0, 20.0).gains(80.0)
    assert total_variation(a, a, draws=2000) == pytest.approx(0.0)
    far = Lobe("cos^n", 60.0, 20.0).gains(40.0)
    assert total_variation(a, far, draws=2000) > 0.999


def test_the_monte_carlo_tv_matches_exact_enumeration() -> None:
    """One servo angle, five scans: few enough outcomes to sum the TV exactly."""
    import itertools

    a, b = np.array([-60.3]), np.array([-59.6])
    ks = np.arange(-64.0, -55.0)
    pa, pb = _probs(a, ks)[0], _probs(b, ks)[0]
    exact = 0.5 * sum(
        abs(np.prod(pa[list(o)]) - np.prod(pb[list(o)]))
        for o in itertools.product(range(ks.size), repeat=SCANS)
    )
    assert 0.2 < exact < 0.9
    assert total_variation(a, b, draws=200_000, seed=3) == pytest.approx(exact, abs=0.01)


def test_the_documented_pair_is_ten_degrees_apart_yet_hard_to_tell() -> None:
    """docs/CONTROL.md 10.8: any estimator is beyond 5 deg on one of these two lobes in
    at least a few percent of draws (Le Cam: (1 - TV) / 2)."""
    a = Lobe("flat-top", 70.0, 10.0).gains(72.0)
    b = Lobe("flat-top", 90.0, 10.0).gains(83.5)
    b = b + (a - b).mean()
    assert np.sqrt(((a - b - (a - b).mean()) ** 2).mean()) < 0.2
    tv = total_variation(a, b, draws=20_000, seed=1)
    assert (1.0 - tv) / 2.0 > 0.03


def test_the_oracle_finds_a_clean_lobe_of_the_class_exactly() -> None:
    bank = [lobe for lobe in class_bank() if lobe.depth_db == 20.0]
    grid = np.arange(60.0, 85.01, 0.5)
    tmpl = templates(bank, grid)
    for lobe, b in ((Lobe("gaussian", 60.0, 20.0), 70.0), (Lobe("flat-top", 90.0, 20.0), 84.5)):
        clean = np.repeat(lobe.gains(b)[None, :] - 55.0, 5, axis=0)
        assert oracle(tmpl, grid, clean) == b
    assert ANGLES_DEG.size == 25
