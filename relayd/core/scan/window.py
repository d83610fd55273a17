"""How wide the next sweep is: the adaptive window's sizing and the scanner's clock.

`relayd.core.scan.leader.TrackingModel.window` decides whether a sweep may be narrowed (a
confident filter, a known beamwidth); `sized_window` here says how much: a few
beamwidths plus a few standard deviations of the predicted bearing, at the full
window's spacing while the bearing is steady, coarser while it moves, in steps fitted
to the scanner's clock (`clocked_step_deg`). `Window` is the sweep both speak of, and
`relayd.core.scan.plan` turns it into servo targets.

Pure: the filter's prediction, the beamwidth and the last sweep's duration come in as
arguments; no clock, no I/O, no memory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from relayd.core.scan.tracker import Track


@dataclass(frozen=True, slots=True)
class WindowParams:
    """How the adaptive window sizes itself."""

    #: The window spans this many (learned) 3 dB beamwidths: the fit needs both flanks ...
    beams: float = 1.5
    #: ... plus this many standard deviations of the predicted bearing on each side.
    sigmas: float = 3.0
    min_samples: int = 9
    #: While the bearing moves faster than this (deg/s), the sweep is for speed: this many
    #: beamwidths at this many samples per beamwidth (never finer than the full window's
    #: spacing), so a wide antenna too sweeps in well under half the full window's time.
    #: While it is steadier, the sweep is for accuracy: the full window's spacing, every
    #: sample of the lobe, which the scan pool averages.
    moving_rate_deg_s: float = 2.0
    moving_beams: float = 1.2
    per_beamwidth: float = 8.0
    #: The scanner's step-mode clock (`clocked_step_deg`): servo slew (deg/s), settle (s),
    #: the RSSI reading's period (s); None: unknown (continuous mode), steps as planned.
    servo_deg_s: float | None = None
    settle_s: float = 0.0
    sample_period_s: float | None = None
    #: A step is stretched to at most this times, or shrunk to no less than this
    #: fraction of, the one planned when that sweeps faster.
    max_stretch: float = 1.25
    min_fraction: float = 0.75


@dataclass(frozen=True, slots=True)
class Window:
    centre_deg: float
    width_deg: float
    samples: int


def sized_window(now: Track, bw: float, sweep_s: float, full: Window, wp: WindowParams) -> Window:
    """The adaptive window around the filter's prediction `now`, for a lobe `bw` deg wide
    and a last sweep of `sweep_s` s, inside the servo's range (`full`)."""
    spacing = full.width_deg / max(1, full.samples - 1)
    beams = wp.beams
    if abs(now.rate_deg_s) > wp.moving_rate_deg_s:
        spacing, beams = max(spacing, bw / wp.per_beamwidth), wp.moving_beams
    spacing = clocked_step_deg(spacing, wp)
    # Half a sweep from now the leader will have moved on by the rate.
    centre = now.bearing_deg + now.rate_deg_s * sweep_s / 2.0
    half = (beams * bw + 2.0 * wp.sigmas * now.sd_deg) / 2.0
    # Clipped at the servo limits, not shifted inside them: beyond a limit there is no
    # lobe to see, and samples on the far side of the window would only cost time.
    lo_lim, hi_lim = full.centre_deg - full.width_deg / 2.0, full.centre_deg + full.width_deg / 2.0
    lo, hi = max(lo_lim, centre - half), min(hi_lim, centre + half)
    samples = max(wp.min_samples, math.ceil((hi - lo) / spacing) + 1)
    if samples >= full.samples:
        return Window(full.centre_deg, full.width_deg, full.samples)
    width = (samples - 1) * spacing
    mid = min(max((lo + hi) / 2.0, lo_lim + width / 2.0), hi_lim - width / 2.0)
    return Window(mid, width, samples)


def clocked_step_deg(step_deg: float, wp: WindowParams) -> float:
    """The servo step near `step_deg` that sweeps fastest on the scanner's clock.

    In step mode a sample costs the servo's travel plus the settle time, rounded up to
    the next RSSI reading: with k readings per sample the step can be up to
    (k T - settle) x slew, and any finer step takes as long. So among those steps, from
    `min_fraction` to `max_stretch` times the one asked for, the fastest (deg/s) is
    taken; the step asked for when none is faster or the timing is unknown. With
    relayd's defaults (180 deg/s, 50 ms settle, 20 Hz): 7.5 and 11.25 deg steps both
    sweep at 75 deg/s, 9 deg ones at 90.
    """
    if wp.sample_period_s is None or wp.servo_deg_s is None or step_deg <= 0.0:
        return step_deg
    period, slew = wp.sample_period_s, wp.servo_deg_s

    def speed(step: float) -> float:
        readings = max(1, math.ceil((step / slew + wp.settle_s) / period - 1e-9))
        return step / (readings * period)

    best, best_speed = step_deg, speed(step_deg)
    k = 1
    while (step := (k * period - wp.settle_s) * slew) <= wp.max_stretch * step_deg:
        if step >= wp.min_fraction * step_deg and speed(step) > best_speed + 1e-9:
            best, best_speed = step, speed(step)
        k += 1
    return best
