"""Lynxmotion SSC-32 / SSC-32U ASCII protocol: a pure codec and the `Ssc32PanTilt` back-end.

Commands are ASCII lines ending in CR (docs/PROTOCOLS.md 2.3):
`#<ch>P<pw>S<spd>T<time>` moves (several `#..P..` before one CR form a group move
that starts and ends together), `Q` answers `.` (done) or `+` (moving), `QP<ch>`
answers one binary byte = pulse width / 10 us. The controller keeps no speed
setting: the slew speed (`S`, us per second) travels with every move, so this
back-end remembers it per channel. Positions read back with 10 us resolution.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from drivers.pantilt.base import PanTilt
from drivers.pantilt.calibration import ServoCalibration
from drivers.pantilt.session import PanTiltError, ReplyError
from drivers.transport.clock import REAL_CLOCK, Clock

MAX_CHANNELS = 32
MIN_PULSE_US = 500
MAX_PULSE_US = 2500
MAX_SPEED_US_S = 65535
MAX_TIME_MS = 65535
CR = b"\r"
QUERY_MOVEMENT = b"Q\r"
#: SSC-32U factory baud rate.
DEFAULT_BAUD = 9600


class Ssc32SyntaxError(ValueError):
    """A command line the SSC-32 would ignore."""


@dataclass(frozen=True, slots=True)
class Ssc32Move:
    channel: int
    pulse_us: int
    speed_us_s: int | None = None  # None or 0: as fast as the servo goes


@dataclass(frozen=True, slots=True)
class Ssc32GroupMove:
    moves: tuple[Ssc32Move, ...]
    time_ms: int | None = None


@dataclass(frozen=True, slots=True)
class Ssc32QueryMovement:
    pass


@dataclass(frozen=True, slots=True)
class Ssc32QueryPulse:
    channels: tuple[int, ...]


Ssc32Command = Ssc32GroupMove | Ssc32QueryMovement | Ssc32QueryPulse

_MOVE_RE = re.compile(rb"#(\d{1,2})P(\d{1,5})(?:S(\d{1,5}))?")
_GROUP_RE = re.compile(rb"(?:#\d{1,2}P\d{1,5}(?:S\d{1,5})?)+(?:T(\d{1,5}))?")
_QP_RE = re.compile(rb"(?:QP\d{1,2})+")


def _check_move(channel: int, pulse_us: int, speed_us_s: int | None) -> None:
    if not 0 <= channel < MAX_CHANNELS:
        raise ValueError(f"SSC-32 channel out of range 0..{MAX_CHANNELS - 1}: {channel}")
    if not MIN_PULSE_US <= pulse_us <= MAX_PULSE_US:
        raise ValueError(f"SSC-32 pulse out of range {MIN_PULSE_US}..{MAX_PULSE_US} us: {pulse_us}")
    if speed_us_s is not None and not 0 <= speed_us_s <= MAX_SPEED_US_S:
        raise ValueError(f"SSC-32 speed out of range 0..{MAX_SPEED_US_S} us/s: {speed_us_s}")


def encode_move(
    channel: int, pulse_us: int, speed_us_s: int | None = None, time_ms: int | None = None
) -> bytes:
    """`#<ch>P<pw>[S<spd>][T<time>]\\r`; speed None or 0 is sent as no S (full speed)."""
    return encode_group_move([Ssc32Move(channel, pulse_us, speed_us_s)], time_ms)


def encode_group_move(moves: Sequence[Ssc32Move], time_ms: int | None = None) -> bytes:
    if not moves:
        raise ValueError("a group move needs at least one servo")
    parts = []
    for m in moves:
        _check_move(m.channel, m.pulse_us, m.speed_us_s)
        parts.append(f"#{m.channel}P{m.pulse_us}" + (f"S{m.speed_us_s}" if m.speed_us_s else ""))
    if time_ms is not None:
        if not 0 <= time_ms <= MAX_TIME_MS:
            raise ValueError(f"SSC-32 move time out of range 0..{MAX_TIME_MS} ms: {time_ms}")
        parts.append(f"T{time_ms}")
    return "".join(parts).encode("ascii") + CR


def encode_query_pulse(*channels: int) -> bytes:
    if not channels:
        raise ValueError("QP needs at least one channel")
    for ch in channels:
        if not 0 <= ch < MAX_CHANNELS:
            raise ValueError(f"SSC-32 channel out of range 0..{MAX_CHANNELS - 1}: {ch}")
    return b"".join(b"QP%d" % ch for ch in channels) + CR


def decode_movement(reply: bytes) -> bool:
    """`Q` reply: `.` -> False (all moves done), `+` -> True (still moving)."""
    if reply == b".":
        return False
    if reply == b"+":
        return True
    raise ReplyError(f"Q reply must be '.' or '+', got {reply!r}")


def decode_pulse_us(reply: bytes) -> int:
    """`QP` reply: one byte, pulse width / 10 us (0 = channel never commanded)."""
    if len(reply) != 1:
        raise ReplyError(f"QP reply must be one byte, got {len(reply)}: {reply!r}")
    return reply[0] * 10


def parse_command(line: bytes) -> Ssc32Command:
    """One command line (without its CR) as the controller reads it.

    Case-insensitive; spaces, tabs and LF are ignored. Raises Ssc32SyntaxError for
    anything the controller would not act on.
    """
    text = line.upper().translate(None, b" \t\n")
    if text == b"Q":
        return Ssc32QueryMovement()
    if _QP_RE.fullmatch(text):
        channels = tuple(int(c) for c in re.findall(rb"QP(\d{1,2})", text))
        if any(ch >= MAX_CHANNELS for ch in channels):
            raise Ssc32SyntaxError(f"channel out of range in {line!r}")
        return Ssc32QueryPulse(channels)
    group = _GROUP_RE.fullmatch(text)
    if group is None:
        raise Ssc32SyntaxError(f"not an SSC-32 command: {line!r}")
    moves = []
    for ch_s, pw_s, spd_s in _MOVE_RE.findall(text):
        channel, pulse = int(ch_s), int(pw_s)
        speed = int(spd_s) if spd_s else None
        try:
            _check_move(channel, pulse, speed)
        except ValueError as exc:
            raise Ssc32SyntaxError(str(exc)) from None
        moves.append(Ssc32Move(channel, pulse, speed))
    time_ms = int(group.group(1)) if group.group(1) else None
    if time_ms is not None and time_ms > MAX_TIME_MS:
        raise Ssc32SyntaxError(f"move time out of range in {line!r}")
    return Ssc32GroupMove(tuple(moves), time_ms)


class Ssc32PanTilt(PanTilt):
    """Servos on a Lynxmotion SSC-32 / SSC-32U."""

    protocol_name = "ssc32"

    def __init__(
        self,
        url: str,
        baud: int,
        calibrations: Mapping[int, ServoCalibration],
        *,
        clock: Clock = REAL_CLOCK,
        **kwargs: Any,
    ) -> None:
        super().__init__(url, baud, calibrations, clock=clock, **kwargs)
        self._speed_us_s: dict[int, int] = {}

    def _check_channel_range(self, channel: int, cal: ServoCalibration) -> None:
        if not 0 <= channel < MAX_CHANNELS:
            raise ValueError(f"SSC-32 channel out of range 0..{MAX_CHANNELS - 1}: {channel}")
        lo, hi = cal.pulse_range_us()
        if round(lo) < MIN_PULSE_US or round(hi) > MAX_PULSE_US:
            raise ValueError(
                f"channel {channel}: pulses {lo:.0f}..{hi:.0f} us are outside "
                f"the SSC-32's {MIN_PULSE_US}..{MAX_PULSE_US} us"
            )

    async def _send_target(self, channel: int, pulse_us: float) -> None:
        speed = self._speed_us_s.get(channel)
        await self._write(encode_move(channel, round(pulse_us), speed or None))

    async def _send_speed(self, channel: int, us_per_s: float) -> None:
        # Nothing to send: the SSC-32 takes the speed with each move.
        self._speed_us_s[channel] = (
            0 if us_per_s <= 0 else min(MAX_SPEED_US_S, max(1, round(us_per_s)))
        )

    async def _read_pulse_us(self, channel: int) -> float:
        reply = await self._request(encode_query_pulse(channel), 1)
        return float(decode_pulse_us(reply))

    async def _read_moving(self) -> bool:
        reply = await self._request(QUERY_MOVEMENT, 1)
        try:
            return decode_movement(reply)
        except ReplyError as exc:
            raise self._reply_error(exc) from None


__all__ = [
    "PanTiltError",
    "Ssc32Command",
    "Ssc32GroupMove",
    "Ssc32Move",
    "Ssc32PanTilt",
    "Ssc32QueryMovement",
    "Ssc32QueryPulse",
    "Ssc32SyntaxError",
    "decode_movement",
    "decode_pulse_us",
    "encode_group_move",
    "encode_move",
    "encode_query_pulse",
    "parse_command",
]
