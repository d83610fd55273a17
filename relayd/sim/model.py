"""A pure closed-loop model of one relay in a scenario world, in virtual time.

For the avoidance bench and property tests: thousands of control steps a second,
deterministic for a seed, no daemons, ptys or clocks. It keeps what matters for getting
past obstacles and drops the rest:

- the real controller (`relayd.core.control.law.control_step`) on every 100 ms SIP, with the
  world's truthful sonar (`World.sonar_mm`) refreshed 8 sonars per SIP in the
  FakeRobot's firing order, as the P3-AT reports them;
- the command as the wire carries it (integer VEL mm/s, RVEL deg/s, the driver's
  rounding) and the FakeRobot's acceleration limits and stall on contact
  (`World.motion_ok` counts a collision per contact episode);
- the leader's bearing from a scan every `scan_period_s`: the true bearing plus seeded
  Gaussian noise, corrected by the odometry turn since, as control.py does;
  RSSI^l from the world's radio at that moment (shadowing and fading per seed).

`relayd sim` remains the end-to-end check with real daemons; this model is the same
controller against the same world, fast enough to sweep.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from dataclasses import dataclass, field

from drivers.arcos.fakebody import FIRING_ORDER
from drivers.arcos.sip import wheel_to_vel_rvel
from relayd.core.avoid.ring import rear_readings
from relayd.core.control.law import (
    ControlInputs,
    ControlMemory,
    ControlOutput,
    ControlParams,
    control_step,
)
from relayd.core.geometry import ROBOT_LENGTH_M, wrap_deg
from relayd.core.scan.estimator import front_readings
from relayd.core.vocab import Mode
from relayd.sim.geometry import Segment, point_segment_distance, segments_intersect
from relayd.sim.scenario import Scenario
from relayd.sim.world import World

SIP_PERIOD_S = 0.1
SONARS_PER_SIP = 8
TRANS_ACCEL_MM_S2 = 300.0
ROT_ACCEL_DEG_S2 = 100.0


@dataclass(slots=True)
class Step:
    """What one control step saw and decided (for the invariant checks)."""

    t: float
    out: ControlOutput
    inputs: ControlInputs
    vel_mm_s: int
    rvel_deg_s: int


@dataclass(slots=True)
class Outcome:
    passed_at_s: float | None
    min_clearance_m: float
    collisions: int
    final_reason: str
    reasons: dict[str, float] = field(default_factory=dict)  # clock seconds per reason
    x_m: float = 0.0
    y_m: float = 0.0
    min_clearance_at: tuple[float, float, float, float] | None = None  # t, x, y, theta


def _approach(v: float, target: float, dv: float) -> float:
    return target if abs(target - v) <= dv else v + math.copysign(dv, target - v)


def _now_frame(bearing: float | None, heading_then: float, heading_now: float) -> float | None:
    """A scan bearing seen from the heading now, as control.py corrects it by odometry."""
    if bearing is None:
        return None
    return wrap_deg(bearing - (heading_now - heading_then))


def clearance_m(poly: tuple[tuple[float, float], ...], segments: list[Segment]) -> float:
    """Distance from the footprint polygon to the nearest segment (0 when touching)."""
    best = math.inf
    n = len(poly)
    for s in segments:
        a, b = (s.x1, s.y1), (s.x2, s.y2)
        for i in range(n):
            p, q = poly[i], poly[(i + 1) % n]
            if segments_intersect(p, q, a, b):
                return 0.0
            best = min(
                best,
                point_segment_distance(p, a, b),
                point_segment_distance(a, p, q),
                point_segment_distance(b, p, q),
            )
    return best


def run_model(
    scenario: Scenario,
    *,
    seed: int = 0,
    past_m: float,
    seconds: float = 180.0,
    params: ControlParams | None = None,
    bearing_noise_deg: float = 3.0,
    scan_period_s: float = 4.5,
    on_step: Callable[[Step], None] | None = None,
    escape: bool = True,
) -> Outcome:
    """Drive relay 0 of `scenario` until its centre is `past_m` along the start->leader
    line (plus half the robot's length), or `seconds` of clock time. escape=False runs the
    paper's law alone (no time or odometry for the escape): the defect, for comparison."""
    params = params or ControlParams(rear_link_required=False)
    world = World(scenario.with_relays(1), seed=seed)
    rng = random.Random(seed * 7919 + 17)
    body = world.relays[0]
    lx, ly = world.leader.x_m, world.leader.y_m
    sx, sy = body.x_m, body.y_m
    line = math.atan2(ly - sy, lx - sx)
    goal = past_m + ROBOT_LENGTH_M / 2.0
    x, y, th = body.x_m * 1000.0, body.y_m * 1000.0, body.theta_deg
    vel = rvel = 0.0
    ranges: list[int | None] = [None] * 16
    fire = 0
    memory = ControlMemory()
    bearing = prev_bearing = None
    scan_heading = prev_heading = 0.0
    rssi_l: float | None = None
    next_scan = 1.0
    obstacles = list(world.obstacles)
    outcome = Outcome(None, math.inf, 0, "")
    t = 0.0
    while t < seconds:
        world.advance(t)
        world.set_pose(0, x, y, th)
        sonar = world.sonar_ranges(0, x, y, th)
        for _ in range(SONARS_PER_SIP):
            i = FIRING_ORDER[fire % 16]
            fire += 1
            ranges[i] = sonar[i]
        if t >= next_scan:
            true_b = world.true_bearing_deg(0)
            prev_bearing, prev_heading = bearing, scan_heading
            bearing, scan_heading = true_b + rng.gauss(0.0, bearing_noise_deg), th
            rssi_l = world.yagi_rssi_dbm(0, true_b)
            next_scan = t + scan_period_s

        inputs = ControlInputs(
            mode=Mode.FOLLOW,
            sip_age_s=0.0,
            rssi_age_s=0.0 if rssi_l is not None else None,
            scan_servo_ok=True,
            bearing_deg=_now_frame(bearing, scan_heading, th),
            prev_bearing_deg=_now_frame(prev_bearing, prev_heading, th),
            rssi_leader_dbm=rssi_l,
            rssi_behind_dbm=-40.0,
            rear_age_s=0.0,
            front_sonar=front_readings(ranges),
            leader_lost=False,
            t_s=t if escape else None,
            odom=(x, y, th) if escape else None,
            rear_sonar=rear_readings(ranges),
        )
        out = control_step(inputs, params, memory)
        memory = out.memory
        tv, trv = wheel_to_vel_rvel(out.left_mm_s, out.right_mm_s)
        if on_step is not None:
            on_step(Step(t, out, inputs, tv, trv))
        outcome.reasons[out.reason] = outcome.reasons.get(out.reason, 0.0) + SIP_PERIOD_S
        outcome.final_reason = out.reason
        # Physics over one SIP period, in a few sub-steps (the motion guard is per step).
        for _ in range(4):
            dt = SIP_PERIOD_S / 4
            vel = _approach(vel, float(tv), TRANS_ACCEL_MM_S2 * dt)
            rvel = _approach(rvel, float(trv), ROT_ACCEL_DEG_S2 * dt)
            dth = rvel * dt
            mid = math.radians(th + dth / 2.0)
            nx, ny = x + vel * dt * math.cos(mid), y + vel * dt * math.sin(mid)
            nth = wrap_deg(th + dth)
            if world.motion_ok(0, nx, ny, nth, (x, y, th)):
                x, y, th = nx, ny, nth
            else:
                vel = 0.0
        t = round(t + SIP_PERIOD_S, 6)
        world.set_pose(0, x, y, th)
        clear = clearance_m(body.polygon(), obstacles)
        if clear < outcome.min_clearance_m:
            outcome.min_clearance_m = clear
            outcome.min_clearance_at = (t, x / 1000.0, y / 1000.0, th)
        along = (x / 1000.0 - sx) * math.cos(line) + (y / 1000.0 - sy) * math.sin(line)
        if outcome.passed_at_s is None and along >= goal:
            outcome.passed_at_s = t
            break
    outcome.collisions = world.collisions()
    outcome.x_m, outcome.y_m = x / 1000.0, y / 1000.0
    return outcome
