"""The door passage: through a gap a little wider than the robot, slowly, in its middle.

The paper's law scales the speed down with the nearest forward echo, to a stop at the
stop distance, and the escape takes over below it. In a doorway 0.8 m wide the jambs are
0.15 m from a P3-AT's sides and its 50 degree sonars read them at 0.3-0.35 m: the robot
creeps to a halt in the door, then the escape backs it out and goes round. A door is not
an obstacle to go round. The passage (mode DOOR of relayd/core/avoid/escape.py): when

- something is inside threshold_o ahead (the law would slow down),
- both sides of the front ring see something within door_side_m (the jambs),
- the gap between them, each side's nearest echo projected across along its sonar's
  axis, is at least the robot's width plus door_margin_m,
- both forward sonars see beyond door_ahead_m (the way through is open),
- and the leader lies within door_bearing_deg of the nose (the goal is through it),

the robot drives at door_speed_mm_s, steering for the gap's middle, instead of the law's
slowed command. The guard still stops forward motion toward any echo that may lie in the
footprint's path within the stop distance. The paper's law takes over again as soon as
any condition fails (through the door, the sides open up) or the guard holds the robot;
held for no_progress_s, it is stuck, and the escape takes over as anywhere else.
"""

from __future__ import annotations

import math
from dataclasses import replace

from relayd.core.avoid.ring import LATERAL_M
from relayd.core.avoid.state import (
    AvoidCommand,
    AvoidMode,
    AvoidParams,
    AvoidState,
    StepView,
    Verdict,
    drive_cmd,
    enter,
)
from relayd.core.geometry import HALF_WIDTH_M
from relayd.core.scan.estimator import SONAR_MAX_RANGE_M

#: The sonars that see a jamb beside or ahead of the robot, by heading (each side).
SIDE_HEADINGS_DEG = (30.0, 50.0, 90.0)


def side_lateral_m(r: dict[float, float], side: int, reach_m: float) -> float | None:
    """How far to side `side` (+1 left, -1 right) the nearest echo within reach_m lies from
    the centreline, each echo placed on its sonar's axis; None when that side sees nothing."""
    lats = [
        LATERAL_M[side * h] + d * math.sin(math.radians(h))
        for h in SIDE_HEADINGS_DEG
        if (d := r.get(side * h, SONAR_MAX_RANGE_M)) <= reach_m
    ]
    return min(lats, default=None)


def door_gap(r: dict[float, float], p: AvoidParams) -> tuple[float, float] | None:
    """(left, right) lateral distances of a gap the robot fits through with door_margin_m to
    spare and an open way on, or None (see the module docstring)."""
    left = side_lateral_m(r, 1, p.door_side_m)
    right = side_lateral_m(r, -1, p.door_side_m)
    if left is None or right is None or left + right < 2.0 * HALF_WIDTH_M + p.door_margin_m:
        return None
    ahead = min(r.get(10.0, SONAR_MAX_RANGE_M), r.get(-10.0, SONAR_MAX_RANGE_M))
    if ahead <= p.door_ahead_m:
        return None
    return left, right


def at_door(v: StepView) -> bool:
    """Whether the passage applies to this step (the law would slow, a door is ahead)."""
    p = v.p
    return (
        p.door_pass
        and v.d_min_m < p.threshold_o_m
        and abs(v.s.bearing_deg) <= p.door_bearing_deg
        and door_gap(v.r, p) is not None
    )


def door_step(st: AvoidState, v: StepView) -> Verdict:
    """Drive through the gap's middle at door_speed_mm_s; the paper's law again (FOLLOW)
    once the passage no longer applies (progress counted afresh) or the guard stops it.
    Progress is counted here as FOLLOW counts it, so a robot the guard holds in a door is
    found stuck by FOLLOW's watchdog after no_progress_s, and the escape takes over."""
    s, p, t = v.s, v.p, v.t
    if st.anchor is None or math.dist(st.anchor, s.pose[:2]) > p.progress_m * 1000.0:
        st = replace(st, anchor=s.pose[:2], anchor_t=t)
    gap = door_gap(v.r, p) if at_door(v) else None
    if gap is not None:
        left, right = gap
        # Positive: the gap's middle is to the left.
        offset_m = (left - right) / 2.0
        rvel = max(-p.door_max_deg_s, min(p.door_max_deg_s, p.door_gain_deg_s_per_m * offset_m))
        cmd = drive_cmd(v.act, s, p, p.door_speed_mm_s, rvel)
        if cmd.vel_mm_s > 0:
            return st, cmd
        # Held by the guard: the watchdog's clock runs on from the last progress.
        return enter(st, AvoidMode.FOLLOW, t), AvoidCommand(True)
    # Through (or no door after all): the paper's law afresh, progress counted from here.
    return enter(st, AvoidMode.FOLLOW, t, anchor=s.pose[:2], anchor_t=t), AvoidCommand(True)
