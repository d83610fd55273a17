"""The relay brain: one pure state machine from events to actions (sans-IO, like h11).

`Brain.handle(event) -> list[Action]` is the whole decision core of a relay: it keeps what
the robot knows, runs the stages of OVERRIDE_ORDER (the law, the retreat, recovery, the
fail-safes) on every SIP and timer tick, and hands scans, the link behind and the trail to
their own rooms (core/scan/memory.py, core/link/rear.py, core/trail), each the one writer
of its memory. No I/O, no clock: the time is in each event, so the same events give the
same actions on a robot, in the simulator and in a test. Its own decisions (stale inputs,
a robot that reports itself down) are in docs/CONTROL.md section 6.2.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import NamedTuple, assert_never

from relayd.core.avoid.ring import rear_readings
from relayd.core.control.law import (
    ControlInputs,
    ControlMemory,
    ControlOutput,
    control_step,
    within_v_max,
)
from relayd.core.control.rangecue import known_front, leader_floor_m
from relayd.core.events import (
    Action,
    Decision,
    DeviceEvent,
    DeviceStatus,
    DriveCommand,
    Event,
    LeaderPath,
    LinkEvent,
    LinkSide,
    ModeCommand,
    RecoveryReport,
    RssiEvent,
    ScanDone,
    ScanReady,
    ScanSampleEvent,
    ServoPosition,
    Shutdown,
    SipEvent,
    Tick,
    WheelCommand,
)
from relayd.core.geometry import SONAR_COUNT
from relayd.core.link.model import LinkModel
from relayd.core.link.rear import RearLinkMemory
from relayd.core.link.retreat import RetreatMemory
from relayd.core.params import BrainParams
from relayd.core.plan.navigator import Navigator
from relayd.core.recovery.machine import recovery_step
from relayd.core.recovery.state import (
    RecoveryInputs,
    RecoveryMemory,
    RecoveryOutput,
    RecoveryParams,
)
from relayd.core.recovery.view import RecoveryView, recovery_view
from relayd.core.scan.estimator import front_readings
from relayd.core.scan.memory import ScanMemory
from relayd.core.trail.keeper import TrailKeeper
from relayd.core.vocab import DriveState, Mode, Reason

#: Device names the brain listens to in `DeviceEvent`s.
ROBOT, PANTILT = "robot", "pantilt"


class Brain:
    """Events in, actions out. Not thread-safe, not async: call `handle` in event order."""

    def __init__(
        self, params: BrainParams, *, mode: Mode = Mode.FOLLOW, link_model: LinkModel | None = None
    ) -> None:
        self.params = params
        self._mode = Mode(mode)
        self._manual: tuple[float, float, float] | None = None
        self._halted = False
        self._sip_t: float | None = None
        self._heading: float | None = None
        self._robot_down = False
        self._sonar: list[int | None] = [None] * SONAR_COUNT
        #: Odometry pose of the latest SIP (mm, mm, deg): the obstacle escape's progress
        #: watchdog and limits (relayd/core/avoid/escape.py) and the recovery's breadcrumbs.
        self._pose: tuple[float, float, float] | None = None
        self._rssi_fresh_t: float | None = None
        self._servo_ok = not params.has_scanner
        #: The sweep in progress, the bearing memory of the scans, leader-lost (relayd/core/scan/memory.py).
        self.scans = ScanMemory(params.scan, params.estimator, params.leader)
        #: RSSI^b, the link model (`link_model`: a set-up seam), the retreat (core/link/rear.py).
        self.rear = RearLinkMemory(params.control, params.link, params.rear_station_mac, link_model)
        self._memory = ControlMemory()
        self.last_output: ControlOutput | None = None
        # Breadcrumbs and the recovery episode (relayd.core.recovery.machine).
        self.recovery = RecoveryMemory()
        self._recovery_shown: RecoveryView | None = None
        #: The leader's estimated position and trail (relayd/core/trail), fed by each scan.
        self.trail = TrailKeeper(params.trail)
        self.nav = Navigator(params.nav)  # the sonar map, the detour round it (core/plan)

    # -- read-only views (the API's shell checks a drive command against the mode) ------

    @property
    def link_model(self) -> LinkModel:
        return self.rear.model

    @property
    def retreat(self) -> RetreatMemory:
        return self.rear.retreat

    @property
    def mode(self) -> Mode:
        return self._mode

    @property
    def leader_lost(self) -> bool:
        return self.scans.leader_lost

    @property
    def servo_ok(self) -> bool:
        return self._servo_ok

    def trail_json(self) -> dict[str, object]:
        """/status's `trail`: the trail's view and the detour in force (core/plan)."""
        return {**self.trail.view().to_json(), "detour_m": self.nav.path_json()}

    # -- the one entry point ------------------------------------------------------------

    # Complexity: one case per event type of the union (a type switch, exhaustive by assert_never).
    def handle(self, event: Event) -> list[Action]:  # noqa: C901
        match event:
            case SipEvent():
                return self._on_sip(event)
            case Tick():
                return self.rear.view(event.t) + self._step(event.t, None)
            case RssiEvent():
                s = event.sample
                if s.fresh and s.rssi_dbm is not None and math.isfinite(s.rssi_dbm):
                    self._rssi_fresh_t = s.t
                return []
            case ScanReady():
                return self.scans.ready(
                    event.t, self._heading, self._mode is Mode.FOLLOW, self._servo_ok
                )
            case ScanSampleEvent():
                self.scans.sample(event, self._heading)
                return []
            case ScanDone():
                count = self.scans.count
                actions = self.scans.done(event, self._heading, self._sonar)
                if self.scans.count != count:
                    self._trail_scan(event.t)
                return actions
            case LinkEvent():
                return self._on_link(event)
            case DeviceEvent():
                return self._on_device(event)
            case ModeCommand():
                self._mode = Mode(event.mode)
                self._manual = None
                return self._step(event.t, None)
            case DriveCommand():
                sum_mm_s = event.left_mm_s + event.right_mm_s  # NaN or inf if either is
                if self._mode is not Mode.MANUAL or not math.isfinite(sum_mm_s):
                    return []  # the API's shell refuses these before they get here
                self._manual = (float(event.left_mm_s), float(event.right_mm_s), event.t)
                return self._step(event.t, None)
            case Shutdown():
                self._halted = True
                return self._step(event.t, None)
            case ServoPosition():
                return []
            case LeaderPath():
                self.trail.leader_path(event)  # the trail the pursuit follows while it is up
                return []
            case _:
                # mypy names the event type a new handler is missing for (STYLE: exhaustive).
                assert_never(event)

    def _on_sip(self, ev: SipEvent) -> list[Action]:
        self._sip_t = ev.t
        self._heading = ev.sip.theta_deg
        self._pose = (ev.sip.x_mm, ev.sip.y_mm, ev.sip.theta_deg)
        self.trail.own_pose(ev.t, self._pose)
        self._robot_down = False
        if len(ev.sonar_mm) == SONAR_COUNT:
            self._sonar = list(ev.sonar_mm)
        else:
            for index, range_mm in ev.sip.sonar:
                if 0 <= index < SONAR_COUNT:
                    self._sonar[index] = range_mm
        self.nav.sonar(ev.t, self._pose, ev.sip.sonar, self.trail.leader_xy_m)  # its echo: unmapped
        return self._step(ev.t, ev.t)

    def _on_device(self, ev: DeviceEvent) -> list[Action]:
        up = ev.status is DeviceStatus.UP
        if ev.device == ROBOT:
            self._robot_down = not up
            return self._step(ev.t, None)
        if ev.device == PANTILT:
            was_ok, self._servo_ok = self._servo_ok, up
            actions = self._step(ev.t, None)
            if up and not was_ok:  # the scanner may have been waiting for the servo
                actions.extend(self.scans.servo_up(ev.t, self._heading, self._mode is Mode.FOLLOW))
            return actions
        return []

    def _on_link(self, ev: LinkEvent) -> list[Action]:
        if ev.side is not LinkSide.REAR:
            return []
        return self.rear.on_poll(ev, self._pose)

    def _trail_scan(self, now: float) -> None:
        """A finished scan into the leader estimate and its trail."""
        bearing = self.scans.bearing_now(now, self._heading)
        sd = self.scans.model.sd_deg(now, self._heading)
        floor = None if bearing is None else leader_floor_m(known_front(self._sonar), bearing, sd)
        self.trail.scan(now, self._pose, bearing, sd, self.scans.rssi_leader_dbm, floor)

    # -- the control step -----------------------------------------------------------------

    def inputs(self, now: float) -> ControlInputs:
        p = self.params.control
        sip_age = None if self._sip_t is None else now - self._sip_t
        if self._robot_down and sip_age is not None:
            sip_age = max(sip_age, p.sip_timeout_s + 1e-6)
        heading = self._heading
        manual_l = manual_r = manual_age = None
        if self._manual is not None:
            manual_l, manual_r, t = self._manual
            manual_age = now - t
        bearing = self.scans.bearing_now(now, heading)
        floor = (
            leader_floor_m(known_front(self._sonar), bearing, self.scans.model.sd_deg(now, heading))
            if p.leader_gap_max_m > 0
            else None
        )
        pursuit = (
            self.trail.steer(now, self._pose, front_readings(self._sonar))
            if self.params.trail.pursuit == "trail"
            else None
        )
        goal = self.trail.goal_xy(self._pose, bearing) if self._mode is Mode.FOLLOW else None
        detour = self.nav.steer(now, self._pose, goal)  # round the sonar map (core/plan)
        return ControlInputs(
            mode=self._mode,
            sip_age_s=sip_age,
            rssi_age_s=None if self._rssi_fresh_t is None else now - self._rssi_fresh_t,
            scan_servo_ok=self._servo_ok,
            bearing_deg=bearing,
            prev_bearing_deg=self.scans.prev_bearing_now(heading),
            rssi_leader_dbm=self.scans.rssi_leader_dbm,
            rssi_behind_dbm=self.rear.dbm,
            rear_age_s=None if self.rear.t is None else now - self.rear.t,
            front_sonar=front_readings(self._sonar),
            leader_lost=self.scans.lost(now, heading, self._mode is Mode.FOLLOW),
            manual_left_mm_s=manual_l,
            manual_right_mm_s=manual_r,
            manual_age_s=manual_age,
            t_s=now,
            odom=self._pose,
            rear_sonar=rear_readings(self._sonar),
            leader_floor_m=floor,
            search_bearing_deg=self.scans.model.search_bearing(now, heading),
            trail_steer_deg=None if pursuit is None else pursuit.steer_deg,
            trail_caught_up=pursuit is not None and pursuit.caught_up,
            trail_remaining_m=None if pursuit is None else self.trail.remaining_m(self._pose),
            detour_steer_deg=None if detour is None else detour.steer_deg,
        )

    def _decide(self, now: float) -> ControlOutput:
        """The override order (OVERRIDE_ORDER): each stage may replace the command before it."""
        situation = self.last_output.situation if self.last_output is not None else 0
        if self._halted:
            return ControlOutput(0.0, 0.0, DriveState.STOPPED, "shutdown", situation, self._memory)
        out: ControlOutput | None = None
        for stage, error in OVERRIDE_ORDER:
            try:
                out = stage(self, now, out)
            except Exception as exc:  # noqa: BLE001 - a bug or bad data in the brain stops the robot
                return ControlOutput(
                    0.0,
                    0.0,
                    DriveState.FAULT,
                    f"{error}: {type(exc).__name__}",
                    situation if out is None else out.situation,
                    self._memory if out is None else out.memory,
                )
        assert out is not None  # OVERRIDE_ORDER starts with the control law
        return out

    def stage_control(self, now: float, _: ControlOutput | None) -> ControlOutput:
        """The paper's law, then the retreat to where the link held (relayd.core.link.retreat)."""
        ci = self.inputs(now)
        out = control_step(ci, self.rear.in_force(), self._memory)
        return self.rear.retreat_step(ci, tuple(self._sonar), out)

    def stage_recovery(self, now: float, out: ControlOutput | None) -> ControlOutput:
        """The recovery seam: an episode's command replaces the follow controller's (never a fault)."""
        assert out is not None
        rp = self.params.recovery
        if not rp.enabled:
            return out
        if rp.control is not self.rear.control:
            # One rear limit: recovery judges by the params the controller drives by (the
            # adaptive limit once learned), so a backup ends where following may resume.
            rp = replace(rp, control=self.rear.control)
        res = self._recovery_step(now, rp, (out.left_mm_s + out.right_mm_s) / 2.0)
        self.recovery = res.memory
        cmd = res.command
        if cmd is None or out.state is DriveState.FAULT:
            return out
        return ControlOutput(
            cmd.left_mm_s, cmd.right_mm_s, cmd.state, cmd.reason, out.situation, out.memory
        )

    def stage_fail_safes(self, now: float, out: ControlOutput | None) -> ControlOutput:
        """No wheel moves on a scan that stopped arriving (the servo or the RSSI stream died);
        no wheel beyond v_max, whichever stage commanded it (law.within_v_max)."""
        assert out is not None
        if (out.left_mm_s or out.right_mm_s) and self.scans.stale(now, self._mode is Mode.FOLLOW):
            return ControlOutput(
                0.0, 0.0, DriveState.FAULT, "scan_stale", out.situation, out.memory
            )
        return within_v_max(out, self.rear.control)

    def _recovery_step(self, now: float, rp: RecoveryParams, forward_mm_s: float) -> RecoveryOutput:
        return recovery_step(
            RecoveryInputs(
                following=self._mode is Mode.FOLLOW and not self._halted,
                pose=self._pose,
                sip_age_s=None if self._sip_t is None or self._robot_down else now - self._sip_t,
                rssi_age_s=None if self._rssi_fresh_t is None else now - self._rssi_fresh_t,
                scan_age_s=None if self.scans.last_scan_t is None else now - self.scans.last_scan_t,
                rear_age_s=None if self.rear.t is None else now - self.rear.t,
                leader_lost=self.leader_lost,
                rssi_leader_dbm=self.scans.rssi_leader_dbm,
                rssi_behind_dbm=self.rear.dbm,
                scan_count=self.scans.count,
                sonar_mm=tuple(self._sonar),
                now_s=now,
                rear_polls=self.rear.polls,
                forward_mm_s=forward_mm_s,
            ),
            rp,
            self.recovery,
        )

    def _recovery_report(self, now: float) -> list[Action]:
        if not self.params.recovery.enabled:
            return []
        view = recovery_view(self.recovery, self.params.recovery, now)
        if view == self._recovery_shown:
            return []
        self._recovery_shown = view
        return [RecoveryReport(view)]

    def _step(self, now: float, sip_t: float | None) -> list[Action]:
        out = self._decide(now)
        self._memory = out.memory
        prev, self.last_output = self.last_output, out
        actions: list[Action] = []
        if not self._halted:
            if out.left_mm_s == 0.0 and out.right_mm_s == 0.0:
                # The urgent stop goes out on the transition to zero; while stopped, the
                # driver keeps reflecting zero, so the serial line is not flooded.
                if prev is None or prev.left_mm_s != 0.0 or prev.right_mm_s != 0.0:
                    actions.append(WheelCommand(0.0, 0.0, True, sip_t))
            else:
                actions.append(WheelCommand(out.left_mm_s, out.right_mm_s, False, sip_t))
        changed = prev is None or prev.state is not out.state or prev.reason != out.reason
        wheels = (out.left_mm_s, out.right_mm_s, out.state, out.reason, out.situation)
        actions.append(Decision(now, *wheels, self._mode, changed))
        actions.extend(self._recovery_report(now))
        return actions


#: One stage of the override order: the brain, the time, the command so far -> the command.
Stage = Callable[["Brain", float, "ControlOutput | None"], "ControlOutput"]


#: Who decides the wheels, in order: each stage may replace the command of the ones before
#: it, and a stage that raises stops the wheels with its error reason. The fail-safes come
#: last, so nothing overrides them (docs/CONTROL.md section 6).
class StageRow(NamedTuple):
    stage: Stage
    reason: Reason  # the fault's reason when the stage raises


OVERRIDE_ORDER: tuple[StageRow, ...] = (
    StageRow(Brain.stage_control, Reason.CONTROLLER_ERROR),  # the paper's law, then the retreat
    StageRow(Brain.stage_recovery, Reason.RECOVERY_ERROR),  # a recovery episode replaces it
    StageRow(Brain.stage_fail_safes, Reason.CONTROLLER_ERROR),  # a stale scan stops every motion
)

__all__ = ["OVERRIDE_ORDER", "PANTILT", "ROBOT", "Brain", "BrainParams", "Stage", "StageRow"]
