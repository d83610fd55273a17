"""The fake robot's wheels: one physics step of a differential drive, with walls.

Pure functions, no clock and no I/O: `drive_step` moves a pose by a forward and a
turning speed over `dt`, and a `motion_guard` (the simulator's walls, another robot)
may refuse the move; then the wheels stall and the robot ends up against the
obstacle, not a step short of it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from drivers.arcos.sip import wrap_deg

#: (x_mm, y_mm, theta_deg) in the world frame.
Pose = tuple[float, float, float]
#: `guard(old, new)` is False when the robot may not move from `old` to `new`.
MotionGuard = Callable[[Pose, Pose], bool]


@dataclass(frozen=True, slots=True)
class Move:
    pose: Pose
    dist_mm: float  # travelled along the arc (what the wheel encoders count)
    turn_deg: float
    stalled: bool


def approach(value: float, target: float, max_step: float) -> float:
    """`value` moved toward `target` by at most `max_step` (an acceleration limit)."""
    if value < target:
        return min(target, value + max_step)
    return max(target, value - max_step)


def drive_step(
    pose: Pose, vel_mm_s: float, rvel_deg_s: float, dt: float, guard: MotionGuard | None
) -> Move:
    """Where `pose` gets in `dt` s at these speeds (mid-point heading), walls permitting."""
    x, y, th = pose
    dth = rvel_deg_s * dt
    mid = math.radians(th + dth / 2.0)
    ds = vel_mm_s * dt
    new = (x + ds * math.cos(mid), y + ds * math.sin(mid), wrap_deg(th + dth))
    if guard is None or guard(pose, new):
        return Move(new, ds, dth, False)
    # Blocked: the wheels stall. Move as far as allowed (halving the step a few times).
    full_ds, ds = ds, 0.0
    new = (x, y, wrap_deg(th + dth))
    if dth != 0 and not guard(pose, new):
        dth = 0.0
        new = pose
    turned = math.radians(new[2] - dth / 2.0)
    frac = 0.5
    for _ in range(5):
        trial = (
            x + frac * full_ds * math.cos(turned),
            y + frac * full_ds * math.sin(turned),
            new[2],
        )
        if guard(pose, trial):
            ds, new = frac * full_ds, trial
            break
        frac /= 2.0
    return Move(new, ds, dth, True)
