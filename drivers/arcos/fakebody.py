"""The fake P3-AT's body: its motion, odometry, sonar firing and the SIP they make.

`FakeBody` is what the robot physically is, apart from the wire: a TRUE world pose for
the simulator (the world answers sonar ranges through `sonar_fn` and vetoes motion
steps through `motion_guard`), velocities that approach their targets at the
configured accelerations (fakemotion.py), odometry that starts at 0,0,0 at OPEN, and
the SIP (`build_sip`) that reports them in robot units (mm / DistConvFactor, 15-bit
wrapped). Sonar policy: `sonars_per_sip` readings per SIP (default 8), taken
round-robin from the front and rear rings in parallel (0, 8, 1, 9, ...), so the whole
ring refreshes every 200 ms; 16 = all every SIP like MobileSim. No echo (None from
`sonar_fn`) is reported as 5000 mm. `FakeRobot` (fake.py) is this body speaking ARCOS:
its commands set the targets and switches here, its SIP loop calls `move`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from drivers.arcos.fakemotion import MotionGuard, Pose, approach, drive_step
from drivers.arcos.sip import (
    ANGLE_CONV_RAD,
    FLAG_ESTOP,
    FLAG_MOTORS,
    FLAG_SONARS,
    NO_ECHO_MM,
    STALL_LEFT,
    STALL_RIGHT,
    RawSip,
    conv_factors,
    vel_rvel_to_wheels,
    wrap_deg,
)
from drivers.arcos.sonar import SONAR_COUNT

SonarFn = Callable[[float, float, float], Sequence[float | None]]

FIRING_ORDER = tuple(i for pair in zip(range(8), range(8, 16), strict=True) for i in pair)


class FakeBody:
    """A P3-AT's motion, odometry and sonar, and the SIP that reports them."""

    def __init__(
        self,
        subclass: str = "p3at",
        *,
        sonar_fn: SonarFn | None = None,
        motion_guard: MotionGuard | None = None,
        pose: Pose = (0.0, 0.0, 0.0),
        battery_v: float = 13.0,
        trans_accel_mm_s2: float = 300.0,
        rot_accel_deg_s2: float = 100.0,
        sonars_per_sip: int = 8,
    ) -> None:
        self.factors = conv_factors(subclass)
        self.sonar_fn = sonar_fn
        self.motion_guard = motion_guard
        self.x_mm, self.y_mm, self.theta_deg = (float(v) for v in pose)
        self.battery_v = battery_v
        self.trans_accel_mm_s2 = trans_accel_mm_s2
        self.rot_accel_deg_s2 = rot_accel_deg_s2
        self.sonars_per_sip = max(1, min(SONAR_COUNT, sonars_per_sip))
        self.estop_pressed = False  # the red STOP button (FLAGS bit 5)
        self.motors_enabled = False
        self.sonar_on = False
        self.target_vel_mm_s = 0.0
        self.target_rvel_deg_s = 0.0
        self.vel_mm_s = 0.0
        self.rvel_deg_s = 0.0
        self.stalled = False
        self._odo: list[float] = [0.0, 0.0, 0.0]
        self._fire_pos = 0

    @property
    def pose(self) -> Pose:
        return (self.x_mm, self.y_mm, self.theta_deg)

    def set_pose(self, x_mm: float, y_mm: float, theta_deg: float) -> None:
        """Move the robot in the world (odometry does not see it, as with a kidnapped robot)."""
        self.x_mm, self.y_mm, self.theta_deg = float(x_mm), float(y_mm), wrap_deg(theta_deg)

    @property
    def odometry_mm_deg(self) -> Pose:
        """The robot's own odometric pose (mm, deg) since OPEN."""
        return (self._odo[0], self._odo[1], self._odo[2])

    def reset_odometry(self) -> None:
        """Odometry back to 0,0,0 (at OPEN, and on SETO)."""
        self._odo = [0.0, 0.0, 0.0]

    def _can_move(self) -> bool:
        return self.motors_enabled and not self.estop_pressed

    def _halt(self, *, hard: bool) -> None:
        self.target_vel_mm_s = self.target_rvel_deg_s = 0.0
        if hard:
            self.vel_mm_s = self.rvel_deg_s = 0.0

    def move(self, dt: float) -> None:
        """Advance the motion by `dt` clock seconds: accelerate toward the targets, then
        move the true pose (as the world allows) and the odometry by the same wheel motion."""
        if not self._can_move():
            self._halt(hard=True)
        self.vel_mm_s = approach(self.vel_mm_s, self.target_vel_mm_s, self.trans_accel_mm_s2 * dt)
        self.rvel_deg_s = approach(
            self.rvel_deg_s, self.target_rvel_deg_s, self.rot_accel_deg_s2 * dt
        )
        self.stalled = False
        if dt <= 0 or (self.vel_mm_s == 0 and self.rvel_deg_s == 0):
            return
        step = drive_step(self.pose, self.vel_mm_s, self.rvel_deg_s, dt, self.motion_guard)
        self.stalled = step.stalled
        self.x_mm, self.y_mm, self.theta_deg = step.pose
        # Odometry sees the same wheel motion, in its own frame.
        omid = math.radians(self._odo[2] + step.turn_deg / 2.0)
        self._odo[0] += step.dist_mm * math.cos(omid)
        self._odo[1] += step.dist_mm * math.sin(omid)
        self._odo[2] = wrap_deg(self._odo[2] + step.turn_deg)

    def _sonar_readings(self) -> tuple[tuple[int, int], ...]:
        if not self.sonar_on:
            return ()
        ranges: Sequence[float | None] = (
            self.sonar_fn(self.x_mm, self.y_mm, self.theta_deg)
            if self.sonar_fn is not None
            else [None] * SONAR_COUNT
        )
        out = []
        for _ in range(self.sonars_per_sip):
            idx = FIRING_ORDER[self._fire_pos % SONAR_COUNT]
            self._fire_pos += 1
            r = ranges[idx] if idx < len(ranges) else None
            out.append((idx, NO_ECHO_MM if r is None else max(0, min(NO_ECHO_MM, round(r)))))
        return tuple(out)

    def build_sip(self) -> RawSip:
        """The SIP of this instant: odometry in robot units, the next sonars in firing order."""
        dist = self.factors.dist_mm_per_unit
        vel = 0.0 if self.stalled else self.vel_mm_s
        left, right = vel_rvel_to_wheels(vel, self.rvel_deg_s)
        flags = (FLAG_MOTORS if self.motors_enabled else 0) | (FLAG_SONARS if self.sonar_on else 0)
        flags |= FLAG_ESTOP if self.estop_pressed else 0
        th_units = round(math.radians(self._odo[2]) / ANGLE_CONV_RAD)
        return RawSip(
            moving=abs(vel) > 0 or abs(self.rvel_deg_s) > 0,
            x_raw=round(self._odo[0] / dist) & 0x7FFF,
            y_raw=round(self._odo[1] / dist) & 0x7FFF,
            th_raw=max(-2048, min(2047, th_units)) if th_units != 2048 else -2048,
            left_raw=round(left),
            right_raw=round(right),
            battery_dv=max(0, min(255, round(self.battery_v * 10))),
            stall_bumpers=(STALL_LEFT | STALL_RIGHT) if self.stalled else 0,
            control=0,
            flags=flags,
            compass=0,
            sonar=self._sonar_readings(),
            battery_x10=round(self.battery_v * 10),
            charge_state=0,
            rotvel_x10=round(self.rvel_deg_s * 10),
            fault_flags=0,
        )
