"""The control shell: the robot's SIPs and the operator's requests in, wheel commands out.

Thin I/O around the brain (`relayd.core.brain`), which decides everything:

- every SIP the ARCOS driver decodes is published on the bus as a `SipEvent`, from
  the driver's own callback, so the brain's step and the wheel command it causes run
  on the SIP's stack with no queue in between (the control latency);
- a timer publishes a `Tick` every `tick_s`, because silence (no SIP) is exactly when
  the robot must be stopped and no SIP would arrive to do it. A tick that wakes late
  (the process held up: a GC pause, a starved CPU) first lets the input that waited
  with it be read, so it judges the robot silent only if the robot was; before it, every
  device's state is looked at and changes are published as `DeviceEvent`s: UP, DOWN,
  or FAULT when its driver's health says the last attempt failed. A fault the
  supervisor reports (a device's task failed and is restarted) comes in through
  `report_fault`. FAULT holds until the device is up again (a faulted device that is
  still down is not re-announced as merely DOWN);
- the API's mode and drive requests (`Controls`) become events;
- `execute` turns a `WheelCommand` into the driver call; the driver's write-time
  latency report is counted only for commands a SIP caused.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Protocol

from drivers.arcos.sip import Sip
from drivers.transport.clock import REAL_CLOCK, Clock
from drivers.transport.health import DeviceHealth
from relayd.core.brain import PANTILT, ROBOT, Brain
from relayd.core.events import (
    DeviceEvent,
    DeviceStatus,
    DriveCommand,
    Event,
    ModeCommand,
    Shutdown,
    SipEvent,
    Tick,
    WheelCommand,
)
from relayd.core.vocab import Mode
from relayd.runtime.health import device_status
from relayd.runtime.state import ModeError

#: Bytes in to SIP decoded: the driver's latency starts this much before the SIP's `t`.
DECODE_SLACK_S = 0.005
#: A tick this much past its time (clock s) was held up with the process, not by its timer.
LATE_TICK_S = 0.05


class SonarView(Protocol):
    @property
    def ranges_mm(self) -> Sequence[int | None]: ...


class WheelBase(Protocol):
    """What the shell needs of the robot driver (drivers.arcos.ArcosRobot, or a test double)."""

    @property
    def connected(self) -> bool: ...
    @property
    def stale(self) -> bool: ...
    @property
    def sonar(self) -> SonarView: ...

    #: Called by the driver with the seconds from a SIP's bytes arriving to the next
    #: motion command written (it cannot tell what caused that command).
    on_command_latency: Callable[[float], None] | None

    def add_listener(self, cb: Callable[[Sip], None]) -> Callable[[], None]: ...
    def stop(self) -> None: ...
    def set_wheels(self, left_mm_s: float, right_mm_s: float) -> None: ...


class Publisher(Protocol):
    def publish(self, event: Event) -> None: ...


class ControlShell:
    """Owns the SIP subscription, the control tick and the wheel side of the actions."""

    def __init__(
        self,
        *,
        bus: Publisher,
        brain: Brain,
        robot: WheelBase | None,
        clock: Clock = REAL_CLOCK,
        tick_s: float = 0.1,
        on_latency: Callable[[float], None] | None = None,
        on_step: Callable[[float], None] | None = None,
        servo_up: Callable[[], bool] | None = None,
        robot_name: Callable[[], str | None] | None = None,
        on_tick: Callable[[float], None] | None = None,
        health: Mapping[str, Callable[[], DeviceHealth]] | None = None,
    ) -> None:
        self._bus = bus
        self._brain = brain
        self._robot = robot
        self._clock = clock
        self._tick_s = tick_s
        self._on_latency = on_latency
        self._on_step = on_step
        self._servo_up = servo_up
        self._robot_name = robot_name or (lambda: None)
        self._on_tick = on_tick
        #: Each device's own `health()`, by device name (robot, pantilt, wifi, ap.rear...).
        self._health = dict(health or {})
        self._halted = False
        self._remove_listener: Callable[[], None] | None = None
        self._status: dict[str, DeviceStatus] = {}
        #: The SIP behind the wheel command last handed to the driver; None: a timer,
        #: a scan or the operator caused it.
        self._cause_sip_t: float | None = None
        self.commands = 0
        self.latency_dropped = 0
        if robot is not None:
            robot.on_command_latency = self._on_written

    # -- Controls (called by the API) ---------------------------------------------------

    def set_mode(self, mode: Mode) -> None:
        self._bus.publish(ModeCommand(self._clock.now(), Mode(mode)))

    def manual_drive(self, left_mm_s: float, right_mm_s: float) -> None:
        if self._brain.mode is not Mode.MANUAL:
            raise ModeError(f"drive commands need manual mode (mode is {self._brain.mode})")
        if not (math.isfinite(left_mm_s) and math.isfinite(right_mm_s)):
            raise ValueError("wheel speeds must be finite")
        self._bus.publish(DriveCommand(self._clock.now(), float(left_mm_s), float(right_mm_s)))

    def halt(self) -> None:
        """Shutdown: never command the wheels again; the robot driver's safe stop follows.

        Synchronous on purpose: a SIP arriving while the driver writes VEL 0, ENABLE 0
        and CLOSE must not slip a non-zero VEL in between.
        """
        self._halted = True
        if self._remove_listener is not None:
            self._remove_listener()
            self._remove_listener = None
        self._bus.publish(Shutdown(self._clock.now()))

    # -- events in ----------------------------------------------------------------------

    def on_sip(self, sip: Sip) -> None:
        started = time.perf_counter()
        robot = self._robot
        sonar = tuple(robot.sonar.ranges_mm) if robot is not None else ()
        self._bus.publish(SipEvent(sip.t, sip, sonar))
        if self._on_step is not None:
            # The cost of one SIP's whole route (brain step, actions, fan-out) on this host.
            self._on_step(time.perf_counter() - started)

    def check_devices(self) -> None:
        """Publish each device's UP/DOWN/FAULT changes (the drivers have no events).

        The robot is up when connected and not stale, the scan servo when the scanner
        can use it; every other device by its driver's health alone.
        """
        now = self._clock.now()
        health = {name: source() for name, source in self._health.items()}
        for name, h in health.items():
            if name not in (ROBOT, PANTILT):
                self._change(name, device_status(h), now, h.last_error)
        if self._robot is not None:
            up = bool(self._robot.connected) and not bool(self._robot.stale)
            self._judge(ROBOT, up, health.get(ROBOT), now, self._robot_name() if up else None)
        if self._servo_up is not None:
            self._judge(PANTILT, self._servo_up(), health.get(PANTILT), now, None)

    def report_fault(self, device: str, detail: str) -> None:
        """A device failed (its task raised and is being restarted): publish FAULT now."""
        self._status[device] = DeviceStatus.FAULT
        self._bus.publish(DeviceEvent(self._clock.now(), device, DeviceStatus.FAULT, detail))

    def _judge(
        self, device: str, up: bool, h: DeviceHealth | None, now: float, detail: str | None
    ) -> None:
        if up:
            self._change(device, DeviceStatus.UP, now, detail)
        elif h is not None and device_status(h) is DeviceStatus.FAULT:
            self._change(device, DeviceStatus.FAULT, now, h.last_error)
        else:
            self._change(device, DeviceStatus.DOWN, now, None)

    def _change(self, device: str, status: DeviceStatus, now: float, detail: str | None) -> None:
        old = self._status.get(device)
        if old is status or (old is DeviceStatus.FAULT and status is DeviceStatus.DOWN):
            return
        self._status[device] = status
        self._bus.publish(DeviceEvent(now, device, status, detail))

    async def run(self) -> None:
        """The control tick; also subscribes to the robot's SIPs (a held task holds both)."""
        if self._robot is not None and not self._halted and self._remove_listener is None:
            self._remove_listener = self._robot.add_listener(self.on_sip)
        try:
            due = self._clock.now()
            while True:
                if self._clock.now() - due > LATE_TICK_S:
                    await _read_what_waited()
                self.check_devices()
                now = self._clock.now()
                self._bus.publish(Tick(now))
                if self._on_tick is not None:
                    self._on_tick(now)
                due = now + self._tick_s
                await self._clock.sleep(self._tick_s)
        finally:
            if self._remove_listener is not None:
                self._remove_listener()
                self._remove_listener = None

    # -- actions out --------------------------------------------------------------------

    def execute(self, cmd: WheelCommand) -> None:
        robot = self._robot
        if robot is None or self._halted:
            return
        # Set before the call: the driver writes at once when the command spacing
        # allows, and reports the latency from inside set_wheels/stop.
        self._cause_sip_t = cmd.sip_t
        if cmd.stop:
            robot.stop()
        else:
            robot.set_wheels(cmd.left_mm_s, cmd.right_mm_s)
        self.commands += 1

    def _on_written(self, seconds: float) -> None:
        """The driver wrote a motion command `seconds` after some SIP's bytes arrived.

        Counted only when the command in force was caused by a SIP (ticks, scans and the
        operator cause commands too; they have no SIP latency), and only once per SIP.
        A figure longer than the time since the causing SIP was decoded belongs to an
        older SIP whose command was never written: dropped, not counted against this one.
        """
        sip_t, self._cause_sip_t = self._cause_sip_t, None
        if sip_t is None or self._on_latency is None:
            return
        since_s = self._clock.to_real(self._clock.now() - sip_t)
        if seconds > since_s + DECODE_SLACK_S:
            self.latency_dropped += 1
            return
        self._on_latency(seconds)


async def _read_what_waited() -> None:
    """Let the event loop read the input that became ready while this task waited.

    A late tick wakes in the same loop iteration as, or ahead of, the robot's SIP bytes
    that arrived during the hold-up; judged at once, the SIP would look `sip_timeout_s`
    old while it sits unread in the socket, and the robot would be stopped for nothing.
    The first yield puts this task behind the callbacks already queued; the loop's next
    poll then queues the readers of every ready descriptor, and the second yield puts
    this task behind those too. A robot that really was silent is still stopped: no
    bytes, no SIP.
    """
    await asyncio.sleep(0)
    await asyncio.sleep(0)
