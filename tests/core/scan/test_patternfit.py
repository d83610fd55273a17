"""The bearing fit with a measured pattern: every antenna shape, the servo's reach, honest sd."""

from __future__ import annotations

import math
import random

import pytest

from relayd.core.scan.bearing import fit_main_lobe
from relayd.core.scan.patternfit import fit_pattern
from relayd.sim.antennas import FAMILY, family_pattern

FULL = [-90.0 + 7.5 * i for i in range(25)]


def _scan(name: str, bearing: float, rng: random.Random, angles: list[float] = FULL) -> list[float]:
    """Whole-dB readings with +-1 dB of jitter, as real adapters report."""
    g = FAMILY[name]
    return [float(round(-50.0 + g(bearing - a) + rng.uniform(-1.0, 1.0))) for a in angles]


@pytest.mark.parametrize("name", list(FAMILY))
def test_one_scan_finds_the_leader_with_every_pattern(name: str) -> None:
    rng = random.Random(7)
    pattern = family_pattern(name)
    worst = 0.0
    for b in range(-85, 86, 10):
        fit = fit_pattern(FULL, _scan(name, b, rng), pattern)
        assert fit is not None
        worst = max(worst, abs(fit.bearing_deg - b))
    # One scan, quantized jitter: a few degrees at most, wherever the leader is.
    assert worst <= 4.0, worst


def test_side_lobes_and_squint_do_not_capture_where_the_parabola_is_fooled() -> None:
    rng = random.Random(3)
    worst_pattern = worst_parabola = 0.0
    for name in ("yagi", "asymmetric"):
        for b in range(-85, 86, 10):
            ys = _scan(name, b, rng)
            fit = fit_pattern(FULL, ys, family_pattern(name))
            lobe = fit_main_lobe(FULL, ys)
            assert fit is not None
            worst_pattern = max(worst_pattern, abs(fit.bearing_deg - b))
            worst_parabola = max(
                worst_parabola, math.inf if lobe is None else abs(lobe.bearing_deg - b)
            )
    assert worst_pattern <= 3.0
    assert worst_parabola > 8.0  # what the pattern file is for


def test_a_narrow_window_is_not_taken_for_the_back_lobe() -> None:
    # The Yagi's back lobe has its main lobe's shape, 15 dB down: in a 72 deg window the
    # scan alone cannot tell them apart, so the fit searches no further than a beamwidth
    # beyond the window.
    rng = random.Random(5)
    for b in (-35.0, 5.0, 45.0):
        window = [b - 36.0 + 9.0 * i for i in range(9)]
        fit = fit_pattern(window, _scan("yagi", b, rng, window), family_pattern("yagi"))
        assert fit is not None and abs(fit.bearing_deg - b) < 3.0


@pytest.mark.parametrize("b", [110.0, -125.0])
def test_a_leader_beyond_the_servo_is_reported_beyond_it(b: float) -> None:
    fit = fit_pattern(FULL, _scan("yagi", b, random.Random(1)), family_pattern("yagi"))
    assert fit is not None and fit.extrapolated
    assert abs(fit.bearing_deg - b) < 3.0  # where it is, not at the limit (+-90)


def test_a_flat_scan_gives_no_bearing() -> None:
    rng = random.Random(2)
    ys = [float(round(-70.0 + rng.uniform(-1.0, 1.0))) for _ in FULL]
    assert fit_pattern(FULL, ys, family_pattern("yagi")) is None


def test_the_sd_is_honest() -> None:
    # The errors, in units of the fit's own sd, have an RMS near 1 (not 0.2, not 5).
    rng = random.Random(11)
    z = []
    for name in ("builtin", "shallow", "yagi", "patch"):
        pattern = family_pattern(name)
        for _ in range(15):
            b = rng.uniform(-80.0, 80.0)
            fit = fit_pattern(FULL, _scan(name, b, rng), pattern)
            assert fit is not None
            z.append((fit.bearing_deg - b) / fit.sd_deg)
    rms = math.sqrt(sum(x * x for x in z) / len(z))
    assert 0.3 < rms < 1.6, rms


def test_scans_fitted_together_share_the_bearing() -> None:
    rng = random.Random(4)
    pattern = family_pattern("shallow")
    angles: list[float] = []
    ys: list[float] = []
    ids: list[int] = []
    for k, level in enumerate((-50.0, -58.0, -45.0)):  # each scan at its own level
        angles += FULL
        ys += [y + 50.0 + level for y in _scan("shallow", 62.0, rng)]
        ids += [k] * len(FULL)
    one = fit_pattern(FULL, ys[:25], pattern)
    pooled = fit_pattern(angles, ys, pattern, scan_ids=ids, around_deg=62.0)
    assert one is not None and pooled is not None
    assert abs(pooled.bearing_deg - 62.0) < 2.0
    assert pooled.sd_deg < one.sd_deg
    assert pooled.peak_dbm == pytest.approx(-45.0, abs=1.5)  # the newest scan's level
