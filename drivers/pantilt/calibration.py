"""Servo calibration: degrees to pulse widths and back, per servo, with its limits.

relayd speaks degrees (counter-clockwise positive: positive = to the robot's left);
the controllers speak pulse widths. `ServoCalibration` maps one to the other,
piecewise linear through the pulse widths measured at -90, 0 and +90 degrees, and
clamps to the servo's limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class ServoCalibration:
    """Pulse widths of one servo at -90, 0 and +90 degrees, and its allowed range.

    The pulses may decrease with the angle (a servo mounted upside down). Angles
    beyond +-90 are extrapolated along the outer segment, so limits wider than 90
    degrees work when the servo travels that far.
    """

    pulse_us: tuple[float, float, float] = (1000.0, 1500.0, 2000.0)
    limits_deg: tuple[float, float] = (-90.0, 90.0)

    def __post_init__(self) -> None:
        pulses = tuple(float(p) for p in self.pulse_us)
        limits = tuple(float(a) for a in self.limits_deg)
        if len(pulses) != 3:
            raise ValueError(f"pulse_us needs 3 values (-90, 0, +90 deg), got {self.pulse_us!r}")
        if len(limits) != 2:
            raise ValueError(f"limits_deg needs 2 values (min, max), got {self.limits_deg!r}")
        if not all(math.isfinite(p) and p > 0 for p in pulses):
            raise ValueError(f"pulse_us must be positive and finite, got {pulses!r}")
        lo, mid, hi = pulses
        if not (lo < mid < hi or lo > mid > hi):
            raise ValueError(f"pulse_us must be strictly monotonic, got {pulses!r}")
        if not all(math.isfinite(a) for a in limits) or not limits[0] < limits[1]:
            raise ValueError(f"limits_deg must be finite with min < max, got {limits!r}")
        # Normalise lists from TOML/pydantic into the declared tuple types.
        object.__setattr__(self, "pulse_us", pulses)
        object.__setattr__(self, "limits_deg", limits)

    def clamp(self, angle_deg: float) -> float:
        lo, hi = self.limits_deg
        return min(hi, max(lo, angle_deg))

    def angle_to_pulse_us(self, angle_deg: float) -> float:
        lo, mid, hi = self.pulse_us
        if angle_deg <= 0.0:
            return mid + (mid - lo) * angle_deg / 90.0
        return mid + (hi - mid) * angle_deg / 90.0

    def pulse_us_to_angle(self, pulse_us: float) -> float:
        lo, mid, hi = self.pulse_us
        d = pulse_us - mid
        if d == 0.0:
            return 0.0
        # Which side of centre: the -90 side lies towards `lo` whichever way pulses run.
        if (d < 0) == (lo < mid):
            return 90.0 * d / (mid - lo)
        return 90.0 * d / (hi - mid)

    @property
    def us_per_deg(self) -> float:
        """Mean slope over the whole travel, used to turn deg/s into pulse change per second."""
        return abs(self.pulse_us[2] - self.pulse_us[0]) / 180.0

    def pulse_range_us(self) -> tuple[float, float]:
        """Smallest and largest pulse width this calibration can ever command."""
        a = self.angle_to_pulse_us(self.limits_deg[0])
        b = self.angle_to_pulse_us(self.limits_deg[1])
        return (min(a, b), max(a, b))


def check_angle(angle_deg: float) -> float:
    angle = float(angle_deg)
    if not math.isfinite(angle):
        raise ValueError(f"angle_deg must be finite, got {angle_deg!r}")
    return angle


def check_speed(deg_s: float) -> float:
    """Validate a slew speed: >= 0 deg/s; 0 and +inf both mean unlimited (returned as 0)."""
    speed = float(deg_s)
    if math.isnan(speed) or speed < 0:
        raise ValueError(f"speed must be >= 0 deg/s (0 = unlimited), got {deg_s!r}")
    return 0.0 if math.isinf(speed) else speed
