"""ControlLoop: the glue between the robot driver, the scanner and the pure controller.

A stand-in robot counts `stop()` and `set_wheels()` calls, so these tests see exactly
what the loop asks of the driver: the urgent stop on the transition to zero (and
only then: a stop on every tick once grew the driver's queue without bound), wheel
speeds otherwise, and the fail-safes of docs/CONTROL.md section 6 with their reasons.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import pytest

import relayd.control
from drivers.clock import Clock
from relayd.control import ControlLoop
from relayd.controller import ControlParams
from relayd.state import DriveState, Mode, ModeError, RelayState


class ManualClock(Clock):
    """A clock that moves only when the test says so."""

    __slots__ = ("t",)

    def __init__(self, t: float = 100.0) -> None:
        super().__init__()
        self.t = t

    def now(self) -> float:
        return self.t


@dataclass
class Sip:
    t: float
    theta_deg: float = 0.0
    x_mm: float = 0.0
    y_mm: float = 0.0


@dataclass
class Sonar:
    ranges_mm: list[int | None] = field(default_factory=lambda: [None] * 16)


class StandInRobot:
    """The part of ArcosRobot the control loop uses, recording every call."""

    def __init__(self) -> None:
        self.last_sip: Sip | None = None
        self.stale = False
        self.sonar = Sonar()
        self.stops = 0
        self.wheels: list[tuple[float, float]] = []
        self.listeners: list[Callable[[object], None]] = []

    def stop(self) -> None:
        self.stops += 1

    def set_wheels(self, left_mm_s: float, right_mm_s: float) -> None:
        self.wheels.append((left_mm_s, right_mm_s))

    def add_listener(self, cb: Callable[[object], None]) -> Callable[[], None]:
        self.listeners.append(cb)
        return lambda: self.listeners.remove(cb)


@dataclass
class StandInScanner:
    servo_ok: bool = True
    leader_lost: bool = False
    bearing_deg: float | None = 20.0
    bearing_heading_deg: float | None = 0.0
    prev_bearing_deg: float | None = 15.0
    prev_heading_deg: float | None = 0.0


class StandInMonitor:
    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self.last_fresh_t: float | None = clock.now()

    def age_s(self, now: float) -> float | None:
        return None if self.last_fresh_t is None else now - self.last_fresh_t


@dataclass
class World:
    clock: ManualClock
    robot: StandInRobot
    scanner: StandInScanner
    monitor: StandInMonitor
    state: RelayState
    loop: ControlLoop
    rear: list[float | None]

    def fresh(self) -> None:
        """A SIP and an RSSI sample arrive now; the rear AP was polled now."""
        self.robot.last_sip = Sip(self.clock.t)
        self.monitor.last_fresh_t = self.clock.t
        self.rear[1] = self.clock.t


PARAMS = ControlParams(sip_timeout_s=0.5, rssi_timeout_s=2.0, rear_timeout_s=3.0, manual_deadman_s=0.5)


def make_world(mode: Mode = Mode.FOLLOW) -> World:
    clock = ManualClock()
    robot = StandInRobot()
    scanner = StandInScanner()
    monitor = StandInMonitor(clock)
    state = RelayState(mode=mode)
    state.rssi_leader_dbm = -50.0  # far: background speed 350 mm/s
    rear: list[float | None] = [-40.0, clock.t]
    loop = ControlLoop(robot=robot, scanner=scanner, monitor=monitor, state=state, params=PARAMS,
                       clock=clock, rear_rssi=lambda: (rear[0], rear[1]))
    world = World(clock, robot, scanner, monitor, state, loop, rear)
    world.fresh()
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
    w.state.mode = Mode.HOLD
    out = w.loop.step()
    assert (out.state, out.reason) == (DriveState.STOPPED, "hold")
    assert w.robot.stops == 2


def test_first_step_stopped_sends_one_stop() -> None:
    w = make_world()
    w.robot.last_sip = None  # no SIP yet
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
        w.robot.last_sip = Sip(w.clock.t)
        w.rear[1] = w.clock.t
    elif fault == "servo":
        w.scanner.servo_ok = False
    else:
        w.clock.t += 3.1
        w.robot.last_sip = Sip(w.clock.t)
        w.monitor.last_fresh_t = w.clock.t
    out = w.loop.step()
    assert (out.state, out.reason) == (DriveState.FAULT, reason)
    assert w.robot.stops == 1
    w.scanner.servo_ok = True
    w.fresh()
    assert w.loop.step().state is DriveState.DRIVING


def test_controller_exception_zeroes_the_wheels(monkeypatch: pytest.MonkeyPatch) -> None:
    w = make_world()
    w.loop.step()
    assert w.robot.stops == 0

    def broken(*_args: object) -> None:
        raise ZeroDivisionError("bug in the brain")

    monkeypatch.setattr(relayd.control, "control_step", broken)
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
    out = w.loop.step()
    assert out.reason.startswith("controller_error")
    assert w.robot.stops == 1


def test_manual_drive_needs_manual_mode() -> None:
    w = make_world()
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
    w.robot.last_sip = Sip(w.clock.t)
    w.loop.step()
    assert w.robot.wheels[-1] == (120.0, -80.0) and w.robot.stops == stops  # still within 0.5 s
    w.clock.t += 0.2
    w.robot.last_sip = Sip(w.clock.t)
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
    w.scanner.prev_bearing_deg = w.scanner.bearing_deg  # no D term
    w.loop.step()
    left0, right0 = w.robot.wheels[-1]
    # The robot has since turned 20 degrees left: the leader is now straight ahead.
    w.robot.last_sip = Sip(w.clock.t, theta_deg=20.0)
    w.loop.step()
    left1, right1 = w.robot.wheels[-1]
    # 2 * kp * 20 mm/s of wheel difference, as the nearest whole RVEL (7 deg/s) carries it.
    assert right0 - left0 == pytest.approx(2 * PARAMS.kp * 20.0, abs=2 * 2.6)
    assert right1 == pytest.approx(left1)


async def test_run_ticks_without_sips_and_unregisters_its_listener() -> None:
    robot = StandInRobot()
    state = RelayState()
    latencies: list[float] = []
    loop = ControlLoop(robot=robot, scanner=None, monitor=None, state=state, params=PARAMS,
                       tick_s=0.01, on_latency=latencies.append)
    task = asyncio.create_task(loop.run())
    async with asyncio.timeout(10):
        while state.loop_tick_t is None or not robot.listeners:
            await asyncio.sleep(0.005)
    first_tick = state.loop_tick_t
    async with asyncio.timeout(10):
        while state.loop_tick_t == first_tick:
            await asyncio.sleep(0.005)  # ticks keep coming with no SIP at all
    assert state.reason == "no_sip"
    assert robot.stops == 1
    robot.listeners[0](Sip(0.0))  # a SIP runs a step and reports its latency
    assert len(latencies) == 1 and latencies[0] >= 0.0
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert robot.listeners == []


async def test_halt_stops_commanding_the_robot_at_once() -> None:
    """Shutdown: after halt() no SIP or tick may command the wheels (the safe stop follows)."""
    w = make_world()
    task = asyncio.create_task(w.loop.run())
    async with asyncio.timeout(10):
        while not w.robot.listeners or not w.robot.wheels:
            await asyncio.sleep(0.005)
    w.loop.halt()
    assert w.robot.listeners == []  # synchronously: no SIP callback can run a step any more
    calls = (w.robot.stops, len(w.robot.wheels))
    w.fresh()
    out = w.loop.step()
    assert (out.state, out.reason) == (DriveState.STOPPED, "shutdown")
    assert (w.state.wheels_left_mm_s, w.state.wheels_right_mm_s) == (0.0, 0.0)
    await asyncio.sleep(0.3)  # several ticks of the still-running task
    assert (w.robot.stops, len(w.robot.wheels)) == calls
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
