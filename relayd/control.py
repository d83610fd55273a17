"""The control task: run the pure controller on every SIP and command the wheels.

The controller is evaluated synchronously inside the robot driver's SIP callback, so a
wheel command follows the data that caused it with no queue in between (the control
latency the benchmarks measure). A periodic tick runs the same step when SIPs stop
arriving: silence is exactly when the robot must be stopped, and no SIP callback
would fire to do it. The tick also marks the loop alive for /healthz and the systemd
watchdog.

Manual mode and mode changes come from the API through the `Controls` methods here.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import structlog

from drivers.clock import REAL_CLOCK, Clock
from relayd.controller import (
    ControlInputs,
    ControlMemory,
    ControlOutput,
    ControlParams,
    control_step,
)
from relayd.estimator import front_readings
from relayd.ring import rear_readings
from relayd.state import DriveState, Mode, ModeError, RelayState

log = structlog.get_logger(__name__)


class SipView(Protocol):
    @property
    def t(self) -> float: ...
    @property
    def theta_deg(self) -> float: ...
    @property
    def x_mm(self) -> float: ...
    @property
    def y_mm(self) -> float: ...


class SonarView(Protocol):
    @property
    def ranges_mm(self) -> Sequence[int | None]: ...


class WheelBase(Protocol):
    """What the loop needs of the robot driver (drivers.arcos.ArcosRobot, or a test double)."""

    @property
    def last_sip(self) -> SipView | None: ...
    @property
    def stale(self) -> bool: ...
    @property
    def sonar(self) -> SonarView: ...
    def add_listener(self, cb: Callable[[Any], None]) -> Callable[[], None]: ...
    def stop(self) -> None: ...
    def set_wheels(self, left_mm_s: float, right_mm_s: float) -> None: ...


class BearingSource(Protocol):
    """What the loop needs of the scanner (relayd.scanner.Scanner)."""

    @property
    def servo_ok(self) -> bool: ...
    @property
    def leader_lost(self) -> bool: ...
    @property
    def bearing_deg(self) -> float | None: ...
    @property
    def bearing_heading_deg(self) -> float | None: ...
    @property
    def prev_bearing_deg(self) -> float | None: ...
    @property
    def prev_heading_deg(self) -> float | None: ...


class RssiFreshness(Protocol):
    def age_s(self, now: float) -> float | None: ...


class ControlLoop:
    """Glue between the robot driver, the scanner's latest estimate and the pure controller."""

    def __init__(
        self,
        *,
        robot: WheelBase | None,
        scanner: BearingSource | None,
        monitor: RssiFreshness | None,
        state: RelayState,
        params: ControlParams,
        clock: Clock = REAL_CLOCK,
        tick_s: float = 0.1,
        rear_rssi: Callable[[], tuple[float | None, float | None]] | None = None,
        on_latency: Callable[[float], None] | None = None,
    ) -> None:
        self._robot = robot
        self._scanner = scanner
        self._monitor = monitor
        self._state = state
        self._params = params
        self._clock = clock
        self._tick_s = tick_s
        self._rear = rear_rssi or (lambda: (None, None))
        self._on_latency = on_latency
        self._memory = ControlMemory()
        self._manual: tuple[float, float, float] | None = None
        self._halted = False
        self._remove_listener: Callable[[], None] | None = None
        self.last_output: ControlOutput | None = None

    # -- Controls (called by the API) -------------------------------------------------

    def set_mode(self, mode: Mode) -> None:
        if mode is not self._state.mode:
            log.info("mode_changed", old=str(self._state.mode), new=str(mode))
        self._state.mode = Mode(mode)
        self._manual = None
        self.step()

    def manual_drive(self, left_mm_s: float, right_mm_s: float) -> None:
        if self._state.mode is not Mode.MANUAL:
            raise ModeError(f"drive commands need manual mode (mode is {self._state.mode})")
        if not (math.isfinite(left_mm_s) and math.isfinite(right_mm_s)):
            raise ValueError("wheel speeds must be finite")
        self._manual = (float(left_mm_s), float(right_mm_s), self._clock.now())
        self.step()

    def halt(self) -> None:
        """Shutdown: never command the wheels again; the robot driver's safe stop follows.

        Synchronous on purpose: a SIP arriving while the driver writes VEL 0, ENABLE 0
        and CLOSE must not slip a non-zero VEL in between, and cancelling the task only
        takes effect at its next await.
        """
        self._halted = True
        if self._remove_listener is not None:
            self._remove_listener()
            self._remove_listener = None

    # -- the loop -----------------------------------------------------------------------

    def on_sip(self, _sip: object) -> None:
        started = time.perf_counter()
        self.step()
        if self._on_latency is not None:
            self._on_latency(time.perf_counter() - started)

    async def run(self) -> None:
        """The periodic tick; also registers the SIP callback."""
        if self._robot is not None and not self._halted:
            self._remove_listener = self._robot.add_listener(self.on_sip)
        try:
            while True:
                self.step()
                await self._clock.sleep(self._tick_s)
        finally:
            if self._remove_listener is not None:
                self._remove_listener()
                self._remove_listener = None

    def inputs(self, now: float) -> ControlInputs:
        robot, scanner, st = self._robot, self._scanner, self._state
        sip = robot.last_sip if robot is not None else None
        sip_age = None if sip is None else now - sip.t
        if robot is not None and robot.stale and sip_age is not None:
            sip_age = max(sip_age, self._params.sip_timeout_s + 1e-6)
        heading = None if sip is None else sip.theta_deg
        ranges = list(robot.sonar.ranges_mm) if robot is not None else [None] * 16
        bearing = prev = None
        lost = False
        servo_ok = True
        if scanner is not None:
            servo_ok = scanner.servo_ok
            lost = scanner.leader_lost
            bearing = _in_current_frame(scanner.bearing_deg, scanner.bearing_heading_deg, heading)
            prev = _in_current_frame(scanner.prev_bearing_deg, scanner.prev_heading_deg, heading)
        rssi_age = self._monitor.age_s(now) if self._monitor is not None else None
        rssi_b, rear_t = self._rear()
        manual_l = manual_r = manual_age = None
        if self._manual is not None:
            manual_l, manual_r, t = self._manual
            manual_age = now - t
        return ControlInputs(
            mode=st.mode,
            sip_age_s=sip_age,
            rssi_age_s=rssi_age,
            scan_servo_ok=servo_ok,
            bearing_deg=bearing,
            prev_bearing_deg=prev,
            rssi_leader_dbm=st.rssi_leader_dbm,
            rssi_behind_dbm=rssi_b,
            rear_age_s=None if rear_t is None else now - rear_t,
            front_sonar=front_readings(ranges),
            leader_lost=lost,
            manual_left_mm_s=manual_l,
            manual_right_mm_s=manual_r,
            manual_age_s=manual_age,
            t_s=now,
            odom=None if sip is None else (sip.x_mm, sip.y_mm, sip.theta_deg),
            rear_sonar=rear_readings(ranges),
        )

    def step(self) -> ControlOutput:
        now = self._clock.now()
        if self._halted:
            out = ControlOutput(0.0, 0.0, DriveState.STOPPED, "shutdown", self._state.situation, self._memory)
            self._apply(out, now)
            return out
        try:
            out = control_step(self.inputs(now), self._params, self._memory)
        except Exception as exc:
            # The controller is pure and tested, but a robot with a bug in its brain stops.
            log.exception("controller_error")
            out = ControlOutput(0.0, 0.0, DriveState.FAULT, f"controller_error: {type(exc).__name__}",
                                self._state.situation, self._memory)
        self._memory = out.memory
        self._apply(out, now)
        return out

    def _apply(self, out: ControlOutput, now: float) -> None:
        robot, st = self._robot, self._state
        prev = self.last_output
        if robot is not None and not self._halted:
            if out.left_mm_s == 0.0 and out.right_mm_s == 0.0:
                # The urgent stop goes out on the transition to zero; while stopped, the
                # driver keeps reflecting zero (PULSE), so the serial line is not flooded.
                if prev is None or prev.left_mm_s != 0.0 or prev.right_mm_s != 0.0:
                    robot.stop()
            else:
                robot.set_wheels(out.left_mm_s, out.right_mm_s)
        self.last_output = out
        st.loop_tick_t = now
        st.wheels_left_mm_s = out.left_mm_s
        st.wheels_right_mm_s = out.right_mm_s
        st.situation = out.situation
        if prev is None or prev.state is not out.state or prev.reason != out.reason:
            log.info("drive_state", state=str(out.state), reason=out.reason,
                     left_mm_s=round(out.left_mm_s, 1), right_mm_s=round(out.right_mm_s, 1))
            st.state = out.state
            st.reason = out.reason
            st.touch()


def _in_current_frame(bearing: float | None, heading_then: float | None, heading_now: float | None) -> float | None:
    """A bearing measured in an earlier robot frame, seen from the robot's heading now."""
    if bearing is None:
        return None
    if heading_then is None or heading_now is None:
        return bearing
    b = bearing - (heading_now - heading_then)
    return (b + 180.0) % 360.0 - 180.0
