"""FakeRobot: the robot side of the ARCOS protocol, for tests and the simulator.

Built on the same codec as the driver. It mirrors MobileSim (docs/PROTOCOLS.md 1.12)
and adds what MobileSim lacks: the real 2 s watchdog stop, SIP type 0x33 while moving,
and a sonar that reports a few sonars per SIP (the policy is in fakebody.py).

`FakeRobot` is a `FakeBody` (fakebody.py: the TRUE world pose, the motion, the
odometry reported in robot units, the sonar firing and the SIP they make) that speaks
ARCOS: here are the session (SYNC0/1/2, OPEN, CLOSE, motors, the watchdog), the
command handlers, the SIP loop, the ports it serves on and the adversarial wire
switches (split writes, garbage, corrupt checksums, silence). A pty hang-up leaves the
robot in its session (it will answer the next SYNC0 with SIPs, as a real robot does
after a pulled cable); a TCP client going away ends the session, as MobileSim does.
"""

from __future__ import annotations

import asyncio
import contextlib
import random
from collections import deque
from collections.abc import Awaitable, Callable, Coroutine

import structlog

from drivers.arcos.codec import (
    Arg,
    CodecError,
    Command,
    Decoder,
    PacketType,
    decode_command,
    encode_packet,
    split_vel2,
)
from drivers.arcos.fakebody import FakeBody, SonarFn
from drivers.arcos.fakemotion import MotionGuard, Pose
from drivers.arcos.sip import (
    MAX_RVEL_DEG_S,
    MAX_VEL_MM_S,
    VEL2_DIVISOR_MM_S,
    RobotIdentity,
    encode_config,
    encode_identity,
    wheel_to_vel_rvel,
)
from drivers.transport.clock import REAL_CLOCK, Clock
from drivers.transport.fakeio import PtyPort, TcpPort
from drivers.transport.memlink import LinkFaults, MemoryPort

log = structlog.get_logger(__name__)

SIP_PERIOD_S = 0.1


class FakeRobot(FakeBody):
    """A protocol-true P3-AT served over a pty, loopback TCP and/or an in-memory link."""

    def __init__(
        self,
        name: str = "relay",
        robot_class: str = "Pioneer",
        subclass: str = "p3at",
        *,
        clock: Clock = REAL_CLOCK,
        sonar_fn: SonarFn | None = None,
        motion_guard: MotionGuard | None = None,
        pose: Pose = (0.0, 0.0, 0.0),
        battery_v: float = 13.0,
        trans_accel_mm_s2: float = 300.0,
        rot_accel_deg_s2: float = 100.0,
        sonars_per_sip: int = 8,
        watchdog_s: float = 2.0,
        old_session: bool = False,
        seed: int | None = None,
    ) -> None:
        super().__init__(
            subclass,
            sonar_fn=sonar_fn,
            motion_guard=motion_guard,
            pose=pose,
            battery_v=battery_v,
            trans_accel_mm_s2=trans_accel_mm_s2,
            rot_accel_deg_s2=rot_accel_deg_s2,
            sonars_per_sip=sonars_per_sip,
        )
        self.identity = RobotIdentity(name, robot_class, subclass)
        self.clock = clock
        self.watchdog_s = watchdog_s
        #: SIP cycle (clock s); ARCOS's default is 100 ms. Benchmarks shorten it to get
        #: many control cycles in little wall time.
        self.sip_period_s = SIP_PERIOD_S

        #: every command received, in order, as (command number, argument)
        self.commands: list[tuple[int, Arg]] = []
        self.bad_commands = 0
        self.sips_sent = 0
        self.sessions = 0

        # adversarial switches
        self.split_writes = False  # write each packet in random pieces
        self.garbage = False  # random bytes (never 0xFA) between packets
        self.corrupt_rate = 0.0  # probability of a corrupted checksum per packet
        self.silent = False  # deaf and mute: no replies, no SIPs

        self.synced = False
        self.opened = False
        self._sync_state = 0
        self._last_cmd_t = clock.now()
        self._watchdog_tripped = False
        self._rng = random.Random(seed)
        self._decoder = Decoder()
        self._pty: PtyPort | None = None
        self._tcp: TcpPort | None = None
        self._mem: MemoryPort | None = None
        self._task: asyncio.Task[None] | None = None
        self._bg: set[asyncio.Task[object]] = set()
        self._out: deque[bytes] = deque()
        self._draining = False
        self._tcp_lock = asyncio.Lock()
        if old_session:
            self.start_old_session()

    # ------------------------------------------------------------------ serving

    @property
    def url(self) -> str | None:
        return self._tcp.url if self._tcp is not None else None

    def serve_pty(self, link_path: str | None = None) -> str:
        """Serve on a new pty (a stable symlink at `link_path` if given). Returns the path."""
        if self._pty is None:
            self._pty = PtyPort(self._on_data, link_path)
        path = self._pty.open()
        self._ensure_task()
        return path

    async def serve_tcp(self, port: int = 0) -> str:
        """Serve on 127.0.0.1:`port` (0 = any). Returns the socket:// URL."""
        if self._tcp is None:
            self._tcp = TcpPort(self._on_data, port=port, on_connect=self._on_tcp_connect)
        url = await self._tcp.open()
        self._ensure_task()
        return url

    def serve_memory(
        self,
        name: str,
        *,
        faults_to_driver: LinkFaults | None = None,
        faults_to_device: LinkFaults | None = None,
    ) -> str:
        """Serve on an in-memory link (unit tests). Returns the `memory://` URL."""
        if self._mem is None:
            self._mem = MemoryPort(
                self._on_data,
                name,
                faults_to_driver=faults_to_driver,
                faults_to_device=faults_to_device,
            )
        url = self._mem.open()
        self._ensure_task()
        return url

    @property
    def memory_port(self) -> MemoryPort | None:
        """The in-memory port (to inject faults into its current connection)."""
        return self._mem

    async def start(self) -> None:
        self._ensure_task()

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        for task in list(self._bg):
            task.cancel()
        if self._pty is not None:
            self._pty.close()
        if self._mem is not None:
            self._mem.close()
        if self._tcp is not None:
            await self._tcp.close()

    def hang_up(self) -> None:
        """The cable is pulled: the pty disappears / the TCP listener and client go away."""
        if self._pty is not None:
            self._pty.hang_up()
        if self._mem is not None:
            self._mem.hang_up()
        if self._tcp is not None:
            self._end_session()
            self._spawn(self._tcp_op(self._tcp.close))

    def reappear(self) -> None:
        """The cable is back (same pty link path / same TCP port)."""
        if self._pty is not None:
            self._pty.open()
        if self._mem is not None:
            self._mem.open()
        if self._tcp is not None:
            self._spawn(self._tcp_op(self._tcp.open))

    def start_old_session(self) -> None:
        """Behave as a robot whose last client never sent CLOSE: already OPEN, streaming SIPs."""
        self.synced = True
        self.opened = True
        self.sonar_on = True
        self._last_cmd_t = self.clock.now()

    async def _tcp_op(self, op: Callable[[], Awaitable[object]]) -> None:
        # hang_up()/reappear() are synchronous: run their TCP halves strictly in order.
        async with self._tcp_lock:
            await op()

    def _spawn(self, coro: Coroutine[object, object, object]) -> None:
        task: asyncio.Task[object] = asyncio.ensure_future(coro)
        self._bg.add(task)
        task.add_done_callback(self._bg.discard)

    def _ensure_task(self) -> None:
        if self._task is None or self._task.done():
            self._task = asyncio.get_running_loop().create_task(self._sip_loop(), name="fake-robot")

    def _on_tcp_connect(self) -> None:
        # MobileSim: each TCP client starts from scratch.
        self._end_session()
        self._decoder.reset()
        self._out.clear()

    # ------------------------------------------------------------------ commands

    def _on_data(self, data: bytes) -> None:
        if self.silent:
            return
        for pkt in self._decoder.feed(data):
            try:
                cmd, arg = decode_command(pkt)
            except CodecError as exc:
                self.bad_commands += 1
                log.debug("fake_robot_bad_command", error=str(exc))
                continue
            self.commands.append((cmd, arg))
            self._last_cmd_t = self.clock.now()
            self._watchdog_tripped = False
            self._handle(cmd, arg)

    def _handle(self, cmd: int, arg: Arg) -> None:
        if not self.opened:
            self._handle_sync(cmd)
            return
        iarg = arg if isinstance(arg, int) else None
        if cmd == Command.SYNC2:  # CLOSE
            self._end_session()
        elif cmd == Command.ENABLE:
            self.motors_enabled = bool(iarg)
            if not self.motors_enabled:
                self._halt(hard=True)
        elif cmd == Command.VEL and iarg is not None and self._can_move():
            self.target_vel_mm_s = float(max(-MAX_VEL_MM_S, min(MAX_VEL_MM_S, iarg)))
        elif cmd in (Command.RVEL, Command.ROTATE) and iarg is not None and self._can_move():
            self.target_rvel_deg_s = float(max(-MAX_RVEL_DEG_S, min(MAX_RVEL_DEG_S, iarg)))
        elif cmd == Command.VEL2 and iarg is not None and self._can_move():
            left, right = split_vel2(iarg)
            vel, rvel = wheel_to_vel_rvel(left * VEL2_DIVISOR_MM_S, right * VEL2_DIVISOR_MM_S)
            self.target_vel_mm_s, self.target_rvel_deg_s = float(vel), float(rvel)
        elif cmd == Command.STOP:
            self._halt(hard=False)
        elif cmd == Command.E_STOP:
            self._halt(hard=True)
        elif cmd == Command.SONAR:
            self.sonar_on = iarg is None or iarg != 0
        elif cmd == Command.CONFIG:
            self._emit(
                encode_packet(
                    PacketType.CONFIG,
                    encode_config(
                        self.identity,
                        watchdog_ms=round(self.watchdog_s * 1000),
                        trans_accel=round(self.trans_accel_mm_s2),
                        rot_accel=round(self.rot_accel_deg_s2),
                    ),
                )
            )
        elif cmd == Command.SETO:
            self.reset_odometry()
        # PULSE, OPEN and everything else: recorded only (MobileSim ignores unknown numbers).

    def _handle_sync(self, cmd: int) -> None:
        if cmd == Command.SYNC0:
            self._sync_state = 1
            self.synced = False
            self._emit(encode_packet(PacketType.SYNC0))
        elif cmd == Command.SYNC1 and self._sync_state == 1:
            self._sync_state = 2
            self._emit(encode_packet(PacketType.SYNC1))
        elif cmd == Command.SYNC2 and self._sync_state >= 2:
            self._sync_state = 3
            self.synced = True
            self._emit(encode_packet(PacketType.SYNC2, encode_identity(self.identity)))
        elif cmd == Command.SYNC1 and self.synced:  # OPEN
            self._open_session()

    def _open_session(self) -> None:
        self.opened = True
        self.sessions += 1
        self.motors_enabled = False  # motors are off after every connect (docs/PROTOCOLS.md 1.5)
        self.sonar_on = True  # "ARIA assumes sonar are on at start" (MobileSim)
        self.reset_odometry()
        self._halt(hard=True)
        self._last_cmd_t = self.clock.now()

    def _end_session(self) -> None:
        self.opened = False
        self.synced = False
        self._sync_state = 0
        self.motors_enabled = False
        self._halt(hard=True)

    # ------------------------------------------------------------------ the SIP loop

    async def _sip_loop(self) -> None:
        last = next_t = self.clock.now()
        while True:
            next_t += self.sip_period_s
            await self.clock.sleep(next_t - self.clock.now())
            now = self.clock.now()
            if now - next_t > 5 * self.sip_period_s:
                next_t = now  # we were starved; do not burst to catch up
            try:
                self.step(now - last, now)
                last = now
                if self.opened and not self.silent:
                    self._send_sip()
            except Exception:  # a sonar_fn/motion_guard bug must not kill the robot
                log.exception("fake_robot_step_error")
                last = now

    def step(self, dt: float, now: float | None = None) -> None:
        """Advance by `dt` clock seconds: the ARCOS watchdog, then the motion (the SIP loop
        calls this)."""
        now = self.clock.now() if now is None else now
        if self.opened and now - self._last_cmd_t > self.watchdog_s and not self._watchdog_tripped:
            # The ARCOS watchdog: no packet for `watchdog_s` stops the robot.
            self._watchdog_tripped = True
            self._halt(hard=False)
            log.info("fake_robot_watchdog_stop")
        self.move(dt)

    def _send_sip(self) -> None:
        ptype, payload = self.build_sip().encode()
        self._emit(encode_packet(ptype, payload))
        self.sips_sent += 1

    # ------------------------------------------------------------------ output

    def _emit(self, data: bytes) -> None:
        if self.silent:
            return
        if self.corrupt_rate and self._rng.random() < self.corrupt_rate:
            data = data[:-1] + bytes(((data[-1] + 1 + self._rng.randrange(255)) & 0xFF,))
        if self.garbage:
            # Never 0xFA: a false header would stall the stream until 255 bytes arrived.
            junk = bytes(
                self._rng.choice([b for b in range(256) if b != 0xFA])
                for _ in range(self._rng.randint(1, 8))
            )
            data = junk + data
        if self.split_writes and len(data) > 1:
            cuts = sorted(self._rng.sample(range(1, len(data)), min(3, len(data) - 1)))
            pieces = [data[a:b] for a, b in zip([0, *cuts], [*cuts, len(data)], strict=True)]
            self._out.extend(pieces)
        else:
            self._out.append(data)
        if not self._draining:
            if self.split_writes:
                self._draining = True
                asyncio.get_running_loop().call_later(0.001, self._drain)
            else:
                self._flush()

    def _flush(self) -> None:
        while self._out:
            self._write(self._out.popleft())

    def _drain(self) -> None:
        # One piece per wakeup so the driver really sees partial packets.
        if self._out:
            self._write(self._out.popleft())
        if self._out:
            asyncio.get_running_loop().call_later(0.001, self._drain)
        else:
            self._draining = False

    def _write(self, data: bytes) -> None:
        if self._pty is not None:
            self._pty.write(data)
        if self._mem is not None:
            self._mem.write(data)
        if self._tcp is not None:
            self._tcp.write(data)
