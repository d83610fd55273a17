"""Scan efficiency: measured scan period over its physical minimum, and theorem 1's speed limit.

`relayd run` (subprocess) sweeps the FakeRig's Maestro (which slews at the commanded
speed) and reads its RSSI file; the robot is in hold mode so it does not turn under
the scan. The period is the interval between consecutive scan completions
(`last_scan.t` in /status, the daemon's own clock), polled every 20 ms; the first two
scans are skipped (the first starts from an unknown servo position).

Physical minimum (as the target defines it): the servo slew over the window at the configured speed plus
one RSSI sample period per step, i.e. width/speed + N/sample_hz in step mode. In
continuous mode the samples are taken during the slew, so its minimum is
width/speed + one sample period (for the last sample). Step mode waits `settle_s`
(default 50 ms) after each step for the Yagi to stop swinging; that wait is not in the
physical minimum, so the default step scan cannot reach 1.1 by construction; the
benchmark also runs it with settle_s = 0 to show the scanner's own overhead.

Theorem 1 of the paper (section "Tracking"): with the antenna's angular scanning
speed theta_dot, the leader-follower distance d and the maximum scanning angle
theta_max, the DOA can be tracked if V_relative <= theta_dot * d / theta_max, or the
leader's perpendicular speed V_perp <= theta_dot * d + theta_max * V_relative. With
the measured effective scan speed theta_dot = window / period and theta_max = the
window (pi rad), the first bound is d / period.
"""

from __future__ import annotations

import asyncio
import itertools
import math
import tempfile
from pathlib import Path
from typing import Any

import aiohttp

from bench.common import BenchOutput, Result
from bench.live import RelaydProcess
from relayd.fakes.rig import FakeRig
from relayd.sim.runner import scratch_root

NAME = "scan"
TARGET_RATIO = 1.1
#: Leader-follower distance theorem 1's bound is printed for (the convoy scenario's spacing).
CONVOY_SPACING_M = 1.6


def physical_min_s(
    mode: str, width_deg: float, speed_deg_s: float, samples: int, sample_hz: float
) -> float:
    slew = width_deg / speed_deg_s
    if mode == "continuous":
        return slew + 1.0 / sample_hz
    return slew + samples / sample_hz


def grid_min_s(
    width_deg: float, speed_deg_s: float, samples: int, sample_hz: float, settle_s: float
) -> float:
    """Step mode's real lower bound: each step's travel + settle, rounded up to the RSSI sample grid.

    Sweeps alternate direction, so the first step has no travel. The target's formula adds a
    whole sample period to every step's travel; when a step's travel is shorter than a
    sample period the two overlap, and a scanner can beat that formula.
    """
    period = 1.0 / sample_hz
    travel = width_deg / max(1, samples - 1) / speed_deg_s

    def on_grid(wait_s: float) -> float:
        return period * max(1, math.ceil(wait_s / period - 1e-9))

    return on_grid(settle_s) + (samples - 1) * on_grid(travel + settle_s)


def theorem1(period_s: float, width_deg: float, d_m: float) -> tuple[float, float]:
    """(max relative speed, max perpendicular leader speed at V_rel = 0), m/s."""
    theta_dot = math.radians(width_deg) / period_s
    theta_max = math.radians(width_deg)
    return theta_dot * d_m / theta_max, theta_dot * d_m


async def measure_mode(
    mode: str,
    *,
    scans: int,
    settle_s: float | None = None,
    samples: int = 25,
    width_deg: float = 180.0,
    work: Path | None = None,
) -> dict[str, Any]:
    scan_cfg: dict[str, Any] = {"mode": mode, "samples": samples, "width_deg": width_deg}
    if settle_s is not None:
        scan_cfg["settle_s"] = settle_s
    with tempfile.TemporaryDirectory(prefix="relayd-bench-scan-", dir=scratch_root()) as tmp:
        rig = FakeRig(work or Path(tmp))
        await rig.start()
        try:
            async with RelaydProcess(
                rig, scan=scan_cfg, control={"mode": "hold"}, log={"level": "warning"}
            ) as relayd:
                times: list[float] = []
                periods: list[float] = []
                counts: list[int] = []
                last_t: float | None = None
                async with aiohttp.ClientSession() as session, asyncio.timeout(60.0 + scans * 10.0):
                    while len(times) < scans + 2:
                        doc = await relayd.status(session)
                        scan = doc.get("last_scan")
                        if scan is not None and scan["t"] != last_t:
                            last_t = scan["t"]
                            times.append(float(scan["t"]))
                            periods.append(float(scan["period_s"] or math.nan))
                            counts.append(len(scan["angles"]))
                        await asyncio.sleep(0.02)
        finally:
            await rig.stop()
    intervals = [b - a for a, b in itertools.pairwise(times[2:])]
    # Polling every 20 ms can miss no scan (a scan takes > 1 s), so consecutive = consecutive.
    return {
        "mode": mode,
        "intervals": intervals,
        "scanner_periods": periods[2:],
        "samples": counts[2:],
    }


def run(quick: bool = False, *, scans: int | None = None, samples: int = 25) -> BenchOutput:
    n = scans if scans is not None else (3 if quick else 10)
    out = BenchOutput(NAME)
    # Config defaults the minimum is computed from.
    width, speed, hz, default_settle = 180.0, 180.0, 20.0, 0.05
    cases = [
        ("step", None, "step, settle_s 0.05 (default)"),
        ("step", 0.0, "step, settle_s 0"),
        ("continuous", None, "continuous"),
    ]
    for mode, settle, label in cases:
        data = asyncio.run(measure_mode(mode, scans=n, settle_s=settle, samples=samples))
        iv = data["intervals"]
        period = sum(iv) / len(iv) if iv else math.nan
        pmin = physical_min_s(mode, width, speed, samples, hz)
        ratio = period / pmin
        settle_used = default_settle if settle is None else settle
        note = (
            (
                f"{len(iv)} scans, period {period:.3f} s (min {min(iv):.3f}, max {max(iv):.3f}), "
                f"physical min {pmin:.3f} s, {sum(data['samples']) / max(1, len(data['samples'])):.1f} "
                f"samples/scan"
            )
            if iv
            else "no scans"
        )
        if mode == "step" and iv:
            grid = grid_min_s(width, speed, samples, hz, settle_used)
            note += (
                f"; against the sample-grid minimum incl. settle ({grid:.3f} s) the ratio is "
                f"{period / grid:.3f}"
            )
        out.results.append(
            Result(
                NAME,
                f"scan period / physical min, {label}",
                ratio,
                "",
                f"<= {TARGET_RATIO:g}",
                ratio <= TARGET_RATIO if iv else None,
                note,
            )
        )
        if mode == "continuous" or (mode == "step" and settle is None):
            v_rel, v_perp = theorem1(period, width, CONVOY_SPACING_M)
            out.results.append(
                Result(
                    NAME,
                    f"theorem 1 max V_relative at d={CONVOY_SPACING_M:g} m, {mode}",
                    v_rel,
                    "m/s",
                    "",
                    None,
                    f"= d/period; {v_rel / CONVOY_SPACING_M:.3f} m/s per metre of separation; "
                    f"V_perp <= {v_perp:.2f} m/s at V_rel = 0",
                )
            )
    out.details.append(
        "Scan settings: width 180 deg, 25 samples, servo 180 deg/s, RSSI 20 Hz "
        "(config defaults); real clock."
    )
    return out
