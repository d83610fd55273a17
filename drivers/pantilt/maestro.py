"""Pololu Maestro compact serial protocol: a pure codec and the `MaestroPanTilt` back-end.

Command bytes have the top bit set, data bytes carry 7 bits; 14-bit values go low 7
bits first. Targets and positions are in quarter-microseconds, speed in 0.25 us per
10 ms, acceleration in 0.25 us per 10 ms per 80 ms (docs/PROTOCOLS.md 2.2).
Replies are little-endian 16-bit words (8 bits per byte, unlike the 7-bit requests).
The Maestro must be in "USB Dual Port" mode for the command port to listen at all.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from enum import IntEnum, IntFlag
from typing import Any

from drivers.pantilt.base import PanTilt
from drivers.pantilt.calibration import ServoCalibration
from drivers.pantilt.session import PanTiltError, ReplyError
from drivers.transport.clock import REAL_CLOCK, Clock

#: Largest 14-bit data value.
MAX_14BIT = 0x3FFF
#: Channels on the biggest Maestro (Mini Maestro 24).
MAX_CHANNELS = 24
#: Pulse change per second of one Set Speed unit: 0.25 us per 10 ms.
US_PER_S_PER_SPEED_UNIT = 25.0
#: Pulse change per second squared of one Set Acceleration unit: 0.25 us / 10 ms / 80 ms.
US_PER_S2_PER_ACCEL_UNIT = 0.25 / (0.010 * 0.080)
#: Pololu-protocol frames start with this byte, then the device number.
POLOLU_START = 0xAA
#: Factory default device number for the Pololu protocol.
DEFAULT_DEVICE_NUMBER = 12
#: Mini SSC frames start with this byte.
MINI_SSC_START = 0xFF


class MaestroCommand(IntEnum):
    SET_TARGET = 0x84
    SET_SPEED = 0x87
    SET_ACCELERATION = 0x89
    GET_POSITION = 0x90
    GET_MOVING_STATE = 0x93
    GET_ERRORS = 0xA1
    GO_HOME = 0xA2


class MaestroError(IntFlag):
    """Bits of the Get Errors reply (bit 8 is UNVERIFIED in the research notes)."""

    SERIAL_SIGNAL = 1 << 0  # a stop bit was missing: baud mismatch
    SERIAL_OVERRUN = 1 << 1
    SERIAL_RX_BUFFER_FULL = 1 << 2
    SERIAL_CRC = 1 << 3
    SERIAL_PROTOCOL = 1 << 4  # malformed or unknown command
    SERIAL_TIMEOUT = 1 << 5
    SCRIPT_STACK = 1 << 6
    SCRIPT_CALL_STACK = 1 << 7
    SCRIPT_PROGRAM_COUNTER = 1 << 8


def error_names(flags: int) -> tuple[str, ...]:
    """Lower-case names of the set error bits, lowest bit first; unknown bits as bitN."""
    known = {int(m): str(m.name).lower() for m in MaestroError}
    return tuple(known.get(1 << bit, f"bit{bit}") for bit in range(16) if flags & (1 << bit))


def encode_14bit(value: int) -> bytes:
    """Two data bytes: low 7 bits, then bits 7-13."""
    if not 0 <= value <= MAX_14BIT:
        raise ValueError(f"14-bit value out of range 0..{MAX_14BIT}: {value}")
    return bytes((value & 0x7F, (value >> 7) & 0x7F))


def decode_14bit(lo: int, hi: int) -> int:
    if lo > 0x7F or hi > 0x7F or lo < 0 or hi < 0:
        raise ValueError(f"not 7-bit data bytes: {lo:#x} {hi:#x}")
    return lo | (hi << 7)


def _channel(channel: int) -> int:
    if not 0 <= channel < MAX_CHANNELS:
        raise ValueError(f"Maestro channel out of range 0..{MAX_CHANNELS - 1}: {channel}")
    return channel


def set_target(channel: int, quarter_us: int) -> bytes:
    """`84 ch lo hi`; target 0 stops the pulses on that channel."""
    return bytes((MaestroCommand.SET_TARGET, _channel(channel))) + encode_14bit(quarter_us)


def set_speed(channel: int, units: int) -> bytes:
    return bytes((MaestroCommand.SET_SPEED, _channel(channel))) + encode_14bit(units)


def set_acceleration(channel: int, units: int) -> bytes:
    return bytes((MaestroCommand.SET_ACCELERATION, _channel(channel))) + encode_14bit(units)


def get_position(channel: int) -> bytes:
    return bytes((MaestroCommand.GET_POSITION, _channel(channel)))


def get_moving_state() -> bytes:
    return bytes((MaestroCommand.GET_MOVING_STATE,))


def get_errors() -> bytes:
    return bytes((MaestroCommand.GET_ERRORS,))


def go_home() -> bytes:
    return bytes((MaestroCommand.GO_HOME,))


def pololu_frame(compact: bytes, device: int = DEFAULT_DEVICE_NUMBER) -> bytes:
    """The same command in the Pololu protocol: `AA dev cmd&7F data...`."""
    if not compact or compact[0] < 0x80:
        raise ValueError("not a compact command frame")
    if not 0 <= device <= 0x7F:
        raise ValueError(f"device number out of range 0..127: {device}")
    return bytes((POLOLU_START, device, compact[0] & 0x7F)) + compact[1:]


def us_to_quarter(pulse_us: float) -> int:
    return round(pulse_us * 4)


def speed_units(us_per_s: float) -> int:
    """Set Speed units for a pulse slew of `us_per_s` (0 = unlimited); never rounds to 0."""
    if us_per_s <= 0 or math.isinf(us_per_s):
        return 0
    return min(MAX_14BIT, max(1, round(us_per_s / US_PER_S_PER_SPEED_UNIT)))


def accel_units(us_per_s2: float) -> int:
    if us_per_s2 <= 0 or math.isinf(us_per_s2):
        return 0
    return min(255, max(1, round(us_per_s2 / US_PER_S2_PER_ACCEL_UNIT)))


def decode_word(reply: bytes) -> int:
    """A 2-byte little-endian reply (Get Position, Get Errors)."""
    if len(reply) != 2:
        raise ReplyError(f"expected 2 bytes, got {len(reply)}: {reply.hex(' ')}")
    return reply[0] | (reply[1] << 8)


def decode_position_us(reply: bytes) -> float:
    """Get Position reply -> pulse width in microseconds (0 = pulses off)."""
    quarter = decode_word(reply)
    if quarter > MAX_14BIT:
        raise ReplyError(f"position {quarter} quarter-us is beyond any target")
    return quarter / 4.0


def decode_moving_state(reply: bytes) -> bool:
    if len(reply) != 1 or reply[0] not in (0, 1):
        raise ReplyError(f"moving state must be 00 or 01, got {reply.hex(' ') or 'nothing'}")
    return reply[0] == 1


def decode_errors(reply: bytes) -> MaestroError:
    word = decode_word(reply)
    # Bits above the documented ones are kept: error_names() reports them as bitN.
    return MaestroError(word & 0xFFFF)


class MaestroPanTilt(PanTilt):
    """Servos on a Pololu Maestro (compact protocol over the USB command port)."""

    protocol_name = "maestro"

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
        self._accel: dict[int, int] = {}
        #: Names from the latest Get Errors that reported anything (the device clears on read).
        self.maestro_errors: tuple[str, ...] = ()
        self.counters["device_errors"] = 0

    def _check_channel_range(self, channel: int, cal: ServoCalibration) -> None:
        _channel(channel)
        lo, hi = cal.pulse_range_us()
        if us_to_quarter(lo) < 1 or us_to_quarter(hi) > MAX_14BIT:
            raise ValueError(
                f"channel {channel}: pulses {lo:.0f}..{hi:.0f} us are outside "
                f"the Maestro's 0.25..{MAX_14BIT / 4} us"
            )

    async def _send_target(self, channel: int, pulse_us: float) -> None:
        await self._write(set_target(channel, us_to_quarter(pulse_us)))

    async def _send_speed(self, channel: int, us_per_s: float) -> None:
        await self._write(set_speed(channel, speed_units(us_per_s)))

    async def _read_pulse_us(self, channel: int) -> float:
        reply = await self._request(get_position(channel), 2)
        try:
            return decode_position_us(reply)
        except ReplyError as exc:
            raise self._reply_error(exc) from None

    async def _read_moving(self) -> bool:
        reply = await self._request(get_moving_state(), 1)
        try:
            return decode_moving_state(reply)
        except ReplyError as exc:
            raise self._reply_error(exc) from None

    async def _on_connected(self) -> None:
        # Get Errors proves the controller answers and reports what happened while away.
        await self.get_errors()
        await super()._on_connected()
        for channel, units in self._accel.items():
            await self._write(set_acceleration(channel, units))

    async def _poll(self) -> None:
        await self.get_errors()

    async def get_errors(self) -> tuple[str, ...]:
        """Read (and so clear) the controller's error bits; returns their names."""
        reply = await self._request(get_errors(), 2)
        try:
            flags = decode_errors(reply)
        except ReplyError as exc:
            raise self._reply_error(exc) from None
        names = error_names(flags)
        if names:
            self.maestro_errors = names
            self.counters["device_errors"] += 1
            self._note_error("maestro errors: " + ", ".join(names))
            self._log.warning("maestro_errors", errors=names, bits=f"{int(flags):#06x}")
        return names

    async def set_acceleration(self, channel: int, deg_s2: float) -> None:
        """Limit the acceleration of `channel` (0 = unlimited); kept across reconnects."""
        cal = self.calibration(channel)
        if math.isnan(deg_s2) or deg_s2 < 0:
            raise ValueError(f"acceleration must be >= 0 deg/s^2, got {deg_s2!r}")
        units = accel_units(deg_s2 * cal.us_per_deg)
        self._accel[channel] = units
        await self._write(set_acceleration(channel, units))

    async def go_home(self) -> None:
        """Send every channel to its configured home (off, ignore or a position)."""
        await self._write(go_home())


__all__ = [
    "MaestroCommand",
    "MaestroError",
    "MaestroPanTilt",
    "PanTiltError",
    "decode_14bit",
    "decode_errors",
    "decode_moving_state",
    "decode_position_us",
    "encode_14bit",
    "error_names",
]
