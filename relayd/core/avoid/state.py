"""The escape's vocabulary: its modes, settings, memory, one step's view and verdict.

relayd/core/avoid/escape.py is the state machine that reads and writes these; they live here
so that the machine reads as its transitions alone. `AvoidState` is the whole memory
of an escape: the caller keeps it (ControlMemory.avoid) and hands it back, so each
step stays pure.

Every command of the escape goes through `Actuator`, so what leaves it is exactly what
VEL (1 mm/s) and RVEL (1 deg/s) can say and a turn in place is at least
`min_turn_deg_s`; and through `guard`, the last line: no forward motion toward an echo
nearer than the stop distance in the robot's path, no reversing without the rear
sonars, no turn in place toward a near side or with anything inside the circle the
corners sweep. `turn_cmd` and `drive_cmd` are those two steps for a turn in place and a
drive; the back-offs in relayd/core/avoid/escape.py call the same guard.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import StrEnum

from relayd.core.avoid.ring import guard
from relayd.core.control.actuator import Actuator
from relayd.core.scan.estimator import SonarReading


class AvoidMode(StrEnum):
    FOLLOW = "follow"
    BACKOFF = "backoff"
    LANE = "lane"
    TURN = "turn"
    WALL = "wall"
    CORNER = "corner"
    ALIGN = "align"
    BLOCKED = "blocked"
    DOOR = "door"


@dataclass(frozen=True, slots=True)
class AvoidParams:
    """The escape's settings; distances in metres, speeds in mm/s, turns in deg/s.
    stop_distance_m and threshold_o_m are overwritten from ControlParams."""

    stop_distance_m: float = 0.3
    threshold_o_m: float = 0.8
    no_progress_s: float = 4.0
    progress_m: float = 0.1
    turn_rate_deg_s: float = 20.0
    backoff_below_m: float = 0.5  # hit closer than this: back off first, to have room to turn
    backoff_to_m: float = 1.4
    backoff_max_m: float = 1.2
    backoff_speed_mm_s: float = 100.0
    unjam_m: float = 0.3  # back-off when a turn in place has no room
    lane_detect_m: float = (
        1.5  # a boundary this close abeam on the free side: a passage, not open ground
    )
    lane_margin_m: float = 0.12  # footprint to that boundary while changing lanes
    lane_min_shift_m: float = 0.3
    lane_speed_mm_s: float = 100.0
    lane_gain_deg_per_m: float = 150.0
    lane_max_deg: float = 35.0
    wall_speed_mm_s: float = 150.0
    wall_gap_m: float = 0.3  # footprint side to the followed boundary
    wall_gain_deg_s_per_m: float = 60.0
    wall_angle_gain: float = 1.0  # deg/s of turn per degree the boundary runs off the heading
    fit_range_m: float = 1.2  # echoes beyond this on the wall side: the boundary is lost
    front_clear_m: float = 0.45  # forward sonars beyond this: the way ahead is open
    corner_run_m: float = 0.45
    leave_clear_m: float = 1.2
    leave_progress_m: float = 0.2  # along the leader's line beyond the hit point (Bug2)
    door_progress_m: float = -0.3  # ... through an opening abeam: a door level with the hit point
    door_run_m: float = 0.3  # run on along an opening abeam before turning into it (its middle)
    turn_clear_m: float = 1.5  # a turn in place goes on until the front is this open ...
    turn_max_deg: float = 100.0  # ... or it has turned this far with the front merely clear
    align_tol_deg: float = 5.0
    tie_m: float = 0.05
    episode_clear_s: float = 8.0  # free this long after an escape: the next obstacle is a new one
    #: A stop for a lost leader keeps the escape's episode (its side, hit point and
    #: spending), not its manoeuvre: turned away from the leader while going round, the
    #: antenna loses it, and an escape that forgot the U it was in drives back into it.
    #: False: every stop starts the escape afresh.
    keep_episode_when_lost: bool = True
    #: The leader lost mid-manoeuvre (turned away from it while going round): the
    #: manoeuvre goes on this long toward where the scans last put it; 0: it stops.
    lost_manoeuvre_s: float = 5.0
    #: A turn in place the guard refuses, with no room to back off or for a wall along a
    #: side: creep on along an arc away from that side until the corners have room (an
    #: ALIGN that cannot, with the way ahead open: straight on; relayd/core/avoid/unpin.py).
    #: False: back off along the wall, go round, or hold, as before.
    unpin: bool = True
    max_escape_s: float = 300.0
    max_escape_m: float = 40.0
    max_turn_deg: float = 1080.0
    #: The escape never takes the robot further than this from where it last took over
    #: from the paper's law (the doorway room's far corner is 5.2 m from its door wall):
    #: what needs more is not an obstacle to go round.
    max_stray_m: float = 6.0
    #: A BLOCKED escape starts afresh after this wait (s), doubling at each block of the
    #: same run of escapes up to blocked_retry_max_s, while the scans go on: in a building
    #: the leader moves on and the way to it changes. 0: it holds until the leader is
    #: ahead and its way open, or the operator.
    blocked_retry_s: float = 10.0
    blocked_retry_max_s: float = 80.0
    #: A leader this far off the nose is not beyond what blocks the way ahead: the escape
    #: turns onto it first (ALIGN) instead of going round the obstacle.
    align_first_deg: float = 60.0
    #: ... nor is it when the leader's own direction is open, this far or more off the
    #: nose: a corridor's mouth seen from beside its jamb (generated corridors 141: the
    #: escape went round the jamb, back up the hall it came down). 0: off.
    align_open_deg: float = 15.0
    #: A hit by an echo beside the way (the forward sonars at +-10 and +-30 deg see beyond
    #: backoff_to_m): the escape starts with its turn (or a lane change), backing off only
    #: the unjam's 0.3 m, or creeping off a wall along the side, where the turn has no
    #: room. A back-off is for room ahead, and there is room ahead; in a corridor the 50
    #: deg sonars never see backoff_to_m, so the back-off ran its whole 1.2 m (12 s) at
    #: every graze. False: back off as for any hit.
    beside_turn: bool = True
    #: The door passage (relayd/core/avoid/door.py): through a gap at least the robot's
    #: width plus door_margin_m, jambs within door_side_m each side, the way on open
    #: beyond door_ahead_m, the leader within door_bearing_deg of the nose; at
    #: door_speed_mm_s, steering for the gap's middle. False: the paper's law slows to a
    #: stop in a narrow door and the escape goes round it.
    door_pass: bool = False
    door_margin_m: float = 0.2
    #: The escape leaves for the leader when the lane toward it (the robot's width plus
    #: leave_lane_margin_m each side, leave_clear_m long) holds no echo (ring.lane_clear), not
    #: only when every sonar within 25 degrees of it sees beyond leave_clear_m (a corridor
    #: wall 0.65 m off fails that for ever, and the escape follows the corridor to its end).
    leave_by_lane: bool = False
    leave_lane_margin_m: float = 0.1
    #: A lane change is past its obstacle once the obstacle side's sonars see this much
    #: beyond the nearest the obstacle came abeam (or leave_clear_m, if nearer): a 2 m
    #: corridor's far wall is never leave_clear_m away from a robot that kept to the lane.
    #: 0: leave_clear_m alone (as before).
    lane_pass_margin_m: float = 0.5
    door_side_m: float = 0.8
    door_ahead_m: float = 0.6
    door_bearing_deg: float = 40.0
    door_speed_mm_s: float = 120.0
    door_gain_deg_s_per_m: float = 100.0
    door_max_deg_s: float = 15.0


@dataclass(frozen=True, slots=True)
class AvoidState:
    """Everything the escape needs from one step to the next; the caller keeps it
    (ControlMemory.avoid) and hands it back, so the step stays pure."""

    mode: AvoidMode = AvoidMode.FOLLOW
    side: int = 0  # +1 turns left (obstacle on the right), -1 right; 0: no episode
    mode_t: float = 0.0
    anchor: tuple[float, float] | None = None  # where the robot last made progress (mm)
    anchor_t: float = 0.0
    escape_t: float | None = None  # start of the current escape episode
    path_m: float = 0.0
    turned_deg: float = 0.0
    goal_deg: float = 0.0  # odometry heading of the leader when the obstacle was hit
    hit_proj_m: float = 0.0
    hit_at: tuple[float, float] | None = None  # where the escape last took over from FOLLOW (mm)
    last_pose: tuple[float, float, float] | None = None
    lost_at: tuple[float, float] | None = None  # WALL: where the boundary was lost
    corner_heading_deg: float | None = None
    clear_since_t: float | None = None
    backoff_from: tuple[float, float] | None = None
    backoff_len_m: float = 0.0  # how far this back-off may go
    after_backoff: AvoidMode = AvoidMode.TURN  # where a back-off hands over
    unjam: bool = False  # this back-off makes room to turn: it runs its length whatever is ahead
    lane_ref: tuple[float, float, float] | None = None  # pose where the lane change began
    lane_beside: bool = False  # LANE (leave_by_lane): the obstacle has been abeam
    lane_near_m: float | None = None  # LANE: the nearest the obstacle side came abeam (m)
    mode_heading_deg: float = 0.0  # odometry heading when the current mode began
    had_wall: bool = False  # WALL: the boundary has been in reach since WALL began
    opening_at: tuple[float, float] | None = None  # WALL: where an opening abeam began
    retry_wait_s: float = 0.0  # the last BLOCKED wait before a fresh escape; 0: none yet


@dataclass(frozen=True, slots=True)
class Sense:
    """One step's view: time, odometry pose (mm, mm, deg), sonars, leader bearing."""

    t_s: float
    pose: tuple[float, float, float]
    sonar: tuple[SonarReading, ...]
    bearing_deg: float  # leader, robot frame, ccw +
    rear: tuple[SonarReading, ...] = ()  # the rear ring; without it the robot never reverses


@dataclass(frozen=True, slots=True)
class AvoidCommand:
    """The step's verdict: follow the paper's law (`follow`), or this (VEL, RVEL) and why."""

    follow: bool
    vel_mm_s: int = 0
    rvel_deg_s: int = 0
    reason: str = "driving"


@dataclass(frozen=True, slots=True)
class StepView:
    """One step's inputs and what every handler derives from them."""

    s: Sense
    p: AvoidParams
    act: Actuator
    r: dict[float, float]  # the front ring by heading (m)
    d_min_m: float  # nearest forward echo
    t: float


#: A handler's verdict: the command, or the handler that decides this same step instead.
Verdict = tuple[AvoidState, "AvoidCommand | AvoidMode"]


def episode_only(st: AvoidState, t_s: float | None, p: AvoidParams) -> AvoidState:
    """The escape's episode without its manoeuvre (AvoidParams.keep_episode_when_lost): the
    side it goes round on, where it hit and toward what, and what it has spent (its limits
    still bound it); it resumes in FOLLOW, and the next hit goes on round the same way.
    Nothing when off, without a time, or past max_escape_s (resumed, it would be "blocked")."""
    if not p.keep_episode_when_lost or st.escape_t is None or t_s is None:
        return AvoidState()
    if t_s - st.escape_t > p.max_escape_s:
        return AvoidState()
    return AvoidState(
        retry_wait_s=st.retry_wait_s,
        escape_t=st.escape_t,
        side=st.side,
        goal_deg=st.goal_deg,
        hit_proj_m=st.hit_proj_m,
        hit_at=st.hit_at,
        path_m=st.path_m,
        turned_deg=st.turned_deg,
    )


def enter(st: AvoidState, mode: AvoidMode, t: float, **changes: object) -> AvoidState:
    """`st` in `mode` from time `t`, with `changes` to its other fields."""
    return replace(st, mode=mode, mode_t=t, **changes)  # type: ignore[arg-type]


def turn_cmd(act: Actuator, s: Sense, p: AvoidParams, rvel: float, reason: str) -> AvoidCommand:
    """A turn in place at `rvel` deg/s, as the actuator and the guard allow it."""
    vel, rv = guard(0, act.turn(rvel), s.sonar, p.stop_distance_m, s.rear)
    if rv == 0:
        # Neither turning that way nor driving is safe: hold, and the next steps decide.
        return AvoidCommand(False, 0, 0, "blocked")
    return AvoidCommand(False, vel, rv, reason)


def drive_cmd(act: Actuator, s: Sense, p: AvoidParams, vel: float, rvel: float) -> AvoidCommand:
    """Drive at (`vel` mm/s, `rvel` deg/s), as the actuator and the guard allow it."""
    v, rv = guard(*act.express(vel, rvel), s.sonar, p.stop_distance_m, s.rear)
    return AvoidCommand(False, v, rv, "avoiding")
