"""The control shell and the brain: SIPs, ticks and operator requests in, wheel commands out.

A stand-in robot counts `stop()` and `set_wheels()` calls, so these tests see exactly
what the brain, through the shell, asks of the driver: the urgent stop on the transition to zero (and
only then: a stop on every tick once grew the driver's queue without bound), wheel
speeds otherwise, and the fail-safes of docs/CONTROL.md section 6 with their reasons.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import socket
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import pytest

import relayd.core.brain
import relayd.runtime.control
from drivers.airos.model import LinkQuality
from drivers.arcos.sip import Sip as ArcosSip
from drivers.transport.clock import Clock
from drivers.transport.health import DeviceHealth, LinkState
from drivers.wifi.records import RssiSample
from relayd.core.brain import PANTILT, Brain, BrainParams
from relayd.core.control.law import ControlOutput, ControlParams
from relayd.core.events import (
    Action,
    DeviceEvent,
    DeviceStatus,
    Event,
    LinkEvent,
    LinkSide,
    RssiEvent,
    SipEvent,
    Tick,
    WheelCommand,
)
from relayd.core.vocab import DriveState, Mode
from relayd.runtime.bus import Bus
from relayd.runtime.control import ControlShell
from relayd.runtime.state import ModeError, RelayState
from relayd.runtime.statewriter import StateWriter
from tests.support import LoopClock, ManualClock, until


def Sip(t: float, theta_deg: float = 0.0) -> ArcosSip:
    return ArcosSip(
        t=t,
        x_mm=0.0,
        y_mm=0.0,
        theta_deg=theta_deg,
        left_mm_s=0.0,
        right_mm_s=0.0,
        battery_v=13.0,
        motors_enabled=True,
        estop=False,
        stall_left=False,
        stall_right=False,
        moving=False,
        sonar=(),
    )


@dataclass
class Sonar:
    ranges_mm: list[int | None] = field(default_factory=lambda: [None] * 16)


class StandInRobot:
    """The part of ArcosRobot the control shell uses, recording every call.

    Like the driver, a `set_wheels` repeating the wish in force is not a new command
    (the brain asks on every step while driving); a `stop()` is always counted.
    """

    def __init__(self) -> None:
        self.connected = True
        self.stale = False
        self.sonar = Sonar()
        self.stops = 0
        self.wheels: list[tuple[float, float]] = []
        self.listeners: list[Callable[[ArcosSip], None]] = []
        self.on_command_latency: Callable[[float], None] | None = None
        self._wish: tuple[float, float] | None = None

    def stop(self) -> None:
        self.stops += 1
        self._wish = None

    def set_wheels(self, left_mm_s: float, right_mm_s: float) -> None:
        if (left_mm_s, right_mm_s) != self._wish:
            self.wheels.append((left_mm_s, right_mm_s))
        self._wish = (left_mm_s, right_mm_s)

    def add_listener(self, cb: Callable[[ArcosSip], None]) -> Callable[[], None]:
        self.listeners.append(cb)
        return lambda: self.listeners.remove(cb)


class Loop:
    """The control shell, its brain and the state writer wired as the daemon wires them."""

    def __init__(
        self,
        clock: Clock,
        robot: StandInRobot,
        mode: Mode,
        *,
        scanner: bool = True,
        tick_s: float = 0.1,
        on_step: Callable[[float], None] | None = None,
        on_latency: Callable[[float], None] | None = None,
    ) -> None:
        self.clock = clock
        self.state = RelayState(mode=mode)
        self.brain = Brain(BrainParams(control=PARAMS, has_scanner=scanner), mode=mode)
        self.bus: Bus[Event, Action] = Bus()
        self.writer = StateWriter(self.state)
        self.shell = ControlShell(
            bus=self.bus,
            brain=self.brain,
            robot=robot,
            clock=clock,
            tick_s=tick_s,
            on_step=on_step,
            on_latency=on_latency,
        )
        self.bus.connect(self.brain.handle, self._on_actions)

    def _on_actions(self, event: Event, actions: Sequence[Action]) -> None:
        self.writer.on_event(event)
        for a in actions:
            if isinstance(a, WheelCommand):
                self.shell.execute(a)
            else:
                self.writer.on_action(a)

    def step(self) -> ControlOutput:
        """One control tick, as the shell's timer runs it."""
        self.shell.check_devices()
        self.bus.publish(Tick(self.clock.now()))
        assert self.brain.last_output is not None
        return self.brain.last_output

    def set_mode(self, mode: Mode) -> None:
        self.shell.set_mode(mode)

    def manual_drive(self, left_mm_s: float, right_mm_s: float) -> None:
        self.shell.manual_drive(left_mm_s, right_mm_s)

    def halt(self) -> None:
        self.shell.halt()

    async def run(self) -> None:
        await self.shell.run()


@dataclass
class World:
    clock: ManualClock
    robot: StandInRobot
    state: RelayState
    loop: Loop
    rear_dbm: float = -40.0

    @property
    def brain(self) -> Brain:
        return self.loop.brain

    def sip(self, theta_deg: float = 0.0, sonar: Sequence[int | None] | None = None) -> None:
        """A SIP arrives now (the brain steps on it, as on a robot)."""
        ranges = tuple(self.robot.sonar.ranges_mm if sonar is None else sonar)
        self.loop.bus.publish(SipEvent(self.clock.t, Sip(self.clock.t, theta_deg), ranges))

    def rssi(self) -> None:
        self.loop.bus.publish(RssiEvent(self.clock.t, RssiSample(self.clock.t, -50.0, True)))

    def rear(self) -> None:
        q = LinkQuality(
            t=self.clock.t,
            signal_dbm=self.rear_dbm,
            rssi=None,
            noise_dbm=None,
            ccq_pct=None,
            tx_mbps=None,
            rx_mbps=None,
        )
        self.loop.bus.publish(LinkEvent(self.clock.t, LinkSide.REAR, q))

    def servo(self, ok: bool) -> None:
        self.loop.bus.publish(
            DeviceEvent(self.clock.t, PANTILT, DeviceStatus.UP if ok else DeviceStatus.DOWN)
        )

    def fresh(self) -> None:
        """An RSSI sample arrives now; the rear AP was polled now; a SIP arrives now."""
        self.rssi()
        self.rear()
        self.sip()


PARAMS = ControlParams(
    sip_timeout_s=0.5, rssi_timeout_s=2.0, rear_timeout_s=3.0, manual_deadman_s=0.5
)


def make_world(mode: Mode = Mode.FOLLOW, *, sip: bool = True) -> World:
    clock = ManualClock()
    robot = StandInRobot()
    # No scanner task in these tests (the scan servo counts as answering until a
    # test says otherwise): the scanner's latest estimates are set below.
    loop = Loop(clock, robot, mode, scanner=False)
    world = World(clock, robot, loop.state, loop)
    # Bearing +20 deg, the scan before +15, both taken at heading 0; a far leader
    # (background speed 350 mm/s). Remembered as two finished scans would leave them.
    loop.brain.scans.remember(15.0, 0.0, -50.0)
    loop.brain.scans.remember(20.0, 0.0, -50.0)
    if sip:
        world.fresh()
    else:
        world.rssi()
        world.rear()
    return world


def test_drives_with_fresh_data_and_turns_toward_the_bearing() -> None:
    w = make_world()
    out = w.loop.step()
    assert out.state is DriveState.DRIVING and out.reason == "driving"
    assert w.robot.stops == 0
    assert len(w.robot.wheels) == 1
    left, right = w.robot.wheels[0]
    assert right > left > 0  # bearing +20: leader to the left
    assert (w.state.wheels_left_mm_s, w.state.wheels_right_mm_s) == (left, right)
    assert w.state.state is DriveState.DRIVING


class HeldUpClock(ManualClock):
    """A clock whose first tick sleep comes back 0.7 s late with the robot's bytes ready.

    As when the process was held up (a GC pause, a starved CPU): the SIP that arrived
    meanwhile sits readable in its socket when the tick wakes. Later sleeps park.
    """

    def __init__(self, robot_side: socket.socket) -> None:
        super().__init__()
        self._robot_side = robot_side
        self.sleeps = 0
        self.parked = asyncio.Event()

    async def sleep(self, seconds: float) -> None:
        self.sleeps += 1
        if self.sleeps == 1:
            self._robot_side.send(b"sip")
            self.t += 0.7  # past sip_timeout_s (0.5), within the RSSI and rear limits
            return  # no yield: the tick task runs on, as after a hold-up
        self.parked.set()
        await asyncio.Event().wait()


async def _late_tick_stops(monkeypatch: pytest.MonkeyPatch, *, read_first: bool) -> int:
    """Run the shell through one late tick; the number of stops the robot was sent."""
    if not read_first:

        async def judge_at_once() -> None:
            return None

        monkeypatch.setattr(relayd.runtime.control, "_read_what_waited", judge_at_once)
    ours, robot_side = socket.socketpair()
    ours.setblocking(False)
    try:
        clock = HeldUpClock(robot_side)
        robot = StandInRobot()
        loop = Loop(clock, robot, Mode.FOLLOW, scanner=False)
        w = World(clock, robot, loop.state, loop)
        loop.brain.scans.remember(20.0, 0.0, -50.0)
        w.fresh()

        def sip_bytes_in() -> None:
            ours.recv(64)
            w.sip()  # decoded now, as the ARCOS driver's reader does

        asyncio.get_running_loop().add_reader(ours.fileno(), sip_bytes_in)
        task = asyncio.create_task(loop.run())
        try:
            await asyncio.wait_for(clock.parked.wait(), 10.0)
        finally:
            asyncio.get_running_loop().remove_reader(ours.fileno())
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        assert clock.t == pytest.approx(100.7)
        return robot.stops
    finally:
        ours.close()
        robot_side.close()


async def test_a_late_tick_reads_the_sip_that_waited_before_judging_the_robot_silent(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # A tick held up 0.7 s behind a SIP that did arrive: the robot is not silent.
    assert await _late_tick_stops(monkeypatch, read_first=True) == 0
    # The same tick judged at once (the old order) stops a robot that was talking.
    assert await _late_tick_stops(monkeypatch, read_first=False) == 1


def test_stop_is_sent_once_on_the_transition_to_zero_not_every_tick() -> None:
    w = make_world()
    w.loop.step()
    assert w.robot.stops == 0
    driving_calls = len(w.robot.wheels)
    # SIPs stop arriving: the first step past the timeout stops the wheels...
    w.clock.t += 0.6
    out = w.loop.step()
    assert (out.state, out.reason) == (DriveState.FAULT, "no_sip")
    assert w.robot.stops == 1
    # ...and the following ticks, still stopped, do not ask again (the periodic tick
    # and every SIP run step(); one stop per tick once flooded the driver's queue).
    for _ in range(50):
        w.clock.t += 0.1
        w.loop.step()
    assert w.robot.stops == 1
    assert len(w.robot.wheels) == driving_calls  # and no wheel command while stopped
    # Fresh again: it resumes by itself, then a new stop goes out on the next transition.
    w.fresh()
    w.loop.step()
    assert len(w.robot.wheels) == driving_calls + 1
    w.loop.set_mode(Mode.HOLD)
    out = w.loop.step()
    assert (out.state, out.reason) == (DriveState.STOPPED, "hold")
    assert w.robot.stops == 2


def test_first_step_stopped_sends_one_stop() -> None:
    w = make_world(sip=False)  # no SIP yet
    for _ in range(5):
        out = w.loop.step()
    assert out.reason == "no_sip"
    assert w.robot.stops == 1
    assert w.robot.wheels == []


def test_stale_flag_stops_even_with_a_recent_sip() -> None:
    w = make_world()
    w.loop.step()
    w.robot.stale = True  # the driver says the link went quiet; last_sip is only 0 s old
    out = w.loop.step()
    assert (out.state, out.reason) == (DriveState.FAULT, "no_sip")
    assert (out.left_mm_s, out.right_mm_s) == (0.0, 0.0)
    assert w.robot.stops == 1
    assert w.state.reason == "no_sip"
    w.robot.stale = False
    assert w.loop.step().state is DriveState.DRIVING


@pytest.mark.parametrize(
    ("fault", "reason"),
    [
        ("rssi", "rssi_stale"),
        ("servo", "scan_servo"),
        ("rear", "rear_link_stale"),
    ],
)
def test_follow_fail_safes_stop_with_a_reason_and_resume(fault: str, reason: str) -> None:
    w = make_world()
    w.loop.step()
    if fault == "rssi":
        w.clock.t += 2.1
        w.rear()
        w.sip()
    elif fault == "servo":
        w.servo(False)
    else:
        w.clock.t += 3.1
        w.rssi()
        w.sip()
    out = w.loop.step()
    assert (out.state, out.reason) == (DriveState.FAULT, reason)
    assert w.robot.stops == 1
    w.servo(True)
    w.fresh()
    assert w.loop.step().state is DriveState.DRIVING


def test_controller_exception_zeroes_the_wheels(monkeypatch: pytest.MonkeyPatch) -> None:
    w = make_world()
    w.loop.step()
    assert w.robot.stops == 0

    def broken(*_args: object) -> None:
        raise ZeroDivisionError("bug in the brain")

    monkeypatch.setattr(relayd.core.brain, "control_step", broken)
    out = w.loop.step()
    assert out.state is DriveState.FAULT
    assert out.reason.startswith("controller_error")
    assert (out.left_mm_s, out.right_mm_s) == (0.0, 0.0)
    assert w.robot.stops == 1
    assert w.state.state is DriveState.FAULT and w.state.reason.startswith("controller_error")
    assert (w.state.wheels_left_mm_s, w.state.wheels_right_mm_s) == (0.0, 0.0)


def test_bad_input_data_is_a_controller_error_not_a_crash() -> None:
    w = make_world()
    w.loop.step()
    w.robot.sonar.ranges_mm[3] = -5  # the estimator rejects a negative range
    w.sip()
    out = w.loop.step()
    assert out.reason.startswith("controller_error")
    assert w.robot.stops == 1


def test_manual_drive_needs_manual_mode() -> None:
    w = make_world(sip=False)  # nothing has moved the wheels yet
    with pytest.raises(ModeError):
        w.loop.manual_drive(100.0, 100.0)
    w.loop.set_mode(Mode.HOLD)
    with pytest.raises(ModeError):
        w.loop.manual_drive(100.0, 100.0)
    assert w.robot.wheels == []


def test_manual_drive_and_deadman() -> None:
    w = make_world()
    w.loop.set_mode(Mode.MANUAL)
    assert w.state.mode is Mode.MANUAL
    assert w.state.reason == "deadman"  # no command yet
    with pytest.raises(ValueError):
        w.loop.manual_drive(math.nan, 0.0)
    w.loop.manual_drive(120.0, -80.0)
    assert w.robot.wheels[-1] == (120.0, -80.0)
    assert w.state.state is DriveState.DRIVING and w.state.reason == "manual"
    stops = w.robot.stops
    w.clock.t += 0.4
    w.sip()
    w.loop.step()
    assert w.robot.wheels[-1] == (120.0, -80.0) and w.robot.stops == stops  # still within 0.5 s
    w.clock.t += 0.2
    w.sip()
    out = w.loop.step()
    assert (out.state, out.reason) == (DriveState.STOPPED, "deadman")
    assert w.robot.stops == stops + 1


def test_mode_change_forgets_the_manual_command() -> None:
    w = make_world()
    w.loop.set_mode(Mode.MANUAL)
    w.loop.manual_drive(100.0, 100.0)
    w.loop.set_mode(Mode.HOLD)
    assert w.state.reason == "hold"
    w.loop.set_mode(Mode.MANUAL)
    assert w.state.reason == "deadman"  # the old command does not come back
    assert (w.state.wheels_left_mm_s, w.state.wheels_right_mm_s) == (0.0, 0.0)


def test_bearing_is_corrected_for_the_turn_since_the_scan() -> None:
    w = make_world()
    w.brain.scans.remember(20.0, 0.0, -50.0)  # the same bearing twice: no D term
    w.loop.step()
    left0, right0 = w.robot.wheels[-1]
    # The robot has since turned 20 degrees left: the leader is now straight ahead.
    w.sip(theta_deg=20.0)
    w.loop.step()
    left1, right1 = w.robot.wheels[-1]
    # 2 * kp * 20 mm/s of wheel difference, as the nearest whole RVEL (7 deg/s) carries it.
    assert right0 - left0 == pytest.approx(2 * PARAMS.kp * 20.0, abs=2 * 2.6)
    assert right1 == pytest.approx(left1)


@pytest.mark.virtual_time
async def test_run_ticks_without_sips_and_unregisters_its_listener() -> None:
    robot = StandInRobot()
    latencies: list[float] = []
    loop = Loop(
        LoopClock(), robot, Mode.FOLLOW, scanner=False, tick_s=0.01, on_step=latencies.append
    )
    state = loop.state
    task = asyncio.create_task(loop.run())
    await until(lambda: state.loop_tick_t is not None and robot.listeners, "the first tick")
    first_tick = state.loop_tick_t
    await until(lambda: state.loop_tick_t != first_tick, "a second tick with no SIP at all")
    assert state.reason == "no_sip"
    assert robot.stops == 1
    robot.listeners[0](Sip(0.0))  # a SIP runs a step and reports its duration
    assert len(latencies) == 1 and latencies[0] >= 0.0
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert robot.listeners == []


@pytest.mark.virtual_time
async def test_halt_stops_commanding_the_robot_at_once() -> None:
    """Shutdown: after halt() no SIP or tick may command the wheels (the safe stop follows)."""
    w = make_world()
    ticks = w.loop.bus.subscribe("ticks", maxlen=1000)
    task = asyncio.create_task(w.loop.run())
    await until(lambda: w.robot.listeners and w.robot.wheels, "the loop commanding the wheels")
    w.loop.halt()
    assert w.robot.listeners == []  # synchronously: no SIP callback can run a step any more
    calls = (w.robot.stops, len(w.robot.wheels))
    w.fresh()
    out = w.loop.step()
    assert (out.state, out.reason) == (DriveState.STOPPED, "shutdown")
    assert (w.state.wheels_left_mm_s, w.state.wheels_right_mm_s) == (0.0, 0.0)
    # An absence is seen only by letting ticks pass: wait for three more of the
    # still-running task's ticks (virtual time: no wall time, none skipped).
    while ticks.get_nowait() is not None:  # what the bus carried before the halt
        pass
    after: list[object] = []

    def three_ticks_after() -> bool:
        while (e := ticks.get_nowait()) is not None:
            after.append(e)
        return sum(isinstance(e, Tick) for e in after) >= 3

    await until(three_ticks_after, "three ticks after the halt")
    assert (w.robot.stops, len(w.robot.wheels)) == calls
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task


def test_a_driver_reporting_a_failure_is_published_as_fault_until_it_is_up() -> None:
    """The shell turns each driver's own health into UP/DOWN/FAULT events on the bus."""
    clock = ManualClock()
    robot = StandInRobot()
    brain = Brain(BrainParams(control=PARAMS, has_scanner=False), mode=Mode.FOLLOW)
    bus: Bus[Event, Action] = Bus()
    bus.connect(brain.handle, lambda event, actions: None)
    seen = bus.subscribe("devices")
    robot_state = {"state": LinkState.UP, "error": None}
    radio_state = {"state": LinkState.CONNECTING, "error": None}

    def health_of(device: str, now: dict[str, object]) -> Callable[[], DeviceHealth]:
        return lambda: DeviceHealth(
            device=device,
            state=LinkState(now["state"]),
            last_error=str(now["error"]) if now["error"] else None,
        )

    shell = ControlShell(
        bus=bus,
        brain=brain,
        robot=robot,
        clock=clock,
        health={
            "robot": health_of("robot", robot_state),
            "ap.rear": health_of("ap.rear", radio_state),
        },
    )

    def events() -> list[tuple[str, DeviceStatus, str | None]]:
        return [
            (e.device, e.status, e.detail)
            for e in iter(seen.get_nowait, None)
            if isinstance(e, DeviceEvent)
        ]

    shell.check_devices()
    assert events() == [("ap.rear", DeviceStatus.DOWN, None), ("robot", DeviceStatus.UP, None)]
    # The robot's link fails (the driver retries on backoff); the radio's login fails.
    robot.connected = False
    robot_state.update(state=LinkState.DOWN, error="SerialException: device disconnected")
    radio_state.update(state=LinkState.DOWN, error="login refused")
    shell.check_devices()
    assert events() == [
        ("ap.rear", DeviceStatus.FAULT, "login refused"),
        ("robot", DeviceStatus.FAULT, "SerialException: device disconnected"),
    ]
    bus.publish(Tick(clock.now()))
    assert brain.last_output is not None and brain.last_output.state is DriveState.FAULT
    assert (brain.last_output.left_mm_s, brain.last_output.right_mm_s) == (0.0, 0.0)
    # Reconnecting (no failure yet) does not hide the fault: FAULT holds until UP.
    robot_state.update(state=LinkState.CONNECTING)
    shell.check_devices()
    assert events() == []
    robot.connected = True
    robot_state.update(state=LinkState.UP, error=None)
    radio_state.update(state=LinkState.UP, error=None)
    shell.check_devices()
    assert events() == [("ap.rear", DeviceStatus.UP, None), ("robot", DeviceStatus.UP, None)]
    # A fault the supervisor reports (the task failed while the driver looks fine).
    shell.report_fault("robot", "OSError: helper lost the robot")
    shell.check_devices()
    assert events() == [
        ("robot", DeviceStatus.FAULT, "OSError: helper lost the robot"),
        ("robot", DeviceStatus.UP, None),
    ]
