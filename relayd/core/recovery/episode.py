"""A running recovery episode: the limits, the stale-input stop, and the drive along the trail.

Called by relayd.core.recovery.machine once its transition table has settled the phase;
also the fence that keeps a relay from driving back to where its link behind broke.
"""

from __future__ import annotations

import math
from dataclasses import replace

from relayd.core.recovery.state import (
    FENCE_CLEAR_DB,
    FENCE_M,
    FENCE_S,
    LIMIT_SLACK_M,
    TAPER_S,
    Kind,
    Phase,
    RecoveryCommand,
    RecoveryInputs,
    RecoveryMemory,
    RecoveryOutput,
    RecoveryParams,
    close,
    inputs_stale,
    zero,
)
from relayd.core.recovery.trail import leader_target, reverse_toward
from relayd.core.vocab import DriveState


def fenced(inp: RecoveryInputs, p: RecoveryParams, m: RecoveryMemory) -> RecoveryOutput:
    """The controller in charge, except that it may not drive forward back to where the link
    behind broke (FENCE_M) for FENCE_S after a restore, unless RSSI^b rose well above."""
    if m.fence is None or m.fence_t is None:
        return RecoveryOutput(None, m)
    rb = inp.rssi_behind_dbm
    if inp.now_s - m.fence_t > FENCE_S or (
        rb is not None and rb > p.control.threshold_b_dbm + p.control.hysteresis_db + FENCE_CLEAR_DB
    ):
        return RecoveryOutput(None, replace(m, fence=None, fence_t=None))
    if (
        inp.pose is not None
        and inp.forward_mm_s > 0
        and math.dist((inp.pose[0], inp.pose[1]), m.fence) < FENCE_M * 1000.0
    ):
        return RecoveryOutput(zero(DriveState.STOPPED, "rear_fence"), m)
    return RecoveryOutput(None, m)


def run_episode(inp: RecoveryInputs, p: RecoveryParams, m: RecoveryMemory) -> RecoveryOutput:
    rear = m.kind is Kind.REAR
    lost_state = DriveState.STOPPED if rear else DriveState.LEADER_LOST
    lost_reason = "rear_lost" if rear else "leader_lost"
    if m.incident_t is None:  # an episode always starts one; a memory built by hand may not
        m = replace(
            m,
            incident_t=m.started_t if m.started_t is not None else inp.now_s,
            incident_m=m.distance_m,
        )
    elapsed = inp.now_s - (m.incident_t if m.incident_t is not None else inp.now_s)
    if elapsed >= p.max_time_s:
        m = close(m, Phase.GAVE_UP, "gave_up_time")
        return RecoveryOutput(zero(lost_state, lost_reason), m)
    remaining_m = p.max_distance_m - m.incident_m
    if remaining_m <= LIMIT_SLACK_M:
        m = close(m, Phase.GAVE_UP, "gave_up_distance")
        return RecoveryOutput(zero(lost_state, lost_reason), m)
    if inputs_stale(inp, p, need_rear=rear):
        return RecoveryOutput(zero(DriveState.FAULT, "recovery_stale_input"), m)

    if m.phase is Phase.WIDEN:
        if inp.scan_count - m.start_scans < p.widen_scans:
            return RecoveryOutput(zero(DriveState.LEADER_LOST, "widen"), m)
        m = replace(
            m, phase=Phase.RETRACE, target=leader_target(m.trail, p.control.threshold_l_dbm)
        )

    # Drop the crumbs already reached (the newest first); the trail is consumed going back.
    if inp.pose is None:  # inputs_stale checks it; no pose is never a reason to move
        return RecoveryOutput(zero(DriveState.FAULT, "recovery_stale_input"), m)
    x, y, _ = inp.pose
    trail = m.trail
    while trail and math.hypot(trail[-1].x_mm - x, trail[-1].y_mm - y) < p.reach_m * 1000.0:
        if m.target is not None and m.target >= len(trail) - 1:
            break  # at the leader's crumb: stay here, scanning
        trail = trail[:-1]
    m = replace(m, trail=trail)
    if m.target is not None and m.target >= len(trail):
        m = replace(m, target=len(trail) - 1 if trail else None)
    at_end = not trail or (
        m.target is not None
        and m.target == len(trail) - 1
        and math.hypot(trail[-1].x_mm - x, trail[-1].y_mm - y) < p.reach_m * 1000.0
    )
    if at_end:
        reason = "rear_trail_end" if rear else "retrace_wait"
        return RecoveryOutput(zero(DriveState.RECOVERING, reason), m)

    speed = p.backup_speed_mm_s if rear else p.retrace_speed_mm_s
    speed = min(speed, remaining_m * 1000.0 / TAPER_S)
    left, right, why = reverse_toward(
        inp.pose,
        trail[-1],
        speed,
        inp.sonar_mm,
        threshold_o_m=p.control.threshold_o_m,
        stop_distance_m=p.control.stop_distance_m,
        gamma_o_m=p.control.gamma_o_m,
        turn_gain_mm_s_deg=p.turn_gain_mm_s_deg,
    )
    reason = ("backup" if rear else "retrace") if why == "retrace" else why
    return RecoveryOutput(RecoveryCommand(left, right, DriveState.RECOVERING, reason), m)
