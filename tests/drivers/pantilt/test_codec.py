"""Pure pan-tilt codecs and calibration: byte vectors from the protocol notes, round trips, fuzz."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.pantilt import ServoCalibration
from drivers.pantilt import maestro as mc
from drivers.pantilt import ssc32 as sc
from drivers.pantilt.base import check_speed
from drivers.pantilt.session import ReplyError

# ---- Maestro compact protocol: vectors from the Maestro guide (docs/PROTOCOLS.md 2.2) ----------


def test_set_target_1500us_on_channel_2() -> None:
    assert mc.set_target(2, mc.us_to_quarter(1500)) == bytes.fromhex("84 02 70 2E")


def test_set_speed_140_units() -> None:
    # 140 = 0b1_0001100 -> low 7 bits 0x0C, high 0x01
    assert mc.set_speed(0, 140) == bytes.fromhex("87 00 0C 01")


def test_other_compact_frames() -> None:
    assert mc.set_acceleration(5, 1) == bytes.fromhex("89 05 01 00")
    assert mc.get_position(3) == bytes.fromhex("90 03")
    assert mc.get_moving_state() == b"\x93"
    assert mc.get_errors() == b"\xa1"
    assert mc.go_home() == b"\xa2"


def test_pololu_protocol_frame() -> None:
    # set target = AA 0C 04 ch lo hi
    assert mc.pololu_frame(mc.set_target(2, 6000)) == bytes.fromhex("AA 0C 04 02 70 2E")


def test_replies() -> None:
    assert mc.decode_position_us(bytes.fromhex("70 17")) == 1500.0  # 6000 = 0x1770, low byte first
    assert mc.decode_moving_state(b"\x00") is False
    assert mc.decode_moving_state(b"\x01") is True
    flags = mc.decode_errors(bytes.fromhex("10 01"))
    assert mc.error_names(flags) == ("serial_protocol", "script_program_counter")
    assert mc.error_names(mc.decode_errors(b"\x00\x80")) == ("bit15",)
    with pytest.raises(ReplyError):
        mc.decode_moving_state(b"\x02")
    with pytest.raises(ReplyError):
        mc.decode_position_us(b"\x70")
    with pytest.raises(ReplyError):
        mc.decode_position_us(b"\xff\xff")  # beyond any 14-bit target


def test_unit_conversions() -> None:
    assert mc.speed_units(0) == 0
    assert mc.speed_units(math.inf) == 0
    assert mc.speed_units(3500) == 140  # 3.5 us/ms
    assert mc.speed_units(1) == 1  # a slow limit never becomes "unlimited"
    assert mc.speed_units(1e9) == mc.MAX_14BIT
    assert mc.accel_units(312.5) == 1


def test_bad_arguments_raise() -> None:
    with pytest.raises(ValueError):
        mc.encode_14bit(0x4000)
    with pytest.raises(ValueError):
        mc.encode_14bit(-1)
    with pytest.raises(ValueError):
        mc.set_target(24, 6000)
    with pytest.raises(ValueError):
        mc.decode_14bit(0x80, 0)


@given(st.integers(0, mc.MAX_14BIT))
def test_14bit_round_trip(value: int) -> None:
    lo, hi = mc.encode_14bit(value)
    assert lo < 0x80 and hi < 0x80  # data bytes never look like command bytes
    assert mc.decode_14bit(lo, hi) == value


# ---- SSC-32 ASCII protocol: docs/PROTOCOLS.md 2.3 -------------------------------------------------------


def test_ssc32_move_frames() -> None:
    assert sc.encode_move(0, 1500) == b"#0P1500\r"
    assert sc.encode_move(5, 1500, 100) == b"#5P1500S100\r"
    assert sc.encode_move(5, 1500, 0) == b"#5P1500\r"
    assert sc.encode_move(31, 2500, 750, time_ms=1000) == b"#31P2500S750T1000\r"
    moves = [sc.Ssc32Move(0, 1000, 500), sc.Ssc32Move(1, 2000)]
    assert sc.encode_group_move(moves, 2000) == b"#0P1000S500#1P2000T2000\r"
    assert sc.QUERY_MOVEMENT == b"Q\r"
    assert sc.encode_query_pulse(3) == b"QP3\r"
    with pytest.raises(ValueError):
        sc.encode_move(32, 1500)
    with pytest.raises(ValueError):
        sc.encode_move(0, 2501)


def test_ssc32_replies() -> None:
    assert sc.decode_movement(b".") is False
    assert sc.decode_movement(b"+") is True
    assert sc.decode_pulse_us(bytes([150])) == 1500  # 1500 us -> 150
    with pytest.raises(ReplyError):
        sc.decode_movement(b"x")
    with pytest.raises(ReplyError):
        sc.decode_pulse_us(b"")


def test_ssc32_parse_is_lenient_like_the_firmware() -> None:
    assert sc.parse_command(b"q") == sc.Ssc32QueryMovement()
    assert sc.parse_command(b" # 5 p 1500 s 100\n") == sc.Ssc32GroupMove(
        (sc.Ssc32Move(5, 1500, 100),)
    )
    assert sc.parse_command(b"QP0QP1") == sc.Ssc32QueryPulse((0, 1))
    assert sc.parse_command(b"#0P1000#1P2000S20T500") == sc.Ssc32GroupMove(
        (sc.Ssc32Move(0, 1000), sc.Ssc32Move(1, 2000, 20)), 500
    )
    for bad in (b"", b"#0", b"#0P", b"#40P1500", b"#0P3000", b"hello", b"QP", b"T100", b"#0P1500T"):
        with pytest.raises(sc.Ssc32SyntaxError):
            sc.parse_command(bad)


@given(
    st.lists(
        st.tuples(
            st.integers(0, 31), st.integers(500, 2500), st.one_of(st.none(), st.integers(1, 65535))
        ),
        min_size=1,
        max_size=4,
    ),
    st.one_of(st.none(), st.integers(0, 65535)),
)
def test_ssc32_encode_parse_round_trip(
    moves: list[tuple[int, int, int | None]], time_ms: int | None
) -> None:
    group = tuple(sc.Ssc32Move(*m) for m in moves)
    frame = sc.encode_group_move(group, time_ms)
    assert frame.endswith(b"\r") and frame.count(b"\r") == 1
    assert sc.parse_command(frame[:-1]) == sc.Ssc32GroupMove(group, time_ms)


# ---- fuzz: decoders raise only ReplyError; the parser only Ssc32SyntaxError -----------


def test_fuzz_reply_decoders() -> None:
    rng = random.Random(1234)
    decoders = [
        mc.decode_position_us,
        mc.decode_moving_state,
        mc.decode_errors,
        sc.decode_movement,
        sc.decode_pulse_us,
    ]
    ok = 0
    for _ in range(20000):
        data = rng.randbytes(rng.choice((0, 1, 1, 2, 2, 3, rng.randrange(16))))
        for decode in decoders:
            try:
                decode(data)
                ok += 1
            except ReplyError:
                pass
    assert ok > 1000  # the valid shapes were hit too, not only errors


def test_fuzz_ssc32_parser() -> None:
    rng = random.Random(99)
    alphabet = b"#PSTQp0123456789 \t\n.+-x"
    for _ in range(20000):
        line = bytes(rng.choice(alphabet) for _ in range(rng.randrange(20)))
        try:
            sc.parse_command(line)
        except sc.Ssc32SyntaxError:
            pass
    for _ in range(5000):
        try:
            sc.parse_command(rng.randbytes(rng.randrange(30)))
        except sc.Ssc32SyntaxError:
            pass


# ---- calibration ----------------------------------------------------------------------


def test_default_calibration() -> None:
    cal = ServoCalibration()
    assert cal.angle_to_pulse_us(-90) == 1000
    assert cal.angle_to_pulse_us(0) == 1500
    assert cal.angle_to_pulse_us(90) == 2000
    assert cal.pulse_us_to_angle(1750) == 45
    assert cal.clamp(120) == 90 and cal.clamp(-200) == -90 and cal.clamp(12.5) == 12.5
    assert cal.us_per_deg == pytest.approx(1000 / 180)


def test_piecewise_and_reversed_calibration() -> None:
    cal = ServoCalibration(pulse_us=(900, 1400, 2100), limits_deg=(-60, 80))
    assert cal.angle_to_pulse_us(-45) == pytest.approx(1400 - 500 * 0.5)
    assert cal.angle_to_pulse_us(45) == pytest.approx(1400 + 700 * 0.5)
    rev = ServoCalibration(pulse_us=[2000, 1500, 1000], limits_deg=[-90, 90])  # type: ignore[arg-type]
    assert rev.pulse_us == (2000.0, 1500.0, 1000.0)  # lists from TOML become tuples
    assert rev.angle_to_pulse_us(45) == 1250
    assert rev.pulse_us_to_angle(1250) == 45
    assert rev.pulse_us_to_angle(1900) == pytest.approx(-72)
    assert rev.pulse_range_us() == (1000, 2000)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"pulse_us": (1000, 1000, 2000)},
        {"pulse_us": (1000, 2500, 2000)},
        {"pulse_us": (1000, 1500)},
        {"pulse_us": (0, 1500, 2000)},
        {"pulse_us": (1000, math.nan, 2000)},
        {"limits_deg": (10, -10)},
        {"limits_deg": (-math.inf, 0)},
    ],
)
def test_bad_calibration_is_a_clear_error(kwargs: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        ServoCalibration(**kwargs)  # type: ignore[arg-type]


def test_check_speed() -> None:
    assert check_speed(math.inf) == 0
    assert check_speed(90) == 90
    for bad in (-1, math.nan):
        with pytest.raises(ValueError):
            check_speed(bad)


@st.composite
def calibrations(draw: st.DrawFn) -> ServoCalibration:
    mid = draw(st.floats(1200, 1800))
    lo_span = draw(st.floats(100, 700))
    hi_span = draw(st.floats(100, 700))
    pulses = (mid - lo_span, mid, mid + hi_span)
    if draw(st.booleans()):
        pulses = (mid + lo_span, mid, mid - hi_span)
    lo = draw(st.floats(-120, 0))
    hi = draw(st.floats(0.5, 120))
    return ServoCalibration(pulse_us=pulses, limits_deg=(lo, hi))


@given(calibrations(), st.floats(-1000, 1000))
def test_calibration_round_trip(cal: ServoCalibration, angle: float) -> None:
    clamped = cal.clamp(angle)
    assert cal.limits_deg[0] <= clamped <= cal.limits_deg[1]
    pulse = cal.angle_to_pulse_us(clamped)
    assert cal.pulse_us_to_angle(pulse) == pytest.approx(clamped, abs=1e-6)
    lo, hi = cal.pulse_range_us()
    assert lo - 1e-9 <= pulse <= hi + 1e-9
