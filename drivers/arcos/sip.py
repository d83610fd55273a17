"""Typed robot -> client packets: SYNC2 identity, the standard SIP, CONFIGpac, odometry.

Pure decoding and encoding (the fake robot uses the `encode_*` side), plus the
`Odometry` integrator that turns 15-bit wrapped robot units into an accumulated pose
in mm/deg the way ARIA does (deltas from the first SIP; never SETO). No asyncio.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

from drivers.arcos.codec import CodecError, PacketType

#: 2*pi/4096 exactly (the .p files print a rounded 0.00153; docs/PROTOCOLS.md 1.10).
ANGLE_CONV_RAD = 2.0 * math.pi / 4096.0
DIFF_CONV_FACTOR = 0.0034  # rad/s per mm/s of half the wheel-speed difference (skid steer)
VEL2_DIVISOR_MM_S = 20
MAX_VEL_MM_S = 1200  # P3-AT MaxVelocity
MAX_RVEL_DEG_S = 300  # P3-AT MaxRVelocity
NO_ECHO_MM = 5000  # ARIA ArSonarDevice max range; ranges at/over it mean "nothing seen"

FLAG_MOTORS = 0x0001
FLAG_SONARS = 0x001E  # bits 1-4: sonar arrays 1-4
FLAG_ESTOP = 0x0020
FLAG_ESTALL = 0x0040
STALL_LEFT = 0x0001
STALL_RIGHT = 0x0100


@dataclass(frozen=True, slots=True)
class RobotIdentity:
    """What the SYNC2 reply says the robot is."""

    name: str
    robot_class: str
    subclass: str


@dataclass(frozen=True, slots=True)
class ConvFactors:
    """Per-subclass conversion factors (ARIA params/<subclass>.p)."""

    dist_mm_per_unit: float
    angle_rad_per_unit: float = ANGLE_CONV_RAD
    vel_mm_s_per_unit: float = 1.0
    range_mm_per_unit: float = 1.0
    diff_conv: float = DIFF_CONV_FACTOR


#: DistConvFactor is the one that differs: 0.465 (H8/AROS "p3at") vs 1.0 (ARCOS "p3at-sh").
CONV_FACTORS: dict[str, ConvFactors] = {
    "p3at": ConvFactors(0.465),
    "p3at-sh": ConvFactors(1.0),
    "p3atiw": ConvFactors(0.465),
    "p3atiw-sh": ConvFactors(1.0),
    "p3at-nolaser": ConvFactors(0.465),
    "p3at-sh-nolaser": ConvFactors(1.0),
}


def conv_factors(subclass: str) -> ConvFactors:
    """Factors for a subclass string (case-insensitive, as ARIA lower-cases it).

    Unknown subclasses fall back by the "-sh" suffix, which marks the ARCOS SH
    controller whose odometry unit is 1 mm.
    """
    key = subclass.strip().lower()
    if key in CONV_FACTORS:
        return CONV_FACTORS[key]
    return ConvFactors(1.0 if "-sh" in key else 0.465)


def _cstrings(payload: bytes, count: int) -> tuple[list[str], int]:
    out: list[str] = []
    pos = 0
    for _ in range(count):
        end = payload.find(b"\x00", pos)
        if end < 0:
            raise CodecError(f"expected {count} NUL-terminated strings, got {len(out)}")
        out.append(payload[pos:end].decode("latin-1"))
        pos = end + 1
    return out, pos


def decode_identity(payload: bytes) -> RobotIdentity:
    """SYNC2 reply: name, class, subclass (the subclass lower-cased, as ARIA does)."""
    (name, cls, sub), _ = _cstrings(payload, 3)
    return RobotIdentity(name, cls, sub.lower())


def encode_identity(identity: RobotIdentity) -> bytes:
    return b"".join(
        s.encode("latin-1") + b"\x00"
        for s in (identity.name, identity.robot_class, identity.subclass)
    )


@dataclass(frozen=True, slots=True)
class RawSip:
    """A standard SIP exactly as on the wire (robot units), fields 1-12 plus the ARCOS tail."""

    moving: bool
    x_raw: int  # uint16, low 15 bits meaningful
    y_raw: int
    th_raw: int  # int16, 4096 units per turn
    left_raw: int
    right_raw: int
    battery_dv: int  # decivolts, uint8
    stall_bumpers: int
    control: int
    flags: int
    compass: int
    sonar: tuple[tuple[int, int], ...]  # (index, range units)
    grip_state: int = 0
    anport: int = 0
    analog: int = 0
    digin: int = 0xFF
    digout: int = 0xFF
    battery_x10: int | None = None
    charge_state: int | None = None
    rotvel_x10: int | None = None
    fault_flags: int | None = None

    def encode(self) -> tuple[int, bytes]:
        """(packet type, payload) for the fake robot."""
        if len(self.sonar) > 255:
            raise CodecError("too many sonar readings for one SIP")
        out = bytearray(
            struct.pack(
                "<HHhhhBHhHBB",
                self.x_raw & 0xFFFF,
                self.y_raw & 0xFFFF,
                self.th_raw,
                self.left_raw,
                self.right_raw,
                self.battery_dv & 0xFF,
                self.stall_bumpers & 0xFFFF,
                self.control,
                self.flags & 0xFFFF,
                self.compass & 0xFF,
                len(self.sonar),
            )
        )
        for idx, rng in self.sonar:
            out += struct.pack("<BH", idx, max(0, min(0xFFFF, rng)))
        out += bytes((self.grip_state, self.anport, self.analog, self.digin, self.digout))
        if self.battery_x10 is not None:
            out += struct.pack("<H", self.battery_x10)
            out += struct.pack("<b", -1 if self.charge_state is None else self.charge_state)
            out += struct.pack("<h", self.rotvel_x10 or 0)
            out += struct.pack("<H", self.fault_flags or 0)
        ptype = PacketType.SIP_MOVING if self.moving else PacketType.SIP_STOPPED
        return int(ptype), bytes(out)


_HEAD = struct.Struct("<HHhhhBHhHBB")


def decode_raw_sip(ptype: int, payload: bytes) -> RawSip:
    """Decode a standard SIP payload; optional trailing fields are read only if present."""
    if ptype not in (PacketType.SIP_STOPPED, PacketType.SIP_MOVING):
        raise CodecError(f"not a standard SIP: type 0x{ptype:02X}")
    if len(payload) < _HEAD.size:
        raise CodecError(f"SIP too short: {len(payload)} bytes")
    x, y, th, lv, rv, batt, stall, control, flags, compass, n = _HEAD.unpack_from(payload)
    pos = _HEAD.size
    if len(payload) < pos + 3 * n:
        raise CodecError(f"SIP announces {n} sonar readings but holds {(len(payload) - pos) // 3}")
    sonar = tuple(struct.unpack_from("<BH", payload, pos + 3 * i) for i in range(n))
    pos += 3 * n
    tail = payload[pos:]

    def byte(i: int, default: int) -> int:
        return tail[i] if len(tail) > i else default

    extra: dict[str, int | None] = {}
    if len(tail) >= 7:
        extra["battery_x10"] = struct.unpack_from("<H", tail, 5)[0]
    if len(tail) >= 8:
        extra["charge_state"] = struct.unpack_from("<b", tail, 7)[0]
    if len(tail) >= 10:
        extra["rotvel_x10"] = struct.unpack_from("<h", tail, 8)[0]
    if len(tail) >= 12:
        extra["fault_flags"] = struct.unpack_from("<H", tail, 10)[0]
    return RawSip(
        moving=ptype == PacketType.SIP_MOVING,
        x_raw=x,
        y_raw=y,
        th_raw=th,
        left_raw=lv,
        right_raw=rv,
        battery_dv=batt,
        stall_bumpers=stall,
        control=control,
        flags=flags,
        compass=compass,
        sonar=tuple((int(i), int(r)) for i, r in sonar),
        grip_state=byte(0, 0),
        anport=byte(1, 0),
        analog=byte(2, 0),
        digin=byte(3, 0xFF),
        digout=byte(4, 0xFF),
        **extra,
    )


@dataclass(frozen=True, slots=True)
class Sip:
    """One decoded SIP in driver units: pose accumulated by the driver since it first connected."""

    t: float
    x_mm: float
    y_mm: float
    theta_deg: float
    left_mm_s: float
    right_mm_s: float
    battery_v: float
    motors_enabled: bool
    estop: bool
    stall_left: bool
    stall_right: bool
    moving: bool
    sonar: tuple[tuple[int, int], ...]  # (index, range_mm) updated in this SIP
    bumpers_front: int = 0  # 7 switch bits
    bumpers_rear: int = 0
    sonar_enabled: bool = False
    rotvel_deg_s: float = 0.0
    flags: int = 0


def wrap_deg(angle_deg: float) -> float:
    """An angle in degrees wrapped to (-180, 180], the one convention of the whole system
    (relayd.core.geometry re-exports it); an angle already in range comes back bit for bit."""
    a = math.fmod(angle_deg, 360.0)
    if a <= -180.0:
        a += 360.0
    elif a > 180.0:
        a -= 360.0
    return a


@dataclass(slots=True)
class Odometry:
    """Accumulates SIP odometry across 15-bit wraps, sessions and robot-side resets.

    The first SIP of a session is only a reference. Deltas are taken in the robot's
    raw frame and rotated into ours by the heading offset fixed at that reference, so
    a reconnect (which restarts the robot's odometry at 0,0,0) continues the pose.
    """

    x_mm: float = 0.0
    y_mm: float = 0.0
    theta_deg: float = 0.0
    _last: tuple[int, int, int] | None = field(default=None, repr=False)
    _rot_rad: float = field(default=0.0, repr=False)

    def new_session(self) -> None:
        self._last = None

    def update(self, sip: RawSip, factors: ConvFactors) -> None:
        x, y, th = sip.x_raw & 0x7FFF, sip.y_raw & 0x7FFF, sip.th_raw
        if self._last is None:
            self._last = (x, y, th)
            raw_heading_deg = math.degrees(th * factors.angle_rad_per_unit)
            self._rot_rad = math.radians(self.theta_deg - raw_heading_deg)
            return
        lx, ly, lth = self._last
        self._last = (x, y, th)
        # modulo 2**15 into [-2**14, 2**14): a wrap is the short way round
        dx = ((x - lx + 0x4000) & 0x7FFF) - 0x4000
        dy = ((y - ly + 0x4000) & 0x7FFF) - 0x4000
        dth = ((th - lth + 2048) & 0xFFF) - 2048
        dx_mm, dy_mm = dx * factors.dist_mm_per_unit, dy * factors.dist_mm_per_unit
        c, s = math.cos(self._rot_rad), math.sin(self._rot_rad)
        self.x_mm += c * dx_mm - s * dy_mm
        self.y_mm += s * dx_mm + c * dy_mm
        self.theta_deg = wrap_deg(self.theta_deg + math.degrees(dth * factors.angle_rad_per_unit))


def wheel_to_vel_rvel(left_mm_s: float, right_mm_s: float) -> tuple[int, int]:
    """(VEL mm/s, RVEL deg/s) for wheel speeds, clamped to the P3-AT limits (docs/PROTOCOLS.md 1.7)."""
    vel = round((left_mm_s + right_mm_s) / 2.0)
    rvel = round(math.degrees((right_mm_s - left_mm_s) / 2.0 * DIFF_CONV_FACTOR))
    return (
        max(-MAX_VEL_MM_S, min(MAX_VEL_MM_S, vel)),
        max(-MAX_RVEL_DEG_S, min(MAX_RVEL_DEG_S, rvel)),
    )


def vel_rvel_to_wheels(vel_mm_s: float, rvel_deg_s: float) -> tuple[float, float]:
    """(left, right) mm/s for a translation + rotation, as MobileSim fabricates them."""
    d = math.radians(rvel_deg_s) / DIFF_CONV_FACTOR
    return vel_mm_s - d, vel_mm_s + d


def sip_from_raw(raw: RawSip, odo: Odometry, t: float, factors: ConvFactors) -> Sip:
    """Typed SIP after `odo.update(raw, ...)` has run."""
    left = raw.left_raw * factors.vel_mm_s_per_unit
    right = raw.right_raw * factors.vel_mm_s_per_unit
    if raw.rotvel_x10 is not None:
        rotvel = raw.rotvel_x10 / 10.0
    else:
        rotvel = math.degrees((right - left) / 2.0 * factors.diff_conv)
    battery_dv = raw.battery_x10 if raw.battery_x10 else raw.battery_dv
    return Sip(
        t=t,
        x_mm=odo.x_mm,
        y_mm=odo.y_mm,
        theta_deg=odo.theta_deg,
        left_mm_s=left,
        right_mm_s=right,
        battery_v=battery_dv / 10.0,
        motors_enabled=bool(raw.flags & FLAG_MOTORS),
        estop=bool(raw.flags & FLAG_ESTOP),
        stall_left=bool(raw.stall_bumpers & STALL_LEFT),
        stall_right=bool(raw.stall_bumpers & STALL_RIGHT),
        moving=raw.moving,
        sonar=tuple((i, round(r * factors.range_mm_per_unit)) for i, r in raw.sonar),
        bumpers_front=(raw.stall_bumpers >> 9) & 0x7F,
        bumpers_rear=(raw.stall_bumpers >> 1) & 0x7F,
        sonar_enabled=bool(raw.flags & FLAG_SONARS),
        rotvel_deg_s=rotvel,
        flags=raw.flags,
    )


@dataclass(frozen=True, slots=True)
class RobotConfig:
    """The CONFIGpac fields the driver uses (docs/PROTOCOLS.md 1.9)."""

    robot_class: str
    subclass: str
    serial: str
    name: str
    rot_vel_top_deg_s: int
    trans_vel_top_mm_s: int
    rot_accel_top: int
    trans_accel_top: int
    pwm_max: int
    sip_cycle_ms: int
    host_baud_index: int
    front_sonar: int | None = None
    rear_sonar: int | None = None
    low_battery_dv: int | None = None
    watchdog_ms: int | None = None


def decode_config(payload: bytes) -> RobotConfig:
    """CONFIGpac: defensive, later fields are optional (older firmware ends earlier)."""
    (cls, sub, serial), pos = _cstrings(payload, 3)
    if len(payload) < pos + 11:
        raise CodecError("CONFIGpac too short")
    pos += 1  # 4MOTS
    rvt, tvt, rat, tat, pwm = struct.unpack_from("<5H", payload, pos)
    pos += 10
    end = payload.find(b"\x00", pos)
    if end < 0:
        raise CodecError("CONFIGpac: name not terminated")
    name = payload[pos:end].decode("latin-1")
    pos = end + 1
    if len(payload) < pos + 2:
        raise CodecError("CONFIGpac too short after name")
    sip_cycle, host_baud = payload[pos], payload[pos + 1]
    pos += 3  # SipCycle, HostBaud, Aux1Baud
    opt: list[int | None] = []
    # HasGripper u16, FrontSonar u16, RearSonar u8, LowBattery u16, RevCount u16, Watchdog u16
    for fmt in ("<H", "<H", "<B", "<H", "<H", "<H"):
        size = struct.calcsize(fmt)
        if len(payload) >= pos + size:
            opt.append(struct.unpack_from(fmt, payload, pos)[0])
            pos += size
        else:
            opt.append(None)
    return RobotConfig(
        cls,
        sub.lower(),
        serial,
        name,
        rvt,
        tvt,
        rat,
        tat,
        pwm,
        sip_cycle,
        host_baud,
        front_sonar=opt[1],
        rear_sonar=opt[2],
        low_battery_dv=opt[3],
        watchdog_ms=opt[5],
    )


def encode_config(
    identity: RobotIdentity,
    *,
    watchdog_ms: int = 2000,
    sip_cycle_ms: int = 100,
    trans_accel: int = 300,
    rot_accel: int = 100,
) -> bytes:
    """A CONFIGpac payload through ShutdownVoltage plus a firmware string (fake robot)."""
    out = bytearray()
    for s in (identity.robot_class, identity.subclass, "FAKE"):
        out += s.encode("latin-1") + b"\x00"
    out += bytes((0,))
    out += struct.pack("<5H", MAX_RVEL_DEG_S, MAX_VEL_MM_S, 300, 2000, 500)
    out += identity.name.encode("latin-1") + b"\x00"
    out += bytes((sip_cycle_ms, 0, 0))
    out += struct.pack("<HHBHHHBHHHH", 0, 1, 1, 110, 16570, watchdog_ms, 0, 0, 0, 0, 0)
    out += struct.pack("<HHHH", 150, 1200, rot_accel, rot_accel)
    out += struct.pack("<6H", 0, 0, 0, trans_accel, trans_accel, 0)
    out += struct.pack("<HH", 0, 0)
    out += bytes((0, 0, 0, 40, 2, 0))
    out += struct.pack("<h", 0)
    out += bytes((0, 0))
    out += struct.pack("<HH", 0, 110)
    out += b"FAKE-1.0\x00"
    return bytes(out)
