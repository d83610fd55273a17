"""Byte-true fake servo controllers (Pololu Maestro, Lynxmotion SSC-32) on a real pty.

Each fake plays the controller's side of the wire: it parses the byte stream as the
firmware does, answers queries with the same bytes, and rejects malformed input the
way the device does (the Maestro sets its serial-protocol error bit; the SSC-32
ignores a line it cannot read). Simulated servos slew from where they are to their
target at the configured speed in clock time; positions are evaluated lazily from
the time of the last command, so no timer runs while nothing is asked.

Known simplifications: a new target or speed mid-move restarts the ramp from rest
at the current position (the Maestro keeps the current velocity), and a "silent"
fake ignores its input entirely, like a controller whose logic has hung. The servos'
motion model (the speed and acceleration ramp) is in slew.py.
"""

from __future__ import annotations

import abc
import os

from drivers.pantilt import maestro as mc
from drivers.pantilt import ssc32 as sc
from drivers.pantilt.slew import SimServo, travelled_us
from drivers.transport.clock import REAL_CLOCK, Clock
from drivers.transport.fakeio import PtyPort
from drivers.transport.memlink import LinkFaults, MemoryPort

__all__ = ["FakeMaestro", "FakeSsc32", "SimServo", "travelled_us"]

#: Longest SSC-32 line kept; the rest of an over-long line is dropped until CR.
MAX_LINE = 256


class _FakeController(abc.ABC):
    """Shared plumbing: the pty, silence, servos, the bytes the driver sent."""

    def __init__(self, channels: int, initial_us: float | None, clock: Clock) -> None:
        self._clock = clock
        self.servos = [SimServo() for _ in range(channels)]
        if initial_us:
            for s in self.servos:
                s.start_us = s.target_us = initial_us
        self.silent = False
        #: Every byte the driver sent (while not silent) and every reply byte sent back.
        self.received = bytearray()
        self.sent = bytearray()
        self._port: PtyPort | MemoryPort | None = None

    @property
    def channel_count(self) -> int:
        return len(self.servos)

    def serve_pty(self, link_path: str | os.PathLike[str] | None = None) -> str:
        """Open a pty for the driver; returns the path to open (the stable link if given)."""
        self._port = PtyPort(self.feed, link_path=link_path)
        return self._port.open()

    def serve_memory(
        self,
        name: str,
        *,
        faults_to_driver: LinkFaults | None = None,
        faults_to_device: LinkFaults | None = None,
    ) -> str:
        """Serve on an in-memory link (unit tests); returns the `memory://` URL to open."""
        self._port = MemoryPort(
            self.feed, name, faults_to_driver=faults_to_driver, faults_to_device=faults_to_device
        )
        return self._port.open()

    @property
    def memory_port(self) -> MemoryPort | None:
        """The in-memory port, if serving on one (to inject faults into its connection)."""
        return self._port if isinstance(self._port, MemoryPort) else None

    @property
    def path(self) -> str:
        return self._port.path if self._port is not None else ""

    def hang_up(self) -> None:
        """Drop the port as a pulled USB cable does; servo state is kept."""
        if self._port is not None:
            self._port.hang_up()
        self._reset_parser()

    def reappear(self) -> str:
        """Plug back in (same stable link path when one was given)."""
        if self._port is None:
            raise RuntimeError("serve_pty() or serve_memory() first")
        return self._port.open()

    def close(self) -> None:
        if self._port is not None:
            self._port.close()

    def position_us(self, channel: int) -> float:
        return self.servos[channel].position_us(self._clock.now())

    def target_us(self, channel: int) -> float:
        return self.servos[channel].target_us

    def moving(self) -> bool:
        now = self._clock.now()
        return any(s.moving(now) for s in self.servos)

    def feed(self, data: bytes) -> None:
        """Bytes as they arrive from the driver (the pty calls this)."""
        if self.silent:
            return
        self.received += data
        self._feed(data)

    def send_noise(self, data: bytes) -> None:
        """Put bytes on the wire that no request asked for (line noise, a reset banner)."""
        self._reply(data)

    def _reply(self, data: bytes) -> None:
        self.sent += data
        if self._port is not None:
            self._port.write(data)

    @abc.abstractmethod
    def _feed(self, data: bytes) -> None:
        """Parse bytes as the controller's firmware does."""

    @abc.abstractmethod
    def _reset_parser(self) -> None:
        """Forget a half-received frame (the cable was pulled mid-frame)."""


# Data bytes after the command byte, per compact command.
_MAESTRO_DATA_LEN: dict[int, int] = {
    mc.MaestroCommand.SET_TARGET: 3,
    mc.MaestroCommand.SET_SPEED: 3,
    mc.MaestroCommand.SET_ACCELERATION: 3,
    mc.MaestroCommand.GET_POSITION: 1,
    mc.MaestroCommand.GET_MOVING_STATE: 0,
    mc.MaestroCommand.GET_ERRORS: 0,
    mc.MaestroCommand.GO_HOME: 0,
}


class FakeMaestro(_FakeController):
    """A Pololu Maestro in USB Dual Port mode: compact, Pololu and Mini SSC protocols.

    `range_us` is the per-channel min/max the Maestro clamps targets to (factory
    992..2000 us); `home_us` maps channels to their home pulse (0 = off; channels not
    listed are "ignore"), used by Go Home and whenever an error bit gets set.
    """

    def __init__(
        self,
        *,
        clock: Clock = REAL_CLOCK,
        channels: int = 6,
        initial_us: float | None = None,
        range_us: tuple[float, float] = (992.0, 2000.0),
        home_us: dict[int, float] | None = None,
        device_number: int = mc.DEFAULT_DEVICE_NUMBER,
    ) -> None:
        super().__init__(channels, initial_us, clock)
        self.range_us = range_us
        self.home_us = dict(home_us or {})
        self.device_number = device_number
        self.error_bits = 0
        self.speed_units = [0] * channels
        self.accel_units = [0] * channels
        #: Decoded commands in arrival order, e.g. ("set_target", 0, 6000).
        self.commands: list[tuple[object, ...]] = []
        #: Why the last frame was rejected (the firmware only sets the error bit).
        self.last_protocol_error = ""
        self._frame = bytearray()

    def _reset_parser(self) -> None:
        self._frame.clear()

    def raise_error(self, bits: int) -> None:
        """Set error bits as the firmware does (and send every channel home)."""
        self.error_bits |= bits
        now = self._clock.now()
        for ch, home in self.home_us.items():
            self.servos[ch].retarget(now, home)

    def _protocol_error(self, why: str) -> None:
        self.last_protocol_error = why
        self._frame.clear()
        self.raise_error(mc.MaestroError.SERIAL_PROTOCOL)

    def _feed(self, data: bytes) -> None:
        for b in data:
            self._byte(b)

    def _byte(self, b: int) -> None:
        frame = self._frame
        if frame and frame[0] == mc.MINI_SSC_START:
            # Mini SSC data bytes may have the top bit set (targets up to 254).
            frame.append(b)
            if len(frame) == 3:
                self._mini_ssc(frame[1], frame[2])
                frame.clear()
            return
        if b & 0x80:
            if frame:
                self._protocol_error("command byte inside an unfinished frame")
            frame.append(b)
            if b not in _MAESTRO_DATA_LEN and b not in (mc.POLOLU_START, mc.MINI_SSC_START):
                self._protocol_error(f"unknown command {b:#04x}")
                return
        else:
            if not frame:
                self._protocol_error(f"data byte {b:#04x} without a command")
                return
            frame.append(b)
        self._try_frame()

    def _try_frame(self) -> None:
        frame = self._frame
        if frame[0] == mc.POLOLU_START:
            if len(frame) < 3:
                return
            cmd = frame[2] | 0x80
            if cmd not in _MAESTRO_DATA_LEN:
                self._protocol_error(f"unknown Pololu-protocol command {frame[2]:#04x}")
                return
            if len(frame) < 3 + _MAESTRO_DATA_LEN[cmd]:
                return
            device, body = frame[1], bytes(frame[3:])
            frame.clear()
            if device == self.device_number:
                self._execute(cmd, body)
            return
        cmd = frame[0]
        if cmd == mc.MINI_SSC_START:
            return  # its two data bytes are taken raw by _byte()
        if len(frame) < 1 + _MAESTRO_DATA_LEN[cmd]:
            return
        body = bytes(frame[1:])
        frame.clear()
        self._execute(cmd, body)

    def _execute(self, cmd: int, body: bytes) -> None:
        now = self._clock.now()
        if body and body[0] >= self.channel_count:
            self.raise_error(mc.MaestroError.SERIAL_PROTOCOL)
            return
        if cmd == mc.MaestroCommand.SET_TARGET:
            ch, value = body[0], mc.decode_14bit(body[1], body[2])
            self.commands.append(("set_target", ch, value))
            target = value / 4.0
            if target:
                target = min(self.range_us[1], max(self.range_us[0], target))
            self.servos[ch].retarget(now, target)
        elif cmd == mc.MaestroCommand.SET_SPEED:
            ch, value = body[0], mc.decode_14bit(body[1], body[2])
            self.commands.append(("set_speed", ch, value))
            self.speed_units[ch] = value
            self._apply_profile(ch, now)
        elif cmd == mc.MaestroCommand.SET_ACCELERATION:
            ch, value = body[0], mc.decode_14bit(body[1], body[2])
            self.commands.append(("set_acceleration", ch, value))
            # The firmware caps acceleration at 255.
            self.accel_units[ch] = min(255, value)
            self._apply_profile(ch, now)
        elif cmd == mc.MaestroCommand.GET_POSITION:
            ch = body[0]
            self.commands.append(("get_position", ch))
            quarter = round(self.servos[ch].position_us(now) * 4)
            self._reply(bytes((quarter & 0xFF, (quarter >> 8) & 0xFF)))
        elif cmd == mc.MaestroCommand.GET_MOVING_STATE:
            self.commands.append(("get_moving_state",))
            self._reply(b"\x01" if self.moving() else b"\x00")
        elif cmd == mc.MaestroCommand.GET_ERRORS:
            self.commands.append(("get_errors",))
            bits, self.error_bits = self.error_bits, 0
            self._reply(bytes((bits & 0xFF, (bits >> 8) & 0xFF)))
        elif cmd == mc.MaestroCommand.GO_HOME:
            self.commands.append(("go_home",))
            for ch, home in self.home_us.items():
                self.servos[ch].retarget(now, home)

    def _apply_profile(self, ch: int, now: float) -> None:
        self.servos[ch].set_profile(
            now,
            self.speed_units[ch] * mc.US_PER_S_PER_SPEED_UNIT,
            self.accel_units[ch] * mc.US_PER_S2_PER_ACCEL_UNIT,
        )

    def _mini_ssc(self, servo: int, target8: int) -> None:
        # Default Mini SSC offset 0, neutral 1500 us, range 476.25 us (formula UNVERIFIED).
        if servo >= self.channel_count or target8 > 254:
            self.raise_error(mc.MaestroError.SERIAL_PROTOCOL)
            return
        self.commands.append(("mini_ssc", servo, target8))
        target = 1500.0 + (target8 - 127) / 127 * 476.25
        self.servos[servo].retarget(self._clock.now(), target)


class FakeSsc32(_FakeController):
    """A Lynxmotion SSC-32/SSC-32U: ASCII lines, group moves, Q and QP queries."""

    def __init__(
        self,
        *,
        clock: Clock = REAL_CLOCK,
        channels: int = sc.MAX_CHANNELS,
        initial_us: float | None = None,
    ) -> None:
        super().__init__(channels, initial_us, clock)
        #: Parsed commands in arrival order.
        self.commands: list[sc.Ssc32Command] = []
        #: Lines the controller could not read and therefore ignored.
        self.ignored_lines = 0
        self._line = bytearray()
        self._overlong = False

    def _reset_parser(self) -> None:
        self._line.clear()
        self._overlong = False

    def _feed(self, data: bytes) -> None:
        for b in data:
            if b == 0x0D:
                line, overlong = bytes(self._line), self._overlong
                self._reset_parser()
                if overlong:
                    self.ignored_lines += 1
                else:
                    self._line_received(line)
            elif len(self._line) >= MAX_LINE:
                self._overlong = True
            else:
                self._line.append(b)

    def _line_received(self, line: bytes) -> None:
        if not line.strip(b" \t\n"):
            return  # a bare CR is not an error, just nothing to do
        try:
            cmd = sc.parse_command(line)
        except sc.Ssc32SyntaxError:
            self.ignored_lines += 1
            return
        if isinstance(cmd, sc.Ssc32GroupMove) and any(
            m.channel >= self.channel_count for m in cmd.moves
        ):
            self.ignored_lines += 1
            return
        self.commands.append(cmd)
        now = self._clock.now()
        if isinstance(cmd, sc.Ssc32QueryMovement):
            self._reply(b"+" if self.moving() else b".")
        elif isinstance(cmd, sc.Ssc32QueryPulse):
            self._reply(
                bytes(min(255, round(self.servos[ch].position_us(now) / 10)) for ch in cmd.channels)
            )
        else:
            self._group_move(cmd, now)

    def _group_move(self, cmd: sc.Ssc32GroupMove, now: float) -> None:
        # All servos of a group start together and arrive together: the group lasts as
        # long as its slowest member (or T, if longer), each servo slews linearly.
        durations = []
        for m in cmd.moves:
            start = self.servos[m.channel].position_us(now)
            dist = abs(m.pulse_us - start) if start > 0 else 0.0
            durations.append(dist / m.speed_us_s if m.speed_us_s else 0.0)
        duration = max([*durations, (cmd.time_ms or 0) / 1000.0])
        for m in cmd.moves:
            servo = self.servos[m.channel]
            start = servo.position_us(now)
            dist = abs(m.pulse_us - start) if start > 0 else 0.0
            servo.set_profile(now, dist / duration if duration > 0 and dist > 0 else 0.0, 0.0)
            servo.retarget(now, float(m.pulse_us))


__all__ = ["FakeMaestro", "FakeSsc32", "SimServo", "travelled_us"]
