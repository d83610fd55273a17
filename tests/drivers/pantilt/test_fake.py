"""The fake controllers on their own: firmware-like parsing, replies, slew in clock time."""

from __future__ import annotations

import random

from hypothesis import given
from hypothesis import strategies as st

from drivers.pantilt import maestro as mc
from drivers.pantilt import ssc32 as sc
from drivers.pantilt.fake import FakeMaestro, FakeSsc32, travelled_us
from tests.support import ManualClock


def maestro(**kwargs: object) -> tuple[FakeMaestro, ManualClock]:
    clock = ManualClock()
    return FakeMaestro(clock=clock, **kwargs), clock  # type: ignore[arg-type]


def ask(fake: FakeMaestro | FakeSsc32, frame: bytes) -> bytes:
    before = len(fake.sent)
    fake.feed(frame)
    return bytes(fake.sent[before:])


# ---- Maestro --------------------------------------------------------------------------


def test_maestro_target_position_and_errors() -> None:
    fake, _ = maestro()
    assert ask(fake, mc.get_position(0)) == b"\x00\x00"  # pulses off at power-up
    fake.feed(mc.set_target(2, 6000))
    assert fake.target_us(2) == 1500.0
    assert ask(fake, mc.get_position(2)) == bytes.fromhex("70 17")
    assert ask(fake, mc.get_moving_state()) == b"\x00"
    assert ask(fake, mc.get_errors()) == b"\x00\x00"
    assert fake.commands[1] == ("set_target", 2, 6000)


def test_maestro_clamps_targets_to_its_configured_range() -> None:
    fake, _ = maestro()
    fake.feed(mc.set_target(0, 4 * 2400))
    assert fake.target_us(0) == 2000.0
    fake.feed(mc.set_target(0, 0))  # 0 = stop pulses, not clamped
    assert fake.target_us(0) == 0.0


def test_maestro_malformed_input_sets_protocol_error() -> None:
    fake, _ = maestro()
    for garbage in (b"\x80", b"\x05", b"\x84\x00\x70" + mc.get_moving_state(), mc.get_position(6)):
        sent = ask(fake, garbage)
        errors = ask(fake, mc.get_errors())
        assert mc.error_names(mc.decode_errors(errors)) == ("serial_protocol",), garbage
        assert ask(fake, mc.get_errors()) == b"\x00\x00"  # reading clears
        # The interrupting Get Moving State of the third case is still answered.
        assert sent in (b"", b"\x00")
    # Nothing was moved by the rejected frames.
    assert all(s.target_us == 0 for s in fake.servos)


def test_maestro_error_sends_channels_home() -> None:
    fake, _ = maestro(home_us={1: 1200.0})
    fake.feed(mc.set_target(1, 6000))
    fake.feed(b"\xc0")
    assert fake.target_us(1) == 1200.0
    fake.feed(mc.set_target(1, 6000) + mc.go_home())
    assert fake.target_us(1) == 1200.0


def test_maestro_pololu_and_mini_ssc_protocols() -> None:
    fake, _ = maestro()
    fake.feed(mc.pololu_frame(mc.set_target(1, 6800)))
    assert fake.target_us(1) == 1700.0
    fake.feed(mc.pololu_frame(mc.set_target(1, 5000), device=13))  # someone else's
    assert fake.target_us(1) == 1700.0
    assert ask(fake, mc.pololu_frame(mc.get_position(1))) == (6800).to_bytes(2, "little")
    fake.feed(bytes((0xFF, 3, 254)))  # Mini SSC: top of range, a data byte with MSB set
    assert fake.target_us(3) == 1976.25
    assert ask(fake, mc.get_errors()) == b"\x00\x00"


def test_maestro_slews_at_the_set_speed() -> None:
    fake, clock = maestro()
    fake.feed(mc.set_target(0, 6000))  # first target of an off channel: immediate
    fake.feed(mc.set_speed(0, 20))  # 20 * 25 = 500 us/s
    fake.feed(mc.set_target(0, 8000))
    assert ask(fake, mc.get_moving_state()) == b"\x01"
    clock.t += 0.5
    assert fake.position_us(0) == 1750.0
    assert ask(fake, mc.get_position(0)) == (7000).to_bytes(2, "little")
    fake.feed(mc.set_speed(0, 40))  # speed change applies from now on
    clock.t += 0.25
    assert fake.position_us(0) == 2000.0
    assert ask(fake, mc.get_moving_state()) == b"\x00"


def test_maestro_acceleration_ramps() -> None:
    fake, clock = maestro()
    fake.feed(mc.set_target(0, 4000) + mc.set_acceleration(0, 1) + mc.set_target(0, 8000))
    clock.t += 1.0  # 312.5 us/s^2: 156.25 us after one second from rest
    assert abs(fake.position_us(0) - 1156.25) < 1e-9
    clock.t += 10.0
    assert fake.position_us(0) == 2000.0


@given(
    st.floats(1, 2000),
    st.one_of(st.just(0.0), st.floats(1, 5000)),
    st.one_of(st.just(0.0), st.floats(1, 5000)),
    st.lists(st.floats(0, 20), min_size=2, max_size=10),
)
def test_ramp_is_monotonic_and_bounded(d: float, v: float, a: float, times: list[float]) -> None:
    last = 0.0
    for t in sorted(times):
        s = travelled_us(d, t, v, a)
        assert -1e-9 <= s <= d + 1e-9
        assert s >= last - 1e-9
        last = s
    assert travelled_us(d, 1e6, v, a) == d


def test_silent_maestro_ignores_everything() -> None:
    fake, _ = maestro()
    fake.silent = True
    assert ask(fake, mc.set_target(0, 6000) + mc.get_position(0)) == b""
    assert fake.target_us(0) == 0.0


# ---- SSC-32 ---------------------------------------------------------------------------


def test_ssc32_move_query_and_garbage() -> None:
    clock = ManualClock()
    fake = FakeSsc32(clock=clock)
    assert ask(fake, b"QP0\r") == b"\x00"
    fake.feed(b"#0P1500\r")
    assert ask(fake, b"QP0\r") == bytes([150])
    assert ask(fake, b"Q\r") == b"."
    # Garbage is ignored up to its CR; the next line is read normally.
    assert ask(fake, b"hello #0P1000 world\r#0p2000s500\r") == b""
    assert fake.ignored_lines == 1
    assert ask(fake, b"Q\r") == b"+"
    clock.t += 0.5
    assert ask(fake, b"QP0\r") == bytes([175])
    clock.t += 0.5
    assert ask(fake, b"Q\rQP0QP1\r") == b"." + bytes([200, 0])


def test_ssc32_group_move_arrives_together() -> None:
    clock = ManualClock()
    fake = FakeSsc32(clock=clock)
    fake.feed(b"#0P1000#1P1000\r")
    fake.feed(b"#0P2000S1000#1P1500T2000\r")  # 1 s at S, but T stretches the group to 2 s
    clock.t += 1.0
    assert fake.position_us(0) == 1500.0
    assert fake.position_us(1) == 1250.0
    clock.t += 1.0
    assert (fake.position_us(0), fake.position_us(1)) == (2000.0, 1500.0)


def test_ssc32_overlong_line_is_dropped() -> None:
    fake = FakeSsc32(clock=ManualClock())
    fake.feed(b"#0P1500" + b" " * 400 + b"\r")
    assert fake.ignored_lines == 1 and fake.target_us(0) == 0.0
    fake.feed(b"#0P1500\r")
    assert fake.target_us(0) == 1500.0


def test_fuzz_fakes_never_raise() -> None:
    rng = random.Random(7)
    clock = ManualClock()
    m = FakeMaestro(clock=clock)
    s = FakeSsc32(clock=clock)
    ssc_alphabet = b"#PSTQ0123456789\r\r\r xq+."
    for _ in range(3000):
        m.feed(rng.randbytes(rng.randrange(12)))
        s.feed(bytes(rng.choice(ssc_alphabet) for _ in range(rng.randrange(16))))
        s.feed(rng.randbytes(rng.randrange(8)))
        clock.t += 0.01
    # Still answering correctly after all that noise.
    m.feed(b"\xa1")  # finish whatever frame was open (a protocol error), then clear
    m.feed(mc.get_errors())
    assert ask(m, mc.get_errors()) == b"\x00\x00"
    s.feed(b"\r")
    assert ask(s, sc.QUERY_MOVEMENT) in (b".", b"+")
