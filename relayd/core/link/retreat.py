"""Stepping back out of a shadow: the adaptive rear limit's one move backwards (pure).

Where the hop behind loses 15 dB within centimetres (a car between the antennas) the
relay stops already in the shadow. `retreat_step` steps it back along its own trail of
spots (each rear poll's verdict marked on it) to the last spot whose poll met the
target, in reverse, guarded by the rear sonars, within MAX_RETREAT_M, and holds there
with the rear limit raised to that poll's RSSI^b + HOLD_MARGIN_DB. It promises: a move
starts only in adaptive mode, in follow, with the controller holding the relay at its
rear limit; it never backs blind; stale input ends a move with wheels at zero on that
step. When, where to, the hold and each constant's reason: docs/CONTROL.md section 5.1,
"Stepping back out of a shadow". No I/O, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from relayd.core.control.inputs import ControlInputs, ControlOutput
from relayd.core.control.modes import stale
from relayd.core.control.params import ControlParams
from relayd.core.recovery.trail import REAR_SONARS, TrailPoint, reverse_toward
from relayd.core.vocab import DriveState, Mode

#: Rear polls in a row below the target, standing at the rear limit, before it steps back.
BELOW_POLLS = 3
#: A miss this far (dB) below the previous poll, which met the target, is a shadow edge ...
EDGE_DROP_DB = 8.0
#: ... when the relay drove between STANDING_M and EDGE_M (m) from that poll's spot.
EDGE_M = 1.0
STANDING_M = 0.02
#: The most path (m) it may reverse before it has driven CLEAR_M away from where it held.
MAX_RETREAT_M = 3.0
#: A retreat that has not arrived after this long ends where it is (an echo blocks the way).
MAX_TIME_S = 30.0
#: Reverse speed (mm/s), at most (distance left) / TAPER_S.
SPEED_MM_S = 150.0
TAPER_S = 1.0
#: TrailPoint spacing along the trail (m), how close counts as arrived (m), trail length (spots).
SPACING_M = 0.1
REACH_M = 0.1
KEEP = 120
#: Margin (dB) over the RSSI^b measured at the spot it holds at.
HOLD_MARGIN_DB = 3.0
#: The hold (and the spent budget) ends this far (m) from the spot.
CLEAR_M = 3.0
#: Closer to the distance bound than this counts as reached (m).
LIMIT_SLACK_M = 0.02
#: The controller's reason for standing at the rear limit.
REAR_WEAK = "rear_weak"


@dataclass(frozen=True, slots=True)
class RetreatMemory:
    trail: tuple[TrailPoint, ...] = ()
    #: The last step's controller held the relay at its rear limit (standing).
    rear_stopped: bool = False
    #: Polls in a row that missed the target while standing at the rear limit.
    below: int = 0
    #: The newest poll found a shadow edge (see EDGE_DROP_DB); cleared by the next poll or a move.
    edge: bool = False
    #: Index into trail of the spot a running move heads for; None: no move.
    target: int | None = None
    started_t: float | None = None
    last_pose: tuple[float, float] | None = None
    #: Path reversed since the budget last cleared (m).
    spent_m: float = 0.0
    #: The rear limit's floor while holding (dBm), and the spot held at (mm).
    floor_dbm: float | None = None
    anchor: tuple[float, float] | None = None
    retreats: int = 0
    last_outcome: str | None = None


def _pose_ok(pose: tuple[float, float, float] | None) -> bool:
    return pose is not None and all(math.isfinite(v) for v in pose)


def record_poll(
    m: RetreatMemory, pose: tuple[float, float, float] | None, rssi_b_dbm: float, met: bool
) -> RetreatMemory:
    """One rear poll the link model accepted: its spot and verdict, the run below target, an edge."""
    below = m.below + 1 if (m.rear_stopped and not met) else 0
    if m.target is not None:
        return replace(m, below=0, edge=False)  # a move runs: its trail's indices must hold still
    if not _pose_ok(pose) or not math.isfinite(rssi_b_dbm) or pose is None:
        return replace(m, below=below, edge=False)
    spot = TrailPoint(pose[0], pose[1], rssi_b_dbm=rssi_b_dbm, met=met)
    trail = m.trail
    edge = not met and is_edge(trail, spot)
    last = trail[-1] if trail else None
    if (
        last is not None
        and last.met is not None
        and m.target is None
        and math.hypot(last.x_mm - spot.x_mm, last.y_mm - spot.y_mm) < SPACING_M * 500.0
    ):
        trail = trail[:-1]
    trail = (*trail, spot)[-KEEP:]
    return replace(m, trail=trail, below=below, edge=edge)


def is_edge(trail: tuple[TrailPoint, ...], spot: TrailPoint) -> bool:
    """The poll at `spot` fell EDGE_DROP_DB below the previous poll, which met the target,
    within EDGE_M of travel (and not standing: a drop that comes to a standing relay is
    the node behind or something between, which stepping back need not cure)."""
    prev = next((s for s in reversed(trail) if s.met is not None), None)
    if prev is None or not prev.met or prev.rssi_b_dbm is None or spot.rssi_b_dbm is None:
        return False
    moved_m = math.hypot(spot.x_mm - prev.x_mm, spot.y_mm - prev.y_mm) / 1000.0
    return STANDING_M <= moved_m <= EDGE_M and prev.rssi_b_dbm - spot.rssi_b_dbm >= EDGE_DROP_DB


def _lay(m: RetreatMemory, x: float, y: float) -> RetreatMemory:
    last = m.trail[-1] if m.trail else None
    if last is not None and math.hypot(x - last.x_mm, y - last.y_mm) < SPACING_M * 1000.0:
        return m
    return replace(m, trail=(*m.trail, TrailPoint(x, y))[-KEEP:])


def retreat_target(
    trail: tuple[TrailPoint, ...], x: float, y: float, budget_m: float
) -> int | None:
    """Where a step back goes, within budget_m of path: the poll before the newest spot more
    than REACH_M away whose poll met the target, if that poll met it too; else that newest spot."""
    path_m, px, py = 0.0, x, y
    newest: int | None = None
    for i in range(len(trail) - 1, -1, -1):
        s = trail[i]
        path_m += math.hypot(s.x_mm - px, s.y_mm - py) / 1000.0
        px, py = s.x_mm, s.y_mm
        if path_m > budget_m:
            return newest
        if newest is None:
            if s.met and math.hypot(s.x_mm - x, s.y_mm - y) > REACH_M * 1000.0:
                newest = i
        elif s.met is not None:
            return i if s.met else newest
    return newest


def held_limit(params: ControlParams, m: RetreatMemory, upper_dbm: float) -> ControlParams:
    """The controller's params with the hold's floor on threshold_b (never above upper_dbm)."""
    if m.floor_dbm is None or m.floor_dbm <= params.threshold_b_dbm:
        return params
    return replace(params, threshold_b_dbm=min(m.floor_dbm, max(upper_dbm, params.threshold_b_dbm)))


def _doubt(ci: ControlInputs, p: ControlParams) -> bool:
    return (
        not _pose_ok(ci.odom)
        or stale(ci.sip_age_s, p.sip_timeout_s)
        or stale(ci.rssi_age_s, p.rssi_timeout_s)
        or stale(ci.rear_age_s, p.rear_timeout_s)
        or ci.rssi_behind_dbm is None
        or not math.isfinite(ci.rssi_behind_dbm)
    )


def _rear_blind(sonar_mm: tuple[int | None, ...]) -> bool:
    """A rear sonar never read (or reading nonsense) cannot guard the way back."""
    for k in REAR_SONARS:
        r = sonar_mm[k] if k < len(sonar_mm) else None
        if r is None or not r > 0:
            return True
    return False


def _end(m: RetreatMemory, outcome: str) -> RetreatMemory:
    return replace(
        m, target=None, started_t=None, last_pose=None, last_outcome=outcome, below=0, edge=False
    )


def _zero(out: ControlOutput, state: DriveState, reason: str) -> ControlOutput:
    return ControlOutput(0.0, 0.0, state, reason, out.situation, out.memory)


def retreat_step(
    ci: ControlInputs,
    sonar_mm: tuple[int | None, ...],
    out: ControlOutput,
    p: ControlParams,
    m: RetreatMemory,
    *,
    enabled: bool,
) -> tuple[ControlOutput, RetreatMemory]:
    """One control step: the controller's output, or a retreat's command in its place."""
    if not enabled:
        return out, m
    stopped = out.left_mm_s == 0.0 and out.right_mm_s == 0.0 and out.reason == REAR_WEAK
    following = ci.mode is Mode.FOLLOW and out.state is not DriveState.FAULT
    m = replace(m, rear_stopped=stopped and following)
    if not following or ci.odom is None or not _pose_ok(ci.odom):
        if m.target is not None:
            return _zero(out, out.state, out.reason), _end(m, "aborted")
        return out, replace(m, below=0, edge=False) if not following else m
    x, y, _ = ci.odom
    now = ci.t_s if ci.t_s is not None else 0.0
    if m.anchor is not None and math.hypot(x - m.anchor[0], y - m.anchor[1]) > CLEAR_M * 1000.0:
        m = replace(m, floor_dbm=None, anchor=None, spent_m=0.0)

    if m.target is None:
        m = _lay(m, x, y)
        if not (stopped and (m.below >= BELOW_POLLS or m.edge)) or _doubt(ci, p):
            return out, m
        target = retreat_target(m.trail, x, y, MAX_RETREAT_M - m.spent_m)
        if target is None:
            return out, replace(m, below=0, edge=False, last_outcome="no_spot")
        m = replace(
            m, target=target, started_t=now, last_pose=(x, y), retreats=m.retreats + 1, edge=False
        )

    # A move runs.
    if _doubt(ci, p):
        return _zero(out, DriveState.FAULT, "retreat_stale_input"), _end(m, "stale_input")
    if m.last_pose is not None:
        m = replace(
            m, spent_m=m.spent_m + math.hypot(x - m.last_pose[0], y - m.last_pose[1]) / 1000.0
        )
    m = replace(m, last_pose=(x, y))
    remaining_m = MAX_RETREAT_M - m.spent_m
    if remaining_m <= LIMIT_SLACK_M:
        return _zero(out, DriveState.STOPPED, REAR_WEAK), replace(
            _end(m, "gave_up_distance"), anchor=(x, y)
        )
    if m.started_t is not None and now - m.started_t >= MAX_TIME_S:
        return _zero(out, DriveState.STOPPED, REAR_WEAK), replace(
            _end(m, "gave_up_time"), anchor=(x, y)
        )
    assert m.target is not None
    trail, target = m.trail, m.target
    # Consume the spots passed (the newest first), never the target.
    while (
        len(trail) - 1 > target
        and math.hypot(trail[-1].x_mm - x, trail[-1].y_mm - y) < REACH_M * 1000.0
    ):
        trail = trail[:-1]
    m = replace(m, trail=trail)
    goal = trail[target]
    if len(trail) - 1 == target and math.hypot(goal.x_mm - x, goal.y_mm - y) < REACH_M * 1000.0:
        floor = None if goal.rssi_b_dbm is None else goal.rssi_b_dbm + HOLD_MARGIN_DB
        return (
            _zero(out, DriveState.STOPPED, "retreat_hold"),
            replace(_end(m, "arrived"), floor_dbm=floor, anchor=(goal.x_mm, goal.y_mm)),
        )
    if _rear_blind(sonar_mm):
        return _zero(
            out, DriveState.STOPPED, "rear_blocked"
        ), m  # never back blind; the time limit runs
    nxt = trail[-1]
    speed = min(SPEED_MM_S, remaining_m * 1000.0 / TAPER_S)
    left, right, why = reverse_toward(
        ci.odom,
        nxt,
        speed,
        sonar_mm,
        threshold_o_m=p.threshold_o_m,
        stop_distance_m=p.stop_distance_m,
        gamma_o_m=p.gamma_o_m,
        turn_gain_mm_s_deg=3.0,
    )
    reason = "retreat" if why == "retrace" else why
    state = DriveState.STOPPED if left == 0.0 and right == 0.0 else DriveState.RECOVERING
    return ControlOutput(left, right, state, reason, out.situation, out.memory), m
