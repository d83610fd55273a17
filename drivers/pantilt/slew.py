"""The simulated servo's motion: a pulse width slewing to its target under the
controller's speed and acceleration limits, evaluated lazily at any clock time.

Used by the fake controllers (fake.py); pure arithmetic, no I/O and no clock of its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


def travelled_us(
    distance_us: float, elapsed_s: float, speed_us_s: float, accel_us_s2: float
) -> float:
    """How far a ramp that started at rest has gone after `elapsed_s` (0 = unlimited)."""
    d = distance_us
    if d <= 0:
        return 0.0
    if accel_us_s2 <= 0 and speed_us_s <= 0:
        # No limits: the controller reports the new target at once, however little
        # time passed (a virtual-time test asks in the same instant).
        return d
    if elapsed_s <= 0:
        return 0.0
    if accel_us_s2 <= 0:
        return d if speed_us_s <= 0 else min(d, speed_us_s * elapsed_s)
    a = accel_us_s2
    t_acc = math.inf if speed_us_s <= 0 else speed_us_s / a
    if a * t_acc * t_acc >= d:  # never reaches the speed limit: triangular profile
        t_half = math.sqrt(d / a)
        if elapsed_s < t_half:
            return 0.5 * a * elapsed_s**2
        if elapsed_s < 2 * t_half:
            return d - 0.5 * a * (2 * t_half - elapsed_s) ** 2
        return d
    v = speed_us_s
    d_acc = 0.5 * a * t_acc**2
    t_cruise = (d - 2 * d_acc) / v
    if elapsed_s < t_acc:
        return 0.5 * a * elapsed_s**2
    if elapsed_s < t_acc + t_cruise:
        return d_acc + v * (elapsed_s - t_acc)
    t_end = 2 * t_acc + t_cruise
    if elapsed_s < t_end:
        return d - 0.5 * a * (t_end - elapsed_s) ** 2
    return d


@dataclass(slots=True)
class SimServo:
    """One servo output: pulses off (0) or slewing from `start_us` to `target_us`."""

    start_us: float = 0.0
    target_us: float = 0.0
    t0: float = 0.0
    speed_us_s: float = 0.0
    accel_us_s2: float = 0.0

    def position_us(self, now: float) -> float:
        if self.target_us <= 0 or self.start_us <= 0:
            return self.target_us
        d = abs(self.target_us - self.start_us)
        s = travelled_us(d, now - self.t0, self.speed_us_s, self.accel_us_s2)
        return self.start_us + math.copysign(s, self.target_us - self.start_us)

    def moving(self, now: float) -> bool:
        return self.position_us(now) != self.target_us

    def retarget(self, now: float, target_us: float) -> None:
        self.start_us = self.position_us(now)
        self.t0 = now
        self.target_us = target_us

    def set_profile(self, now: float, speed_us_s: float, accel_us_s2: float) -> None:
        # Rebase so the new limits apply from here on, not retroactively.
        self.start_us = self.position_us(now)
        self.t0 = now
        self.speed_us_s = speed_us_s
        self.accel_us_s2 = accel_us_s2
