"""The main-lobe fit (relayd.core.scan.bearing): no pull toward the window's middle, any antenna."""

from __future__ import annotations

import math
import random
from fractions import Fraction

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.brainrig import cos_n_pattern, gaussian_pattern
from relayd.core.scan.bearing import fit_main_lobe
from relayd.core.scan.estimator import plan_scan, wca_bearing

FULL = plan_scan(0.0, 180.0, 25, (-90.0, 90.0), True)
patterns = st.sampled_from([cos_n_pattern, gaussian_pattern])


def scan(
    pattern: object,
    bearing: float,
    angles: tuple[float, ...] = FULL,
    level: float = -50.0,
    jitter_db: float = 0.0,
    rng: random.Random | None = None,
) -> list[float]:
    out = []
    for a in angles:
        noise = rng.uniform(-jitter_db, jitter_db) if rng is not None else 0.0
        out.append(level + pattern(a - bearing) + noise)  # type: ignore[operator]
    return out


@settings(max_examples=300, deadline=None)
@given(
    make=patterns,
    beamwidth=st.floats(30.0, 60.0),
    ftb=st.floats(12.0, 30.0),
    bearing=st.floats(-85.0, 85.0),
)
def test_noise_free_any_antenna_any_bearing_within_4_degrees(make, beamwidth, ftb, bearing) -> None:
    pattern = make(beamwidth, ftb)
    fit = fit_main_lobe(FULL, scan(pattern, bearing))
    assert fit is not None
    assert abs(fit.bearing_deg - bearing) <= 4.0
    # ... where the centroid of the same scan is pulled toward the middle near the limits.
    if abs(bearing) >= 80.0 and ftb <= 15.0:
        assert abs(wca_bearing(FULL, scan(pattern, bearing), 10.0) - bearing) > 10.0


@settings(max_examples=200, deadline=None)
@given(make=patterns, beamwidth=st.floats(30.0, 60.0), bearing=st.floats(-85.0, 85.0))
def test_with_the_learned_beamwidth_a_lobe_cut_by_the_servo_limit_is_within_1_degree(
    make, beamwidth, bearing
) -> None:
    fit = fit_main_lobe(FULL, scan(make(beamwidth, 20.0), bearing), beamwidth_prior_deg=beamwidth)
    assert fit is not None and abs(fit.bearing_deg - bearing) <= 1.5


@settings(max_examples=200, deadline=None)
@given(
    offset=st.floats(-40.0, 40.0),
    shift=st.floats(-20.0, 20.0),
    bearing=st.floats(-40.0, 40.0),
    beamwidth=st.floats(30.0, 60.0),
)
def test_level_does_not_matter_and_rotating_the_scene_rotates_the_answer(
    offset, shift, bearing, beamwidth
) -> None:
    pattern = cos_n_pattern(beamwidth, 20.0)
    base = fit_main_lobe(FULL, scan(pattern, bearing))
    louder = fit_main_lobe(FULL, scan(pattern, bearing, level=-50.0 + offset))
    angles = tuple(a + shift for a in FULL)
    turned = fit_main_lobe(angles, scan(pattern, bearing + shift, angles))
    assert base is not None and louder is not None and turned is not None
    assert louder.bearing_deg == pytest.approx(base.bearing_deg, abs=1e-6)
    assert turned.bearing_deg == pytest.approx(base.bearing_deg + shift, abs=1e-6)
    assert louder.peak_dbm == pytest.approx(base.peak_dbm + offset, abs=1e-6)


@pytest.mark.parametrize("beamwidth", [30.0, 45.0, 60.0])
@pytest.mark.parametrize("ftb", [12.0, 30.0])
def test_two_db_jitter_costs_a_few_degrees_and_the_sd_says_so(beamwidth: float, ftb: float) -> None:
    rng = random.Random(int(beamwidth * 100 + ftb))
    pattern = cos_n_pattern(beamwidth, ftb)
    errors, z = [], []
    for bearing in range(-60, 61, 10):
        for _ in range(15):
            fit = fit_main_lobe(
                FULL, scan(pattern, bearing, jitter_db=2.0, rng=rng), beamwidth_prior_deg=beamwidth
            )
            assert fit is not None
            errors.append(fit.bearing_deg - bearing)
            z.append((fit.bearing_deg - bearing) / fit.sd_deg)
    rms = math.sqrt(sum(e * e for e in errors) / len(errors))
    assert rms <= 3.5
    # The reported sd is the right size (not off by a factor of 2 either way).
    assert 0.5 <= math.sqrt(sum(x * x for x in z) / len(z)) <= 2.0


def test_no_lobe_no_bearing() -> None:
    assert fit_main_lobe(FULL, [-60.0] * len(FULL)) is None  # flat: nothing heard in any direction
    assert fit_main_lobe(FULL, [-60.0 + 0.01 * a * a for a in FULL]) is None  # a valley, not a lobe
    assert fit_main_lobe((0.0, 10.0), (-50.0, -51.0)) is None  # too few samples


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError):
        fit_main_lobe((0.0, 1.0, 2.0), (-50.0, -51.0))
    with pytest.raises(ValueError):
        fit_main_lobe((0.0, 1.0, math.nan), (-50.0, -51.0, -52.0))
    with pytest.raises(ValueError):
        fit_main_lobe(FULL, scan(cos_n_pattern(45.0, 20.0), 0.0), beamwidth_prior_deg=0.0)


def test_a_leader_beyond_the_servo_limit_is_extrapolated_but_bounded() -> None:
    fit = fit_main_lobe(FULL, scan(cos_n_pattern(45.0, 20.0), 100.0), beamwidth_prior_deg=45.0)
    assert fit is not None and fit.extrapolated and 92.0 <= fit.bearing_deg <= 110.0
    far = fit_main_lobe(FULL, scan(cos_n_pattern(45.0, 20.0), 170.0))
    assert far is None or far.bearing_deg <= 90.0 + 20.0


@settings(max_examples=150, deadline=None)
@given(
    make=patterns,
    beamwidth=st.floats(30.0, 60.0),
    bearing=st.floats(-85.0, 85.0),
    levels=st.lists(st.floats(-15.0, 15.0), min_size=2, max_size=5),
)
def test_scans_fitted_together_each_keep_their_level(make, beamwidth, bearing, levels) -> None:
    # The same lobe heard at different levels (the leader nearer, other shadowing) is the
    # same lobe: the scans' levels do not move the pooled bearing, the peak is the newest
    # scan's, and the pooled fit is as good as one scan's (noise-free).
    pattern = make(beamwidth, 20.0)
    ids = [k for k in range(len(levels)) for _ in FULL]
    flat = fit_main_lobe(FULL * len(levels), scan(pattern, bearing) * len(levels), scan_ids=ids)
    pooled = fit_main_lobe(
        FULL * len(levels),
        [x for lv in levels for x in scan(pattern, bearing, level=-50.0 + lv)],
        scan_ids=ids,
    )
    assert flat is not None and pooled is not None
    assert pooled.bearing_deg == pytest.approx(flat.bearing_deg, abs=1e-6)
    assert pooled.peak_dbm == pytest.approx(flat.peak_dbm + levels[-1], abs=1e-6)
    assert abs(pooled.bearing_deg - bearing) <= 4.0


def test_five_faded_scans_fitted_together_beat_five_fits_averaged_at_a_servo_limit() -> None:
    # A 90 deg lobe at +60 deg is cut by the +90 deg limit; under 3 dB of jitter one scan's
    # curvature is poorly seen, and the fits that claim the sharpest lobe (the smallest
    # sd) are the ones pulled toward the samples: a weighted mean of single fits is biased.
    rng = random.Random(7)
    pattern = cos_n_pattern(90.0, 20.0)
    single_err, pooled_err = [], []
    for _ in range(60):
        scans = [[x + rng.gauss(0.0, 3.0) for x in scan(pattern, 60.0)] for _ in range(5)]
        fits = [f for f in (fit_main_lobe(FULL, s) for s in scans) if f is not None]
        w = [1.0 / f.sd_deg**2 for f in fits]
        single_err.append(
            sum(f.bearing_deg * x for f, x in zip(fits, w, strict=True)) / sum(w) - 60.0
        )
        pooled = fit_main_lobe(
            FULL * 5, [x for s in scans for x in s], scan_ids=[k for k in range(5) for _ in FULL]
        )
        assert pooled is not None
        pooled_err.append(pooled.bearing_deg - 60.0)

    def rms(xs: list[float]) -> float:
        return math.sqrt(sum(x * x for x in xs) / len(xs))

    assert rms(pooled_err) < 0.75 * rms(single_err)
    assert abs(sum(pooled_err) / len(pooled_err)) < 1.5


def test_scan_ids_must_match_the_samples() -> None:
    with pytest.raises(ValueError):
        fit_main_lobe(FULL, scan(cos_n_pattern(45.0, 20.0), 0.0), scan_ids=[0, 1])


@settings(max_examples=200, deadline=None)
@given(
    rows=st.lists(
        st.tuples(
            st.floats(-90.0, 90.0), st.floats(-90.0, -20.0), st.floats(0.1, 1.0), st.integers(0, 3)
        ),
        min_size=6,
        max_size=60,
    ),
    prior=st.one_of(st.none(), st.tuples(st.floats(-0.01, -0.0001), st.floats(0.0, 1e4))),
)
def test_the_closed_forms_solve_the_normal_equations(rows, prior) -> None:
    # The scan end's fits use a closed-form 3x3 inverse and one-pass pooled sums; both
    # against the equations written out plainly.
    from relayd.core.scan.bearing import _inverse_sym3, _wls_pooled

    us, ys, ws, gs = (list(x) for x in zip(*rows, strict=True))
    s = [sum(w * u**k for u, w in zip(us, ws, strict=True)) for k in range(5)]
    inv = _inverse_sym3(*s)
    if inv is not None:
        # Against the exact inverse of the same floats (rational arithmetic). The adjugate's
        # rounding is bounded by the terms each cofactor and the determinant cancel: a few
        # ulps of those, relative to what is left (an ill-conditioned draw cancels 1e10).
        q = [Fraction(v) for v in s]
        cof = {
            (0, 0): (q[2] * q[4], q[3] * q[3]),
            (0, 1): (q[2] * q[3], q[1] * q[4]),
            (0, 2): (q[1] * q[3], q[2] * q[2]),
            (1, 1): (q[0] * q[4], q[2] * q[2]),
            (1, 2): (q[1] * q[2], q[0] * q[3]),
            (2, 2): (q[0] * q[2], q[1] * q[1]),
        }
        det = q[0] * (cof[0, 0][0] - cof[0, 0][1]) + q[1] * (cof[0, 1][0] - cof[0, 1][1])
        det += q[2] * (cof[0, 2][0] - cof[0, 2][1])
        det_terms = sum(
            abs(q[k]) * (abs(a) + abs(b))
            for k, (a, b) in enumerate((cof[0, 0], cof[0, 1], cof[0, 2]))
        )
        eps = Fraction(2) ** -52
        for (i, j), (a, b) in cof.items():
            exact = (a - b) / det
            slack = 8 * eps * ((abs(a) + abs(b)) / abs(det) + (det_terms / abs(det)) * abs(exact))
            err = abs(Fraction(inv[i][j]) - exact)
            assert err <= slack, (i, j, float(err), float(slack))
            assert inv[j][i] == inv[i][j]
    # Pooled: (b, c) minimise the weighted squares with one free level per scan.
    fit = _wls_pooled(us, ys, ws, prior, gs)
    groups = sorted(set(gs))
    cent = {
        g: [
            sum(w * u for u, w, h in zip(us, ws, gs, strict=True) if h == g),
            sum(w * u * u for u, w, h in zip(us, ws, gs, strict=True) if h == g),
            sum(w * y for y, w, h in zip(ys, ws, gs, strict=True) if h == g),
            sum(w for w, h in zip(ws, gs, strict=True) if h == g),
        ]
        for g in groups
    }
    m00 = m01 = m11 = r0 = r1 = 0.0
    for u, y, w, g in zip(us, ys, ws, gs, strict=True):
        su, sv, sy, sw = cent[g]
        du, dv, dy = u - su / sw, u * u - sv / sw, y - sy / sw
        m00, m01, m11 = m00 + w * du * du, m01 + w * du * dv, m11 + w * dv * dv
        r0, r1 = r0 + w * du * dy, r1 + w * dv * dy
    if prior is not None:
        m11, r1 = m11 + prior[1], r1 + prior[1] * prior[0]
    det = m00 * m11 - m01 * m01
    if fit is None or abs(det) < 1e-6 * max(1.0, m00 * m11):
        return  # (near) singular: nothing to compare
    _, b, c = fit[0]
    assert b == pytest.approx((m11 * r0 - m01 * r1) / det, rel=1e-6, abs=1e-9)
    assert c == pytest.approx((m00 * r1 - m01 * r0) / det, rel=1e-6, abs=1e-9)
