"""What the P3-AT's motion commands can express, and turns it really executes.

VEL is an integer in mm/s and RVEL an integer in deg/s on the wire (docs/PROTOCOLS.md);
the driver turns wheel speeds into them by rounding. The controller rounds first, so a
small intended turn becomes an executable one or a deliberate zero, never an accident
of the driver's rounding, and /status shows the command the robot really got.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drivers.arcos.sip import DIFF_CONV_FACTOR, MAX_RVEL_DEG_S, MAX_VEL_MM_S


@dataclass(frozen=True, slots=True)
class Actuator:
    """What the P3-AT's motion commands can express: VEL in mm/s, RVEL in deg/s, integers."""

    vel_step_mm_s: float = 1.0
    rvel_step_deg_s: float = 1.0
    diff_conv: float = DIFF_CONV_FACTOR
    max_vel_mm_s: float = float(MAX_VEL_MM_S)
    max_rvel_deg_s: float = float(MAX_RVEL_DEG_S)
    #: The slowest in-place turn a skid-steered P3-AT really executes (its wheels must
    #: overcome the scrub of four tyres); a smaller turn rate is a deliberate zero.
    min_turn_deg_s: float = 8.0

    def vel_rvel(self, left_mm_s: float, right_mm_s: float) -> tuple[float, float]:
        """(VEL, RVEL) before rounding, as the driver computes them."""
        return (left_mm_s + right_mm_s) / 2.0, math.degrees(
            (right_mm_s - left_mm_s) / 2.0 * self.diff_conv
        )

    def wheels(self, vel_mm_s: float, rvel_deg_s: float) -> tuple[float, float]:
        d = math.radians(rvel_deg_s) / self.diff_conv
        return vel_mm_s - d, vel_mm_s + d

    def express(self, vel_mm_s: float, rvel_deg_s: float) -> tuple[int, int]:
        """The (VEL, RVEL) on the wire: rounded to the step and clamped; an intended turn
        slower than half a step becomes a deliberate 0."""
        vel = round(vel_mm_s / self.vel_step_mm_s) * self.vel_step_mm_s
        rvel = round(rvel_deg_s / self.rvel_step_deg_s) * self.rvel_step_deg_s
        vel = max(-self.max_vel_mm_s, min(self.max_vel_mm_s, vel))
        rvel = max(-self.max_rvel_deg_s, min(self.max_rvel_deg_s, rvel))
        return int(vel), int(rvel)

    def turn(self, rvel_deg_s: float) -> int:
        """An in-place turn the robot executes: at least `min_turn_deg_s`, never 0 unless asked."""
        if rvel_deg_s == 0:
            return 0
        mag = max(abs(rvel_deg_s), self.min_turn_deg_s)
        mag = math.ceil(mag / self.rvel_step_deg_s) * self.rvel_step_deg_s
        return int(math.copysign(min(mag, self.max_rvel_deg_s), rvel_deg_s))

    def within(self, vel: int, rvel: int, wheel_max_mm_s: float) -> tuple[int, int]:
        """Shrink an expressed command (translation first) so no wheel exceeds wheel_max."""
        d = abs(math.radians(rvel) / self.diff_conv)
        if d > wheel_max_mm_s:
            steps = math.floor(math.degrees(wheel_max_mm_s * self.diff_conv) / self.rvel_step_deg_s)
            rvel = int(math.copysign(steps * self.rvel_step_deg_s, rvel))
            d = abs(math.radians(rvel) / self.diff_conv)
        excess = abs(vel) + d - wheel_max_mm_s
        if excess > 1e-9:
            mag = max(0.0, abs(vel) - math.ceil(excess / self.vel_step_mm_s) * self.vel_step_mm_s)
            vel = int(math.copysign(mag, vel))
        return vel, rvel

    def express_wheels(
        self, left_mm_s: float, right_mm_s: float, wheel_max_mm_s: float | None = None
    ) -> tuple[float, float]:
        """Wheel speeds that the driver turns into exactly the intended integer VEL/RVEL."""
        vel, rvel = self.express(*self.vel_rvel(left_mm_s, right_mm_s))
        if wheel_max_mm_s is not None:
            vel, rvel = self.within(vel, rvel, wheel_max_mm_s)
        return self.wheels(vel, rvel)
