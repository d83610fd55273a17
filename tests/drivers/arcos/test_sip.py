"""SIP decoding, odometry wrap handling, conversion factors and the sonar ring (pure)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.arcos.codec import CodecError, Decoder, PacketType
from drivers.arcos.sip import (
    Odometry,
    RawSip,
    RobotIdentity,
    conv_factors,
    decode_config,
    decode_identity,
    decode_raw_sip,
    encode_config,
    encode_identity,
    sip_from_raw,
    vel_rvel_to_wheels,
    wheel_to_vel_rvel,
)
from drivers.arcos.sonar import SONAR_POSES, SonarRing, reading_point

DOC_SIP = bytes.fromhex(
    "FA FB 28 32 E8 03 F4 01 00 04 64 00 64 00 82 00 00 00 00 1F 00 00 02 00 DC 05 03 20 03"
    " 00 00 00 FF FF 82 00 00 00 00 00 00 82 8B"
)


def _raw(x: int = 0, y: int = 0, th: int = 0, **kw: object) -> RawSip:
    base: dict[str, object] = dict(
        moving=False,
        x_raw=x,
        y_raw=y,
        th_raw=th,
        left_raw=0,
        right_raw=0,
        battery_dv=130,
        stall_bumpers=0,
        control=0,
        flags=0,
        compass=0,
        sonar=(),
    )
    base.update(kw)
    return RawSip(**base)  # type: ignore[arg-type]


def test_doc_example_sip_fields() -> None:
    (pkt,) = Decoder().feed(DOC_SIP)
    raw = decode_raw_sip(pkt.ptype, pkt.payload)
    assert (raw.x_raw, raw.y_raw, raw.th_raw) == (1000, 500, 1024)
    assert (raw.left_raw, raw.right_raw, raw.battery_dv) == (100, 100, 130)
    assert raw.sonar == ((0, 1500), (3, 800))
    assert (raw.digin, raw.digout, raw.battery_x10, raw.rotvel_x10) == (0xFF, 0xFF, 130, 0)
    assert raw.encode() == (pkt.ptype, pkt.payload)
    odo = Odometry()
    odo.update(raw, conv_factors("p3at-sh"))
    sip = sip_from_raw(raw, odo, 1.0, conv_factors("p3at-sh"))
    assert sip.motors_enabled and sip.sonar_enabled and not sip.estop
    assert sip.battery_v == 13.0 and sip.left_mm_s == 100.0
    assert sip.sonar == ((0, 1500), (3, 800))


def test_short_or_inconsistent_sips_are_rejected() -> None:
    with pytest.raises(CodecError):
        decode_raw_sip(0x32, bytes(10))
    payload = bytearray(_raw().encode()[1])
    payload[18] = 5  # claims 5 sonar readings
    with pytest.raises(CodecError):
        decode_raw_sip(0x32, bytes(payload[:25]))
    with pytest.raises(CodecError):
        decode_raw_sip(0x20, bytes(payload))


def test_stall_bumper_and_flag_bits() -> None:
    raw = _raw(stall_bumpers=0x0101 | (0x05 << 9) | (0x03 << 1), flags=0x0021, moving=True)
    ptype, payload = raw.encode()
    assert ptype == PacketType.SIP_MOVING
    sip = sip_from_raw(decode_raw_sip(ptype, payload), Odometry(), 0.0, conv_factors("p3at"))
    assert sip.stall_left and sip.stall_right and sip.estop and sip.motors_enabled
    assert (sip.bumpers_front, sip.bumpers_rear) == (5, 3)
    assert sip.moving


def test_subclass_factors() -> None:
    assert conv_factors("p3at").dist_mm_per_unit == 0.465
    assert conv_factors("P3AT-SH").dist_mm_per_unit == 1.0
    assert conv_factors("p3atiw-sh").dist_mm_per_unit == 1.0


@given(
    st.lists(st.integers(-3000, 3000), min_size=1, max_size=60),
    st.sampled_from(["p3at", "p3at-sh"]),
    st.integers(0, 0x7FFF),
)
def test_odometry_accumulates_across_15_bit_wraps(steps: list[int], sub: str, start: int) -> None:
    f = conv_factors(sub)
    odo = Odometry()
    raw = start
    odo.update(_raw(x=raw), f)
    total = 0
    for d in steps:
        raw = (raw + d) & 0x7FFF
        total += d
        # the robot may send bit 15 set (MobileSim int16 accumulators); it is ignored
        odo.update(_raw(x=raw | 0x8000), f)
    assert odo.x_mm == pytest.approx(total * f.dist_mm_per_unit, abs=1e-6)


def test_heading_wraps_and_reconnect_keeps_pose() -> None:
    f = conv_factors("p3at-sh")
    odo = Odometry()
    odo.update(_raw(th=2000), f)
    assert odo.theta_deg == 0.0  # the first SIP is only the reference
    odo.update(_raw(th=-2000), f)  # +96 units across the +-180 seam
    assert math.isclose(odo.theta_deg, 96 * 360 / 4096, abs_tol=1e-9)
    # drive 100 mm along the robot's x while heading +90 deg in our frame
    odo = Odometry(theta_deg=90.0)
    odo.new_session()
    odo.update(_raw(x=0), f)
    odo.update(_raw(x=100), f)
    assert odo.x_mm == pytest.approx(0.0, abs=1e-9) and odo.y_mm == pytest.approx(100.0)


def test_identity_and_config_round_trip() -> None:
    ident = RobotIdentity("relay1", "Pioneer", "p3at-sh")
    assert decode_identity(encode_identity(ident)) == ident
    with pytest.raises(CodecError):
        decode_identity(b"name\x00class")
    cfg = decode_config(encode_config(ident, watchdog_ms=2000))
    assert (cfg.robot_class, cfg.subclass, cfg.name) == ("Pioneer", "p3at-sh", "relay1")
    assert (cfg.watchdog_ms, cfg.sip_cycle_ms, cfg.host_baud_index) == (2000, 100, 0)
    short = decode_config(encode_config(ident)[:45])
    assert short.name == "relay1"
    with pytest.raises(CodecError):
        decode_config(b"a\x00b\x00c\x00")


@given(st.floats(-600, 600), st.floats(-600, 600))
def test_wheels_to_vel_rvel_and_back(left: float, right: float) -> None:
    vel, rvel = wheel_to_vel_rvel(left, right)
    back_l, back_r = vel_rvel_to_wheels(vel, rvel)
    # 1 deg/s of RVEL is ~10 mm/s of wheel difference: that is the resolution
    assert abs(back_l - left) < 7 and abs(back_r - right) < 7


def test_wheel_conversion_uses_diff_conv_factor() -> None:
    assert wheel_to_vel_rvel(100, 200) == (150, round(math.degrees(50 * 0.0034)))
    assert wheel_to_vel_rvel(5000, 5000) == (1200, 0)


def test_sonar_ring_front_min_points_and_no_echo() -> None:
    ring = SonarRing()
    assert ring.front_min_mm() is None
    ring.update([(3, 800), (4, 5000), (9, 1200), (40, 10)], t=1.0)
    assert ring.ranges_mm[3] == 800 and ring.updated_t[3] == 1.0 and ring.ignored == 1
    assert ring.front_min_mm() == 800
    assert ring.front_min_mm(max_age_s=0.5, now=2.0) is None
    assert not ring.has_echo(4) and ring.has_echo(9)
    pts = ring.points()
    assert [p.index for p in pts] == [3, 9]
    p3 = pts[0]
    assert p3.x_mm == pytest.approx(245 + 800 * math.cos(math.radians(10)))
    assert p3.angle_deg == pytest.approx(math.degrees(math.atan2(p3.y_mm, p3.x_mm)))
    ring.update([(4, 7000)], t=3.0)
    assert ring.ranges_mm[4] == 5000


def test_sonar_poses_are_the_p3at_table() -> None:
    assert len(SONAR_POSES) == 16
    assert (SONAR_POSES[0].x_mm, SONAR_POSES[0].y_mm) == (147, 136)
    assert (SONAR_POSES[8].x_mm, SONAR_POSES[8].y_mm) == (-144, -136)
    assert [p.heading_deg for p in SONAR_POSES[:8]] == [90, 50, 30, 10, -10, -30, -50, -90]
    assert SONAR_POSES[12].heading_deg == 170
    # sonar 3 looks 10 deg left from 27 mm left of the axis: the point is seen at 5..10 deg
    assert 5 < reading_point(3, 1000).angle_deg < 10
