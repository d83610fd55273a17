"""A loopback ARCOS bridge between one client (relayd's driver) and one MobileSim robot.

MobileSim serves one client per robot port, and the simulator needs more of the robot
than its client does: the robot's TRUE pose (for the radio model, the trace and the
clearance figures) and its stall flags (collisions). The bridge listens on a free
loopback port, and for each client that connects it opens the robot's port and passes
bytes both ways, packet by packet:

- client -> robot: unchanged; once the client's OPEN has gone through, the bridge adds
  `SIM_SET_POSE` (224; x, y mm, th deg as int4, the argument-type byte ignored) when a
  start pose is pending, and `SIM_STAT 2` (237: a SIMSTAT packet before each SIP);
- robot -> client: SIMSTAT packets (0x62) are read here and not passed on (a real
  robot sends none); SIPs are passed on after their stall bits are read.

The client sees exactly a P3-AT over TCP. Everything read is in `BridgeBody`.
"""

from __future__ import annotations

import asyncio
import contextlib
import struct
from dataclasses import dataclass, field

from drivers.arcos.codec import Decoder, PacketType, encode_command, encode_packet
from drivers.arcos.sip import decode_raw_sip
from relayd.sim.tasks import cancel_and_wait

SIM_SET_POSE = 224
SIM_STAT = 237
SIMSTAT_PACKET = 0x62
SYNC2 = 2
OPEN = 1
#: Standard SIP stall_bumpers bits: left wheel stalled (bit 0), right wheel (bit 8).
STALL_BITS = 0x0101


@dataclass(slots=True)
class BridgeBody:
    """What the bridge knows of its robot (the attributes the sim runner reads)."""

    name: str
    x_mm: float = 0.0
    y_mm: float = 0.0
    theta_deg: float = 0.0
    vel_mm_s: float = 0.0
    rvel_deg_s: float = 0.0
    stalled: bool = False
    stall_sips: int = 0
    simstats: int = 0
    sips: int = 0
    opened: asyncio.Event = field(default_factory=asyncio.Event)
    posed: asyncio.Event = field(default_factory=asyncio.Event)


def set_pose_packet(x_mm: float, y_mm: float, theta_deg: float) -> bytes:
    return encode_packet(
        SIM_SET_POSE, b"\x3b" + struct.pack("<iii", round(x_mm), round(y_mm), round(theta_deg))
    )


def decode_simstat(payload: bytes) -> tuple[int, int, int]:
    """True (x mm, y mm, theta deg) of a SIMSTAT payload (MobileSim's README layout)."""
    # 2 reserved bytes, flags u4, three u2 intervals, then true x, y, z, theta (int4).
    x, y, _z, th = struct.unpack_from("<iiii", payload, 2 + 4 + 6)
    return x, y, th


class ArcosBridge:
    """Serves `body` on a loopback port, forwarding to MobileSim's robot port."""

    def __init__(
        self, body: BridgeBody, robot_port: int, start: tuple[float, float, float]
    ) -> None:
        self.body = body
        self.robot_port = robot_port
        self.start_pose: tuple[float, float, float] | None = start
        self.port = 0
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()

    @property
    def url(self) -> str:
        return f"socket://127.0.0.1:{self.port}"

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._client, "127.0.0.1", 0)
        self.port = self._server.sockets[0].getsockname()[1]

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
        await cancel_and_wait(list(self._tasks))
        if self._server is not None:
            with contextlib.suppress(Exception):
                await self._server.wait_closed()

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        try:
            r_reader, r_writer = await asyncio.open_connection("127.0.0.1", self.robot_port)
        except OSError:
            writer.close()
            self._tasks.discard(task)
            return
        up = asyncio.create_task(self._up(reader, r_writer))
        down = asyncio.create_task(self._down(r_reader, writer))
        try:
            await asyncio.wait({up, down}, return_when=asyncio.FIRST_COMPLETED)
        except asyncio.CancelledError:
            pass  # the bridge is closing: the finally below closes both ends
        finally:
            for t in (up, down):
                t.cancel()
            for w in (writer, r_writer):
                w.close()
            self._tasks.discard(task)

    async def _up(self, reader: asyncio.StreamReader, robot: asyncio.StreamWriter) -> None:
        dec = Decoder()
        synced = False  # SYNC1 and OPEN are both command 1: OPEN is the one after SYNC2
        while data := await reader.read(4096):
            for pkt in dec.feed(data):
                robot.write(pkt.encode())
                if pkt.ptype == SYNC2:
                    synced = True
                elif pkt.ptype == OPEN and synced and not self.body.opened.is_set():
                    if self.start_pose is not None:
                        robot.write(set_pose_packet(*self.start_pose))
                        self.start_pose = None
                    robot.write(encode_command(SIM_STAT, 2))
                    self.body.opened.set()
            await robot.drain()

    async def _down(self, robot: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        dec = Decoder()
        body = self.body
        while data := await robot.read(4096):
            out = bytearray()
            for pkt in dec.feed(data):
                if pkt.ptype == SIMSTAT_PACKET:
                    x, y, th = decode_simstat(pkt.payload)
                    body.x_mm, body.y_mm, body.theta_deg = float(x), float(y), float(th)
                    body.simstats += 1
                    body.posed.set()
                    continue
                if pkt.ptype in (PacketType.SIP_STOPPED, PacketType.SIP_MOVING):
                    with contextlib.suppress(Exception):
                        raw = decode_raw_sip(pkt.ptype, pkt.payload)
                        body.stalled = bool(raw.stall_bumpers & STALL_BITS)
                        body.stall_sips += body.stalled
                        body.sips += 1
                        # Wheel speeds (mm/s on a P3-AT's units) for the trace's v and w.
                        body.vel_mm_s = (raw.left_raw + raw.right_raw) / 2.0
                        body.rvel_deg_s = float(raw.rotvel_x10 or 0) / 10.0
                out += pkt.encode()
            writer.write(bytes(out))
            await writer.drain()
