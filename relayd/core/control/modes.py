"""Section 6's first rules: the fail-safes, hold and manual (docs/CONTROL.md section 6).

A stale SIP, RSSI, rear link or scan servo stops the wheels; hold stands; manual drives
the operator's wheels behind the deadman and the forward guard. Each of them ends the
lost leader's search, and hold and manual end the escape and the loss's timing too: the
operator may have moved the robot, so what was going on before means nothing after.
"""

from __future__ import annotations

import math
from dataclasses import replace

from relayd.core.avoid.state import AvoidState
from relayd.core.control.inputs import ControlInputs, ControlMemory, ControlOutput, stopped
from relayd.core.control.params import ControlParams
from relayd.core.control.search import SearchState
from relayd.core.scan.estimator import nearest_front_m
from relayd.core.vocab import DriveState, Mode


def clamp(value: float, low: float, high: float) -> float:
    return min(max(value, low), high)


def stale(age_s: float | None, timeout_s: float) -> bool:
    """No reading yet, a NaN age, or older than the timeout."""
    return age_s is None or math.isnan(age_s) or age_s > timeout_s


def _manual(
    inputs: ControlInputs, params: ControlParams, situation: int, memory: ControlMemory
) -> ControlOutput:
    left, right = inputs.manual_left_mm_s, inputs.manual_right_mm_s
    if (
        left is None
        or right is None
        or not (math.isfinite(left) and math.isfinite(right))
        or stale(inputs.manual_age_s, params.manual_deadman_s)
    ):
        return stopped(DriveState.STOPPED, "deadman", situation, memory)
    v_max = params.v_max_mm_s
    left, right = clamp(left, -v_max, v_max), clamp(right, -v_max, v_max)
    reason = "manual"
    d_min = nearest_front_m(inputs.front_sonar)
    forward = (left + right) / 2.0
    if d_min is not None and d_min < params.stop_distance_m and forward > 0:
        # Keep the turn and any backing off, drop only the part that drives into the object.
        left, right = left - forward, right - forward
        reason = "obstacle"
    state = DriveState.DRIVING if (left != 0.0 or right != 0.0) else DriveState.STOPPED
    return ControlOutput(
        left, right, state, reason, situation, replace(memory, prev_steer_deg=None)
    )


def fail_safe_or_mode(
    inputs: ControlInputs, params: ControlParams, situation: int, memory: ControlMemory
) -> ControlOutput | None:
    """Section 6's first rules: a stale input or servo stops, hold and manual decide.
    None: none of them applies, and the law goes on."""
    halted = replace(memory, search=SearchState())
    if inputs.mode is not Mode.FOLLOW:
        halted = replace(halted, avoid=AvoidState(), lost_t=None)
    if stale(inputs.sip_age_s, params.sip_timeout_s):
        return stopped(DriveState.FAULT, "no_sip", situation, halted)
    if inputs.mode is Mode.FOLLOW:
        if stale(inputs.rssi_age_s, params.rssi_timeout_s):
            return stopped(DriveState.FAULT, "rssi_stale", situation, halted)
        if not inputs.scan_servo_ok:
            return stopped(DriveState.FAULT, "scan_servo", situation, halted)
        if params.rear_link_required and (
            stale(inputs.rear_age_s, params.rear_timeout_s) or inputs.rssi_behind_dbm is None
        ):
            return stopped(DriveState.FAULT, "rear_link_stale", situation, halted)

    if inputs.mode is Mode.HOLD:
        return stopped(DriveState.STOPPED, "hold", situation, halted)
    if inputs.mode is Mode.MANUAL:
        return _manual(inputs, params, situation, halted)
    return None
