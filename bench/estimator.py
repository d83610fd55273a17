"""Estimator: bearing error after 5 scans to a static leader, noise-free and with noise.

Pure code only: `relayd.core.scan.estimator` (plan_scan, estimate_scan: the WCA the daemon runs)
fed by `relayd.sim.radio` (log-distance path loss, the Yagi's cos^2 pattern floored at
-20 dB, shadowing, Rician/Rayleigh fast fading averaged over 4 frames). The robot and
the leader stand still 5 m apart outdoors (L0 -20 dBm, n 2.5); each scan's window is
centred on the previous estimate (the first on the "start" angle), 25 samples, width
180 deg, servo limits +-90 deg, gamma 10: the config defaults. The error is the 5th
estimate minus the true bearing.

Two set-ups. Closed loop, the judged figure: the relay does what relayd does between
scans, turning in place toward its newest bearing (the PD wheel law at v = 0 with the
default kp/kd, through the P3-AT's DiffConvFactor; the servo takes 0.1 s a step), and
the error is the last bearing against the leader's direction in the robot's frame at
that moment. Open loop: the robot does not turn, so the window always spans the whole
servo range and the WCA's pull toward the middle of it shows undiluted; reported to
show where that bias starts.

Noise-free: every true bearing in -90..90 (5 deg steps) from every start in -90..90
(15 deg steps). With noise: true bearings -60..60 (10 deg steps), start 0, many seeds
(each seed a different shadowing field and fading sequence); RMS of the error. Note
that for a static pair shadowing adds the same dB to every sample of a scan, and the
WCA's weights are normalised to the scan's best sample, so shadowing alone cannot move
the bearing; fast fading does.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from bench.common import BenchOutput, Result, rms
from drivers.arcos.sip import DIFF_CONV_FACTOR
from relayd.core.control.law import wheel_law
from relayd.core.scan.estimator import (
    EstimatorParams,
    ScanSample,
    estimate_scan,
    front_readings,
    plan_scan,
)
from relayd.sim.radio import Radio, RadioParams, yagi_gain_db

NAME = "estimator"
TARGET_DEG = 5.0
SCANS = 5
DISTANCE_M = 5.0


def error_after(
    radio: Radio,
    true_deg: float,
    start_deg: float,
    *,
    scans: int = SCANS,
    width_deg: float = 180.0,
    samples: int = 25,
    gamma: float = 10.0,
    limits: tuple[float, float] = (-90.0, 90.0),
) -> float:
    """Bearing error (deg) of the `scans`-th scan to a static leader at `true_deg`."""
    params = EstimatorParams(gamma=gamma)
    no_sonar = front_readings([None] * 16)
    leader = (
        DISTANCE_M * math.cos(math.radians(true_deg)),
        DISTANCE_M * math.sin(math.radians(true_deg)),
    )
    center, ascending = start_deg, True
    for _ in range(scans):
        angles = plan_scan(center, width_deg, samples, limits, ascending)
        ascending = not ascending
        batch = [
            ScanSample(a, radio.sample_dbm((0.0, 0.0), leader, yagi_gain_db(a - true_deg)), 0.0)
            for a in angles
        ]
        center = estimate_scan(batch, 0.0, no_sonar, params).bearing_deg
    return center - true_deg


def closed_loop_error(
    radio: Radio,
    true_deg: float,
    start_deg: float,
    *,
    scans: int = SCANS,
    samples: int = 25,
    step_s: float = 0.1,
    kp: float = 1.0,
    kd: float = 0.3,
    v_max_mm_s: float = 400.0,
    limits: tuple[float, float] = (-90.0, 90.0),
) -> float:
    """Error (deg) of the `scans`-th bearing while the robot turns in place toward its estimate.

    The leader stands still at `true_deg` of the robot's initial heading. Between and
    during scans the robot yaws at the wheel law's rate, using the newest bearing
    corrected by odometry into the current frame, as relayd's control task does.
    """
    params = EstimatorParams()
    no_sonar = front_readings([None] * 16)
    leader = (
        DISTANCE_M * math.cos(math.radians(true_deg)),
        DISTANCE_M * math.sin(math.radians(true_deg)),
    )
    heading, center, ascending = 0.0, start_deg, True
    bearing: float | None = None
    prev: float | None = None
    heading_then = 0.0
    substeps = 5
    for _ in range(scans):
        angles = plan_scan(center, 180.0, samples, limits, ascending)
        ascending = not ascending
        batch = []
        for a in angles:
            for _ in range(substeps):
                if bearing is not None:
                    now = bearing - (heading - heading_then)
                    now_prev = None if prev is None else prev - (heading - heading_then)
                    left, right = wheel_law(0.0, now, now_prev, kp, kd, v_max_mm_s)
                    heading += (
                        math.degrees((right - left) / 2.0 * DIFF_CONV_FACTOR) * step_s / substeps
                    )
            off_axis = a + heading - true_deg
            batch.append(
                ScanSample(a, radio.sample_dbm((0.0, 0.0), leader, yagi_gain_db(off_axis)), heading)
            )
        est = estimate_scan(batch, heading, no_sonar, params)
        prev = None if bearing is None else bearing - (heading - heading_then)
        bearing, heading_then = est.bearing_deg, heading
        center = est.bearing_deg
    assert bearing is not None
    return math.remainder(bearing - (true_deg - heading), 360.0)


def noise_free(
    bearings: Iterable[float], starts: Iterable[float], **kw: Any
) -> dict[tuple[float, float], float]:
    radio = Radio(RadioParams.outdoor(fading=False, shadow_sigma_db=0.0), [], seed=0)
    starts = list(starts)
    return {(b, s): error_after(radio, b, s, **kw) for b in bearings for s in starts}


def noisy(bearings: Iterable[float], seeds: int, *, nlos: bool = False, **kw: Any) -> list[float]:
    errors = []
    bearings = list(bearings)
    for seed in range(seeds):
        # rician_k_db very low = Rayleigh fading (no dominant path), as behind a wall.
        params = RadioParams.outdoor(rician_k_db=-60.0) if nlos else RadioParams.outdoor()
        radio = Radio(params, [], seed=seed)
        errors += [error_after(radio, b, 0.0, **kw) for b in bearings]
    return errors


def run(
    quick: bool = False, *, seeds: int | None = None, step_deg: float | None = None
) -> BenchOutput:
    n_seeds = seeds if seeds is not None else (20 if quick else 200)
    step = step_deg if step_deg is not None else 5.0
    out = BenchOutput(NAME)
    bearings = [-90.0 + step * i for i in range(int(180 / step) + 1)]
    errs = noise_free(bearings, [-90.0 + 15.0 * i for i in range(13)])
    worst = max(errs.items(), key=lambda kv: abs(kv[1]))

    def band(limit: float) -> float:
        return max(abs(e) for (b, _s), e in errs.items() if abs(b) <= limit + 1e-9)

    radio = Radio(RadioParams.outdoor(fading=False, shadow_sigma_db=0.0), [], seed=0)
    closed = {
        (b, s0): closed_loop_error(radio, b, s0)
        for b in bearings
        for s0 in [-90.0 + 15.0 * i for i in range(13)]
    }
    cworst = max(closed.items(), key=lambda kv: abs(kv[1]))
    out.results.append(
        Result(
            NAME,
            "noise-free |error| after 5 scans, any bearing and start in -90..90, robot turning (closed loop)",
            abs(cworst[1]),
            "deg",
            f"<= {TARGET_DEG:g} deg",
            abs(cworst[1]) <= TARGET_DEG,
            f"{len(closed)} cases; worst at bearing {cworst[0][0]:g}, start {cworst[0][1]:g}",
        )
    )
    out.results.append(
        Result(
            NAME,
            "noise-free |error| after 5 scans, any bearing and start in -90..90, robot still (open loop)",
            abs(worst[1]),
            "deg",
            "",
            None,
            f"worst at bearing {worst[0][0]:g}, start {worst[0][1]:g}; max over |bearing| <= 30: {band(30):.1f}, "
            f"<= 45: {band(45):.1f}, <= 60: {band(60):.1f}, <= 75: {band(75):.1f}",
        )
    )
    out.results.append(
        Result(
            NAME,
            "noise-free |error| after 5 scans, |bearing| <= 45, robot still (open loop)",
            band(45),
            "deg",
            "",
            None,
            "shows where the WCA's pull toward the window's middle starts",
        )
    )
    noisy_b = [-60.0 + 10.0 * i for i in range(13)]
    los = noisy(noisy_b, n_seeds)
    nlos = noisy(noisy_b, max(1, n_seeds // 2), nlos=True)
    out.results.append(
        Result(
            NAME,
            "RMS error after 5 scans, shadowing + Rician fading (LOS)",
            rms(los),
            "deg",
            "",
            None,
            f"{len(los)} runs: {n_seeds} seeds x bearings -60..60",
        )
    )
    out.results.append(
        Result(
            NAME,
            "RMS error after 5 scans, shadowing + Rayleigh fading (NLOS)",
            rms(nlos),
            "deg",
            "",
            None,
            f"{len(nlos)} runs",
        )
    )
    bias = noise_free([b for b in (0.0, 30.0, 45.0, 60.0, 75.0, 90.0)], [0.0])
    out.details.append(
        "Noise-free error after 5 scans by true bearing (start 0): "
        + ", ".join(f"{b:g} deg: {e:+.1f}" for (b, _s), e in bias.items())
    )
    return out
