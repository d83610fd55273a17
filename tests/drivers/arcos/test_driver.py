"""ArcosRobot against FakeRobot.

Unit tests run on in-memory links in virtual time (`virtual_time`: timers fire without
waiting); a few integration tests keep real ptys and loopback TCP on a 10x clock.
"""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import pytest

from drivers.arcos import ArcosRobot, HandshakeError
from drivers.arcos.codec import CLOSE, Command, encode_command, encode_packet, vel2_arg
from drivers.arcos.fake import FakeRobot
from drivers.arcos.sip import Sip
from drivers.transport.backoff import Backoff
from drivers.transport.clock import Clock
from drivers.transport.link import LinkError, open_link
from drivers.transport.memlink import LinkFaults
from tests.support import clock_for, running, until

SPEED = 10.0
VT = pytest.mark.virtual_time
#: Real byte pipes; each test over them has an in-memory twin in virtual time. (The loop
#: is chosen per test function, so the twin is a function of its own, not a parameter.)
KINDS = ["pty", "tcp"]


@pytest.fixture
def clock(request: pytest.FixtureRequest) -> Clock:
    return clock_for(request, SPEED)


async def serve(fake: FakeRobot, kind: str) -> str:
    if kind == "memory":
        return fake.serve_memory("robot")
    return fake.serve_pty() if kind == "pty" else await fake.serve_tcp()


@pytest.mark.parametrize("kind", KINDS)
async def test_handshake_identity_sonar_and_pose(kind: str, clock: Clock) -> None:
    await _handshake_identity_sonar_and_pose(kind, clock)


@VT
async def test_handshake_identity_sonar_and_pose_in_memory(clock: Clock) -> None:
    await _handshake_identity_sonar_and_pose("memory", clock)


async def _handshake_identity_sonar_and_pose(kind: str, clock: Clock) -> None:
    ranges = [1000 + 100 * i for i in range(16)]
    ranges[5] = None  # type: ignore[call-overload]
    fake = FakeRobot(
        "relay7",
        subclass="p3at-sh",
        clock=clock,
        pose=(1000, 2000, 90),
        sonar_fn=lambda x, y, th: ranges,
    )
    url = await serve(fake, kind)
    robot = ArcosRobot(url, clock=clock, enable_motors=True)
    seen: list[Sip] = []
    robot.add_listener(seen.append)
    try:
        async with running(robot):
            await until(lambda: robot.connected and robot.last_sip is not None)
            assert robot.identity is not None
            assert (robot.identity.name, robot.identity.robot_class, robot.identity.subclass) == (
                "relay7",
                "Pioneer",
                "p3at-sh",
            )
            assert robot.config is not None and robot.config.watchdog_ms == 2000
            assert not robot.stale
            await until(lambda: None not in robot.sonar.ranges_mm)
            assert robot.sonar.ranges_mm[0] == 1000 and robot.sonar.ranges_mm[15] == 2500
            assert robot.sonar.ranges_mm[5] == 5000 and not robot.sonar.has_echo(5)
            assert robot.sonar.front_min_mm() == 1000
            # drive an arc: v = 150 mm/s, RVEL = 10 deg/s
            robot.set_wheels(100, 200)
            # Polled, not slept: on a 10x clock a loaded machine's stall of 0.2 s wall
            # is the fake's 2 s watchdog, which zeroes the target until the next refresh.
            await until(
                lambda: fake.target_vel_mm_s == 150 and fake.target_rvel_deg_s == 10,
                "VEL 150 and RVEL 10 at the fake",
            )
            # Far enough along the arc (about 3 s of it) for both wheels to hold speed.
            await until(
                lambda: math.hypot(*fake.odometry_mm_deg[:2]) >= 400, "400 mm along the arc"
            )
            sip = robot.last_sip
            assert sip is not None and sip.moving and sip.motors_enabled
            assert sip.left_mm_s == pytest.approx(100, abs=8)
            assert sip.right_mm_s == pytest.approx(200, abs=8)
            # The pose is compared at rest: while moving, the last SIP lags the fake by a
            # SIP period plus however long a loaded machine took to read it (10 ms of
            # wall time is 15 mm here on the 10x clock).
            robot.set_wheels(0, 0)
            await until(lambda: fake.vel_mm_s == 0 and fake.rvel_deg_s == 0, "the fake to stop")
            count = len(seen)
            await until(lambda: len(seen) >= count + 2, "two SIPs at rest")
            sip = seen[-1]
            # odometry started at 0 at OPEN; the world pose started at (1000, 2000, 90)
            ox, oy, oth = fake.odometry_mm_deg
            assert sip.x_mm == pytest.approx(ox, abs=20) and sip.y_mm == pytest.approx(oy, abs=20)
            assert sip.theta_deg == pytest.approx(oth, abs=2)
            dist = math.hypot(fake.x_mm - 1000, fake.y_mm - 2000)
            assert dist == pytest.approx(math.hypot(ox, oy), abs=1)
            assert fake.theta_deg == pytest.approx(90 + oth, abs=0.01)
            assert 300 < math.hypot(sip.x_mm, sip.y_mm) < 750
    finally:
        await fake.stop()
    assert seen and all(s.t <= seen[-1].t for s in seen)
    assert robot.counters["sips"] == len(seen)
    assert robot.counters["checksum_errors"] == 0


@VT
async def test_motors_not_enabled_unless_asked(clock: Clock) -> None:
    fake = FakeRobot(clock=clock)
    robot = ArcosRobot(fake.serve_memory("robot"), clock=clock)
    try:
        async with running(robot):
            await until(lambda: robot.connected and robot.last_sip is not None)
            robot.set_wheels(200, 200)
            await asyncio.sleep(clock.to_real(1.0))
            assert (Command.ENABLE, 1) not in fake.commands
            assert not fake.motors_enabled and fake.vel_mm_s == 0  # VEL dropped while disabled
            robot.enable_motors(True)
            await until(lambda: fake.vel_mm_s > 0)
            assert robot.last_sip is not None
            await until(lambda: robot.last_sip is not None and robot.last_sip.motors_enabled)
    finally:
        await fake.stop()


@VT
async def test_driver_keeps_the_watchdog_fed(clock: Clock) -> None:
    fake = FakeRobot(clock=clock, trans_accel_mm_s2=1000)
    robot = ArcosRobot(fake.serve_memory("robot"), clock=clock, enable_motors=True)
    try:
        async with running(robot):
            await until(lambda: robot.connected)
            robot.set_wheels(300, 300)  # once; nothing else calls set_wheels
            await asyncio.sleep(clock.to_real(3.5))
            assert fake.vel_mm_s == 300 and not fake._watchdog_tripped
            vels = [a for c, a in fake.commands if c == Command.VEL]
            assert vels.count(300) >= 5  # re-sent at least every 500 ms
            robot.set_wheels(0, 0)
            await asyncio.sleep(clock.to_real(1.5))
            pulses = len([c for c, _ in fake.commands if c == 0])
            assert pulses >= 1  # idle: PULSE keeps the session alive
    finally:
        await fake.stop()


@VT
async def test_fake_watchdog_stops_an_unattended_robot(clock: Clock) -> None:
    """The fake itself: a raw client that goes quiet gets its robot stopped after 2 s."""
    fake = FakeRobot(clock=clock, trans_accel_mm_s2=3000)
    path = fake.serve_memory("robot")

    class Sink(asyncio.Protocol):
        def __init__(self) -> None:
            self.lost = asyncio.Event()

        def data_received(self, data: bytes) -> None:
            pass

        def connection_lost(self, exc: Exception | None) -> None:
            self.lost.set()

    transport, sink = await open_link(path, 9600, Sink)
    try:
        for cmd in (0, 1, 2):
            transport.write(encode_command(cmd))
            await asyncio.sleep(0.01)
        for cmd, arg in ((1, 1), (Command.ENABLE, 1), (Command.VEL, 200)):
            transport.write(encode_command(cmd, arg))
            await asyncio.sleep(0.01)
        await until(lambda: fake.vel_mm_s == 200)
        await asyncio.sleep(clock.to_real(1.5))
        assert fake.vel_mm_s == 200
        await until(lambda: fake.vel_mm_s == 0, timeout_s=clock.to_real(2.0) + 1)
        assert fake._watchdog_tripped
    finally:
        transport.close()
        await sink.lost.wait()
        await fake.stop()


@pytest.mark.parametrize("kind", KINDS)
async def test_reconnect_after_hang_up(kind: str, clock: Clock, tmp_path: Path) -> None:
    await _reconnect_after_hang_up(kind, clock, tmp_path)


@VT
async def test_reconnect_after_hang_up_in_memory(clock: Clock, tmp_path: Path) -> None:
    await _reconnect_after_hang_up("memory", clock, tmp_path)


async def _reconnect_after_hang_up(kind: str, clock: Clock, tmp_path: Path) -> None:
    fake = FakeRobot(clock=clock)
    url = fake.serve_pty(str(tmp_path / "robot")) if kind == "pty" else await serve(fake, kind)
    robot = ArcosRobot(
        url,
        clock=clock,
        enable_motors=True,
        backoff=Backoff(initial_s=0.1, maximum_s=0.5, jitter=0),
    )
    try:
        async with running(robot):
            await until(lambda: robot.connected and robot.last_sip is not None)
            robot.set_wheels(100, 100)
            fake.hang_up()
            await until(lambda: not robot.connected)
            assert robot.stale and robot.last_error is not None
            # Nothing to connect to while hung up: three tries (0.1, 0.2, 0.4 s apart) fail.
            tries = robot.backoff.attempts
            await until(lambda: robot.backoff.attempts >= tries + 3, "three reconnect tries")
            assert not robot.connected
            fake.reappear()
            await until(lambda: robot.connected and not robot.stale, timeout_s=5)
            assert robot.counters["reconnects"] == 1
            # the wish survives: motors re-enabled and the wheels commanded again
            await until(lambda: fake.motors_enabled and fake.target_vel_mm_s == 100)
    finally:
        await fake.stop()
    if kind != "tcp":  # the real robot never saw CLOSE: it was still in the old session
        assert robot.counters["old_sessions"] >= 1


@VT
async def test_old_session_is_closed_then_reopened(clock: Clock) -> None:
    fake = FakeRobot(clock=clock, old_session=True)
    robot = ArcosRobot(fake.serve_memory("robot"), clock=clock)
    try:
        await asyncio.sleep(clock.to_real(0.3))
        assert fake.sips_sent > 0  # streaming before anyone connects
        async with running(robot):
            await until(lambda: robot.connected and robot.last_sip is not None)
        assert robot.counters["old_sessions"] == 1
        first_close = fake.commands.index((CLOSE, 1))
        assert (0, None) in fake.commands[first_close:]  # SYNC0 again after the CLOSE
        assert fake.sessions == 1
    finally:
        await fake.stop()


@VT
@pytest.mark.parametrize(
    ("subclass", "override", "factor"),
    [("p3at", None, 1.0), ("p3at-sh", None, 1.0), ("p3at-sh", "p3at", 0.465)],
)
async def test_odometry_scale_per_subclass(
    subclass: str, override: str | None, factor: float, clock: Clock
) -> None:
    fake = FakeRobot(clock=clock, subclass=subclass, trans_accel_mm_s2=2000)
    robot = ArcosRobot(
        fake.serve_memory("robot"), clock=clock, enable_motors=True, subclass_override=override
    )
    try:
        async with running(robot):
            await until(lambda: robot.connected and robot.last_sip is not None)
            robot.set_wheels(500, 500)
            await until(lambda: fake.odometry_mm_deg[0] > 1000, timeout_s=5)
            robot.stop()
            await until(lambda: robot.last_sip is not None and not robot.last_sip.moving)
            await asyncio.sleep(clock.to_real(0.3))
            assert robot.last_sip is not None
            # the robot reports odometry / DistConvFactor(true subclass); the driver multiplies
            # by the factor of the subclass it believes: right unless overridden wrongly
            assert robot.last_sip.x_mm == pytest.approx(fake.odometry_mm_deg[0] * factor, abs=3)
    finally:
        await fake.stop()


@VT
async def test_stale_after_silence_then_session_dropped_and_recovered(clock: Clock) -> None:
    fake = FakeRobot(clock=clock)
    robot = ArcosRobot(
        fake.serve_memory("robot"),
        clock=clock,
        lost_after_s=0.5,
        drop_after_s=1.5,
        backoff=Backoff(initial_s=0.1, maximum_s=0.3, jitter=0),
        sync_timeout_s=0.3,
    )
    try:
        async with running(robot):
            await until(lambda: robot.connected and not robot.stale)
            fake.silent = True
            t0 = clock.now()
            await until(lambda: robot.stale)
            assert clock.now() - t0 < 0.5 + 0.3  # lost_after_s plus one SIP period and a tick
            assert robot.connected  # stale first; the session is only dropped later
            await until(lambda: not robot.connected)
            assert "no SIP" in (robot.last_error or "")
            fake.silent = False
            await until(lambda: robot.connected and not robot.stale, timeout_s=5)
    finally:
        await fake.stop()


@VT
async def test_controller_reset_packet_ends_session(clock: Clock) -> None:
    fake = FakeRobot(clock=clock)
    robot = ArcosRobot(
        fake.serve_memory("robot"),
        clock=clock,
        backoff=Backoff(initial_s=0.1, maximum_s=0.3, jitter=0),
    )
    try:
        async with running(robot):
            await until(lambda: robot.connected and robot.last_sip is not None)
            fake._emit(encode_packet(0xFF))
            await until(lambda: "controller reset" in (robot.last_error or ""))
            await until(lambda: robot.connected and robot.counters["reconnects"] == 1, timeout_s=5)
    finally:
        await fake.stop()


@VT
async def test_adversarial_stream_split_garbage_corruption(clock: Clock) -> None:
    fake = FakeRobot(clock=clock, seed=7, sonars_per_sip=16)
    fake.split_writes = True
    fake.garbage = True
    robot = ArcosRobot(fake.serve_memory("robot"), clock=clock)
    try:
        async with running(robot):
            await until(lambda: robot.connected and robot.last_sip is not None, timeout_s=5)
            fake.corrupt_rate = 0.3
            n0 = robot.counters["sips"]
            await asyncio.sleep(clock.to_real(3.0))
            got = robot.counters["sips"] - n0
            assert 10 <= got <= 30
            assert robot.counters["checksum_errors"] >= 1
            assert robot.counters["resyncs"] >= 10 and robot.counters["garbage_bytes"] > 0
            assert robot.connected and all(r == 5000 for r in robot.sonar.ranges_mm)
    finally:
        await fake.stop()


@VT
async def test_safe_stop_on_cancel(clock: Clock) -> None:
    fake = FakeRobot(clock=clock)
    robot = ArcosRobot(fake.serve_memory("robot"), clock=clock, enable_motors=True)
    try:
        async with running(robot):
            await until(lambda: robot.connected)
            robot.set_wheels(200, 250)
            await until(lambda: fake.vel_mm_s > 0)
        # the context manager cancelled run(); the safe stop happened before the port closed
        await until(lambda: (CLOSE, 1) in fake.commands, timeout_s=1)
        tail = fake.commands[-4:]
        assert tail == [(Command.VEL, 0), (Command.RVEL, 0), (Command.ENABLE, 0), (CLOSE, 1)]
        assert not fake.opened and not fake.motors_enabled
        assert not robot.connected
    finally:
        await fake.stop()


async def test_shutdown_is_idempotent_and_ends_run(clock: Clock) -> None:
    fake = FakeRobot(clock=clock)
    robot = ArcosRobot(await fake.serve_tcp(), clock=clock)
    try:
        task = asyncio.create_task(robot.run())
        await until(lambda: robot.connected)
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        await robot.shutdown()
        assert loop.time() - t0 < 0.2
        await robot.shutdown()
        await asyncio.wait_for(task, 1)  # run() returned by itself
        assert fake.commands[-2:] == [(Command.ENABLE, 0), (CLOSE, 1)]
        assert fake.commands.count((CLOSE, 1)) == 1
    finally:
        await fake.stop()


@VT
async def test_stop_jumps_the_queue(clock: Clock) -> None:
    fake = FakeRobot(clock=clock, trans_accel_mm_s2=5000)
    robot = ArcosRobot(fake.serve_memory("robot"), clock=clock, enable_motors=True)
    try:
        async with running(robot):
            await until(lambda: robot.connected)
            robot.set_wheels(400, 400)
            await until(lambda: fake.vel_mm_s == 400)
            robot.enable_motors(True)  # queue some normal traffic
            robot.stop()
            await until(lambda: fake.target_vel_mm_s == 0, timeout_s=1)
            assert robot.wheels_wish == (0.0, 0.0)
    finally:
        await fake.stop()


@VT
async def test_listener_errors_do_not_stop_the_driver(clock: Clock) -> None:
    fake = FakeRobot(clock=clock)
    robot = ArcosRobot(fake.serve_memory("robot"), clock=clock)

    def broken(sip: Sip) -> None:
        raise RuntimeError("listener bug")

    good: list[Sip] = []
    unsubscribe = robot.add_listener(broken)
    robot.add_listener(good.append)
    try:
        async with running(robot):
            await until(lambda: len(good) >= 3)
            unsubscribe()
            n = robot.counters["listener_errors"]
            await until(lambda: len(good) >= 6)
            assert n >= 3 and robot.counters["listener_errors"] == n
    finally:
        await fake.stop()


async def test_silent_robot_handshake_gives_up(clock: Clock) -> None:
    fast = Clock(40)
    fake = FakeRobot(clock=fast)
    fake.silent = True
    robot = ArcosRobot(fake.serve_pty(), clock=fast, max_misses=4)
    try:
        with pytest.raises(HandshakeError, match="never answered SYNC0"):
            await robot.connect()
        assert robot.current_baud != 9600  # it cycled to another rate after two misses
    finally:
        await fake.stop()


async def test_missing_port_names_the_port(tmp_path) -> None:
    robot = ArcosRobot(str(tmp_path / "nope"))
    with pytest.raises(LinkError, match="nope"):
        await robot.connect()


@VT
async def test_motion_guard_rejection_sets_stall_bits(clock: Clock) -> None:
    fake = FakeRobot(
        clock=clock, trans_accel_mm_s2=2000, motion_guard=lambda old, new: new[0] < 300
    )
    robot = ArcosRobot(fake.serve_memory("robot"), clock=clock, enable_motors=True)
    try:
        async with running(robot):
            # the driver's origin is its first SIP (as ARIA's): wait for it before moving
            await until(lambda: robot.connected and robot.last_sip is not None)
            robot.set_wheels(400, 400)
            await until(
                lambda: robot.last_sip is not None and robot.last_sip.stall_left, timeout_s=3
            )
            # it creeps up to the wall (within 1/32 of a 40 mm step), stalled all the way
            await until(lambda: robot.last_sip is not None and robot.last_sip.x_mm > 298)
            await asyncio.sleep(clock.to_real(0.3))  # and keeps pushing against it
            sip = robot.last_sip
            assert sip is not None and sip.stall_left and sip.stall_right and sip.left_mm_s == 0
            assert 298 < fake.x_mm < 300 and sip.x_mm == pytest.approx(fake.x_mm, abs=1)
            # turning in place is still allowed against the wall
            robot.set_wheels(-100, 100)
            await until(lambda: fake.theta_deg > 5)
    finally:
        await fake.stop()


async def test_fake_vel2_estop_seto_and_disable() -> None:
    fake = FakeRobot(trans_accel_mm_s2=1e6, rot_accel_deg_s2=1e6)
    fake._handle(0, None)
    fake._handle(1, None)
    fake._handle(2, None)
    fake._handle(1, 1)  # OPEN
    assert fake.opened and not fake.motors_enabled
    fake._handle(Command.VEL, 200)
    assert fake.target_vel_mm_s == 0  # dropped while disabled
    fake._handle(Command.ENABLE, 1)
    fake._handle(Command.VEL2, vel2_arg(5, 10))  # left 100, right 200 mm/s
    assert fake.target_vel_mm_s == 150 and fake.target_rvel_deg_s == 10
    fake.step(0.1)
    assert fake.vel_mm_s == 150 and fake.build_sip().moving
    fake._handle(Command.E_STOP, None)
    assert fake.vel_mm_s == 0 and fake.target_vel_mm_s == 0
    fake._handle(Command.SETO, None)
    assert fake.odometry_mm_deg == (0.0, 0.0, 0.0)
    fake._handle(Command.VEL, 100)
    fake.step(0.1)
    fake._handle(Command.ENABLE, 0)
    assert fake.vel_mm_s == 0 and not fake.build_sip().moving
    fake._handle(CLOSE, None)
    assert not fake.opened


@VT
async def test_control_latency_is_measured_from_the_sip_to_the_command_it_caused(
    clock: Clock,
) -> None:
    """A wheel command set inside a SIP listener is timed from that SIP's bytes to its write."""
    fake = FakeRobot(clock=clock)
    url = fake.serve_memory("robot")
    robot = ArcosRobot(url, clock=clock, enable_motors=True)
    latencies: list[float] = []
    robot.on_command_latency = latencies.append
    speeds = iter(range(100, 10_000, 10))
    last: list[int] = []

    def on_sip(_sip: Sip) -> None:
        last.append(next(speeds))
        robot.set_wheels(last[-1], last[-1])  # a new command on every SIP

    try:
        async with running(robot):
            await until(lambda: robot.connected and robot.last_sip is not None)
            # Outside a SIP callback a new command is not a control-latency sample.
            robot.set_wheels(50, 50)
            await until(lambda: fake.target_vel_mm_s == 50)
            assert latencies == []
            remove = robot.add_listener(on_sip)
            await until(lambda: len(latencies) >= 5)
            remove()
            await until(lambda: fake.target_vel_mm_s == last[-1])  # the last one is written
            # One sample per SIP-caused command, each a real, small, positive duration.
            assert all(0.0 < s < 0.5 for s in latencies), latencies
            n = len(latencies)
            robot.set_wheels(60, 60)  # again outside a SIP: no new sample
            await until(lambda: fake.target_vel_mm_s == 60)
            assert len(latencies) == n
    finally:
        await fake.stop()


@VT
async def test_a_fatal_write_error_ends_the_session_at_once(clock: Clock) -> None:
    """The root cause of a flaky fault test: a write that kills the transport must end the
    session there and then (robot state unknown), not on the SIP timeout later."""
    fake = FakeRobot(clock=clock)
    robot = ArcosRobot(
        fake.serve_memory("robot"),
        clock=clock,
        enable_motors=True,
        backoff=Backoff(initial_s=0.1, maximum_s=0.2, jitter=0),
    )
    try:
        async with running(robot):
            await until(lambda: robot.connected and not robot.stale, "a session")
            port = fake.memory_port
            assert port is not None and port.transport is not None
            port.transport.fail_next_write(OSError(5, "Input/output error"))
            robot.set_wheels(100, 100)  # written from this stack: the write fails here
            assert not robot.connected and robot.stale
            await until(
                lambda: robot.last_error is not None and "write error" in robot.last_error,
                "the write error reported",
            )
            assert robot.counters["reconnects"] == 0
            # The port is still there: the driver reconnects and the wish is carried out.
            await until(lambda: robot.connected and fake.target_vel_mm_s == 100, "reconnected")
            assert robot.counters["reconnects"] == 1
    finally:
        await fake.stop()


@VT
@pytest.mark.parametrize(
    "faults",
    [
        LinkFaults(chunk_bytes=1),
        LinkFaults(random_chunks=True, delay_s=0.02, seed=3),
        LinkFaults(garbage_rate=0.5, garbage_avoid=frozenset({0xFA}), drop_rate=0.002, seed=5),
    ],
    ids=["one-byte-at-a-time", "random-chunks-delayed", "garbage-and-drops"],
)
async def test_the_driver_holds_on_a_hostile_line(faults: LinkFaults, clock: Clock) -> None:
    """The real driver against the real fake over a line that splits, delays, adds
    garbage and loses bytes (both directions): it still connects, keeps the SIPs
    coming and counts what it had to throw away."""
    fake = FakeRobot(clock=clock, seed=1)
    url = fake.serve_memory(
        "robot", faults_to_driver=faults, faults_to_device=LinkFaults(chunk_bytes=1)
    )
    robot = ArcosRobot(url, clock=clock, enable_motors=True)
    try:
        async with running(robot):
            await until(lambda: robot.connected and robot.last_sip is not None, "a session")
            robot.set_wheels(150, 150)
            await until(lambda: fake.target_vel_mm_s == 150, "VEL 150 at the fake")
            n0 = robot.counters["sips"]
            await asyncio.sleep(clock.to_real(3.0))
            assert robot.counters["sips"] - n0 >= 20  # of ~30 in 3 s, some lost to drops
            assert robot.connected
            if faults.garbage_rate:
                assert robot.counters["garbage_bytes"] > 0 and robot.counters["resyncs"] > 0
    finally:
        await fake.stop()
