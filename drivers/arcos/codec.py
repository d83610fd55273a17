"""Pure ARCOS packet codec: framing, checksum, argument encoding and an incremental decoder.

No asyncio and no I/O here: the driver (`drivers.arcos.driver`) and the fake robot
(`drivers.arcos.fake`) both feed raw bytes in and write `encode_*` bytes out, so they
cannot disagree about the wire format. Layout (docs/PROTOCOLS.md 1.1):

    FA FB N TYPE PAYLOAD... CK_HI CK_LO      N = len(TYPE + PAYLOAD) + 2, unsigned
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from enum import IntEnum

SYNC = b"\xfa\xfb"
#: N counts type + payload + 2 checksum bytes; it is one unsigned byte.
MIN_COUNT = 3
MAX_COUNT = 255
#: Conventional ceiling for what a client sends (ARIA, p2os, MobileSim refuse more).
MAX_SEND_PAYLOAD = 200


class Command(IntEnum):
    """Client -> robot command numbers (ARIA ArCommands.h; docs/PROTOCOLS.md 1.6)."""

    SYNC0 = 0
    SYNC1 = 1
    SYNC2 = 2
    POLLING = 3
    ENABLE = 4
    SETA = 5
    SETV = 6
    SETO = 7
    MOVE = 8
    ROTATE = 9
    SETRV = 10
    VEL = 11
    HEAD = 12
    DHEAD = 13
    SAY = 15
    JOYINFO = 17
    CONFIG = 18
    ENCODER = 19
    RVEL = 21
    DCHEAD = 22
    SETRA = 23
    SONAR = 28
    STOP = 29
    DIGOUT = 30
    VEL2 = 32
    BUMPSTALL = 44
    HOSTBAUD = 50
    E_STOP = 55
    SONARCYCLE = 48


# The handshake numbers double as session commands once the SYNC2 reply is in.
PULSE = Command.SYNC0
OPEN = Command.SYNC1
CLOSE = Command.SYNC2


class PacketType(IntEnum):
    """Robot -> client packet types (docs/PROTOCOLS.md 1.8, 1.9)."""

    SYNC0 = 0x00
    SYNC1 = 0x01
    SYNC2 = 0x02
    CONFIG = 0x20
    SIP_STOPPED = 0x32
    SIP_MOVING = 0x33
    ENCODER = 0x90
    RESET_DATA = 0xFE
    RESET = 0xFF


SIP_TYPES = frozenset({PacketType.SIP_STOPPED, PacketType.SIP_MOVING})
RESET_TYPES = frozenset({PacketType.RESET_DATA, PacketType.RESET})


class ArgType(IntEnum):
    """Argument type byte that follows the command byte."""

    INT = 0x3B  # non-negative magnitude follows, LE
    NINT = 0x1B  # magnitude follows; the value is its negative
    STR = 0x2B  # length byte, then the bytes


class CodecError(ValueError):
    """Bytes that cannot be a valid packet or argument."""


def checksum(body: bytes | bytearray | memoryview) -> int:
    """ARCOS checksum over type + payload: big-endian 16-bit pair sum, odd byte XORed low."""
    c = 0
    n = len(body)
    for i in range(0, n - 1, 2):
        c = (c + ((body[i] << 8) | body[i + 1])) & 0xFFFF
    if n & 1:
        c ^= body[n - 1]
    return c


def encode_packet(ptype: int, payload: bytes = b"") -> bytes:
    """Frame one packet (either direction)."""
    if not 0 <= ptype <= 0xFF:
        raise CodecError(f"packet type out of range: {ptype}")
    count = 1 + len(payload) + 2
    if count > MAX_COUNT:
        raise CodecError(f"payload of {len(payload)} bytes does not fit one packet")
    body = bytes((ptype,)) + payload
    c = checksum(body)
    return SYNC + bytes((count,)) + body + bytes((c >> 8, c & 0xFF))


def encode_int_arg(value: int) -> bytes:
    """ARGINT for v >= 0, ARGNINT with the magnitude for v < 0 (ARIA comInt)."""
    mag = abs(int(value))
    if mag > 0xFFFF:
        raise CodecError(f"integer argument out of range: {value}")
    kind = ArgType.INT if value >= 0 else ArgType.NINT
    return bytes((kind, mag & 0xFF, mag >> 8))


def encode_str_arg(value: bytes | str) -> bytes:
    """ARGSTR: type byte, length byte, the bytes (no NUL, as ARIA comStrN)."""
    raw = value.encode("latin-1") if isinstance(value, str) else bytes(value)
    if len(raw) > MAX_SEND_PAYLOAD - 3:
        raise CodecError(f"string argument of {len(raw)} bytes is too long")
    return bytes((ArgType.STR, len(raw))) + raw


def encode_command(cmd: int, arg: int | str | bytes | None = None) -> bytes:
    """One client command packet: bare, with an int argument, or with a string argument."""
    if arg is None:
        payload = b""
    elif isinstance(arg, int):
        payload = encode_int_arg(arg)
    else:
        payload = encode_str_arg(arg)
    if len(payload) > MAX_SEND_PAYLOAD:
        raise CodecError("command payload too long")
    return encode_packet(int(cmd), payload)


def vel2_arg(left_counts: int, right_counts: int) -> int:
    """VEL2 argument: high byte left, low byte right, signed 8-bit counts clamped to -128..127."""
    left = max(-128, min(127, int(left_counts))) & 0xFF
    right = max(-128, min(127, int(right_counts))) & 0xFF
    v = (left << 8) | right
    return v - 0x10000 if v & 0x8000 else v


def split_vel2(value: int) -> tuple[int, int]:
    """Inverse of `vel2_arg`: (left_counts, right_counts)."""
    v = value & 0xFFFF
    left, right = v >> 8, v & 0xFF
    return (left - 256 if left > 127 else left, right - 256 if right > 127 else right)


@dataclass(frozen=True, slots=True)
class Packet:
    """One framed packet: its type/command byte and payload (checksum already verified)."""

    ptype: int
    payload: bytes = b""

    def encode(self) -> bytes:
        return encode_packet(self.ptype, self.payload)


Arg = int | bytes | None


def decode_command(packet: Packet) -> tuple[int, Arg]:
    """Split a client command into (command number, argument). Raises CodecError."""
    p = packet.payload
    if not p:
        return packet.ptype, None
    kind = p[0]
    if kind in (ArgType.INT, ArgType.NINT):
        if len(p) < 3:
            raise CodecError(f"command {packet.ptype}: truncated integer argument")
        mag = p[1] | (p[2] << 8)
        return packet.ptype, -mag if kind == ArgType.NINT else mag
    if kind == ArgType.STR:
        if len(p) < 2 or len(p) < 2 + p[1]:
            raise CodecError(f"command {packet.ptype}: truncated string argument")
        return packet.ptype, bytes(p[2 : 2 + p[1]])
    raise CodecError(f"command {packet.ptype}: unknown argument type 0x{kind:02X}")


class Decoder:
    """Incremental frame extractor: feed any chunks, get every valid packet in order.

    Resync rule (docs/PROTOCOLS.md 1.4): on a bad checksum or impossible count only the
    leading FA is discarded and the search restarts, so a real frame hidden inside a
    corrupted one is still found. The buffer never holds more than one maximal frame
    plus the newest chunk.
    """

    __slots__ = (
        "_buf",
        "bytes_rx",
        "checksum_errors",
        "garbage_bytes",
        "length_errors",
        "packets",
        "resyncs",
    )

    def __init__(self) -> None:
        self._buf = bytearray()
        self.bytes_rx = 0
        self.packets = 0
        self.checksum_errors = 0
        self.length_errors = 0
        self.resyncs = 0
        self.garbage_bytes = 0

    @property
    def pending(self) -> int:
        """Bytes held while waiting for the rest of a frame."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget a partial frame (new session, or a partial frame that went silent)."""
        self._buf.clear()

    def counters(self) -> dict[str, int]:
        return {
            "bytes_rx": self.bytes_rx,
            "packets": self.packets,
            "checksum_errors": self.checksum_errors,
            "length_errors": self.length_errors,
            "resyncs": self.resyncs,
            "garbage_bytes": self.garbage_bytes,
        }

    def _skip(self, n: int) -> None:
        del self._buf[:n]
        self.garbage_bytes += n
        self.resyncs += 1

    def feed(self, data: bytes | bytearray | memoryview) -> list[Packet]:
        self.bytes_rx += len(data)
        self._buf += data
        return list(self._extract())

    def _extract(self) -> Iterator[Packet]:
        buf = self._buf
        while buf:
            start = buf.find(SYNC)
            if start < 0:
                # Keep a trailing FA: it may be the first half of the next sync pair.
                keep = 1 if buf[-1] == 0xFA else 0
                if len(buf) > keep:
                    self._skip(len(buf) - keep)
                return
            if start:
                self._skip(start)
            if len(buf) < 3:
                return
            count = buf[2]  # bytes are unsigned in Python: N >= 128 is fine (pitfall 1)
            if count < MIN_COUNT:
                self.length_errors += 1
                self._skip(1)
                continue
            total = count + 3
            if len(buf) < total:
                return
            body = bytes(buf[3 : total - 2])
            if checksum(body) != (buf[total - 2] << 8 | buf[total - 1]):
                self.checksum_errors += 1
                self._skip(1)
                continue
            del buf[:total]
            self.packets += 1
            yield Packet(body[0], body[1:])
