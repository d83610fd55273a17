"""ARCOS codec: the manuals' byte examples (docs/PROTOCOLS.md 1.2), round trips, resync and fuzzing."""

from __future__ import annotations

import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.arcos.codec import (
    ArgType,
    CodecError,
    Command,
    Decoder,
    Packet,
    checksum,
    decode_command,
    encode_command,
    encode_packet,
    split_vel2,
    vel2_arg,
)

DOC_VECTORS = [
    (encode_command(Command.SYNC0), "FA FB 03 00 00 00"),
    (encode_command(Command.SYNC1), "FA FB 03 01 00 01"),  # also OPEN without argument
    (encode_command(Command.SYNC2), "FA FB 03 02 00 02"),
    (encode_command(Command.ENABLE, 1), "FA FB 06 04 3B 01 00 05 3B"),
    (encode_command(Command.CONFIG, 1), "FA FB 06 12 3B 01 00 13 3B"),
    (encode_command(Command.VEL, -200), "FA FB 06 0B 1B C8 00 D3 1B"),
    (encode_command(Command.RVEL, -30), "FA FB 06 15 1B 1E 00 33 1B"),
    (encode_command(Command.SONAR, 1), "FA FB 06 1C 3B 01 00 1D 3B"),
    (encode_command(Command.VEL2, vel2_arg(-1, 1)), "FA FB 06 20 1B FF 00 1F 1B"),
]

DOC_SIP = bytes.fromhex(
    "FA FB 28 32 E8 03 F4 01 00 04 64 00 64 00 82 00 00 00 00 1F 00 00 02 00 DC 05 03 20 03"
    " 00 00 00 FF FF 82 00 00 00 00 00 00 82 8B"
)


@pytest.mark.parametrize(("encoded", "hexbytes"), DOC_VECTORS)
def test_protocol_doc_byte_examples(encoded: bytes, hexbytes: str) -> None:
    assert encoded == bytes.fromhex(hexbytes)


def test_doc_sip_example_decodes() -> None:
    d = Decoder()
    (pkt,) = d.feed(DOC_SIP)
    assert pkt.ptype == 0x32 and len(pkt.payload) == 0x28 - 3
    assert pkt.encode() == DOC_SIP


def test_checksum_odd_byte_xors_low_byte() -> None:
    assert checksum(b"\x01\x02\x03") == (0x0102 ^ 0x03)
    assert checksum(b"\xff\xff\xff\xff") == 0xFFFE  # 16-bit wrap


def test_int_args_and_strings() -> None:
    assert encode_command(Command.VEL, 0)[4:7] == bytes((ArgType.INT, 0, 0))
    assert encode_command(Command.VEL, 300)[4:7] == bytes((ArgType.INT, 0x2C, 0x01))
    assert encode_command(Command.VEL, -300)[4:7] == bytes((ArgType.NINT, 0x2C, 0x01))
    pkt = encode_command(3, b"\x01\x02\x03")
    assert pkt[4:9] == bytes((ArgType.STR, 3, 1, 2, 3))
    (p,) = Decoder().feed(pkt)
    assert decode_command(p) == (3, b"\x01\x02\x03")
    with pytest.raises(CodecError):
        encode_command(Command.VEL, 70000)
    with pytest.raises(CodecError):
        decode_command(Packet(11, b"\x3b\x01"))
    with pytest.raises(CodecError):
        decode_command(Packet(11, b"\x99\x01\x00"))


def test_vel2_clamps_to_signed_byte() -> None:
    assert split_vel2(vel2_arg(128, -129)) == (127, -128)  # ARIA's +128 -> -128 bug avoided
    assert split_vel2(vel2_arg(-5, 7)) == (-5, 7)


def test_long_packets_use_an_unsigned_count() -> None:
    payload = bytes(range(200))  # N = 203 >= 128: the AriaCoda signed-char regression
    frame = encode_packet(0x20, payload)
    assert frame[2] == 203
    d = Decoder()
    assert d.feed(frame) == [Packet(0x20, payload)]
    assert d.checksum_errors == 0
    with pytest.raises(CodecError):
        encode_packet(0x20, bytes(253))


def test_bad_checksum_and_impossible_length_are_counted() -> None:
    good = encode_command(Command.ENABLE, 1)
    bad = bytearray(good)
    bad[-1] ^= 0x55
    d = Decoder()
    assert d.feed(bytes(bad) + b"\xfa\xfb\x02\x00" + good) == [Packet(4, b"\x3b\x01\x00")]
    assert d.checksum_errors == 1
    assert d.length_errors == 1
    assert d.packets == 1


def test_frame_hidden_inside_a_corrupt_frame_is_found() -> None:
    good = encode_command(Command.SONAR, 1)
    # a false header claiming 20 bytes, swallowing the real frame
    d = Decoder()
    out = d.feed(b"\xfa\xfb\x14" + good + bytes(20))
    assert out == [Packet(28, b"\x3b\x01\x00")]


def test_byte_at_a_time() -> None:
    stream = b"".join(f for f, _ in DOC_VECTORS) + DOC_SIP
    d = Decoder()
    out: list[Packet] = []
    for b in stream:
        out += d.feed(bytes((b,)))
    assert len(out) == len(DOC_VECTORS) + 1
    assert d.pending == 0 and d.resyncs == 0


packets = st.builds(Packet, st.integers(0, 255), st.binary(max_size=252))
commands = st.tuples(
    st.sampled_from(list(Command)),
    st.one_of(st.none(), st.integers(-0xFFFF, 0xFFFF), st.binary(max_size=100)),
)


@given(st.lists(packets, max_size=8), st.data())
def test_round_trip_any_split(pkts: list[Packet], data: st.DataObject) -> None:
    stream = b"".join(p.encode() for p in pkts)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=10)))
    d = Decoder()
    out: list[Packet] = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        out += d.feed(stream[a:b])
    assert out == pkts


@given(commands)
def test_command_round_trip(cmd: tuple[Command, int | bytes | None]) -> None:
    number, arg = cmd
    (pkt,) = Decoder().feed(encode_command(number, arg))
    assert decode_command(pkt) == (number, arg)


def _no_header(b: bytes) -> bool:
    return b"\xfa\xfb" not in b and not b.endswith(b"\xfa")


@given(
    st.lists(st.tuples(st.binary(max_size=30).filter(_no_header), packets), max_size=8),
    st.binary(max_size=30),
)
def test_valid_packets_between_garbage_all_recovered_in_order(
    chunks: list[tuple[bytes, Packet]], tail: bytes
) -> None:
    stream = b"".join(g + p.encode() for g, p in chunks) + tail
    d = Decoder()
    got = d.feed(stream)
    assert got[: len(chunks)] == [p for _, p in chunks]


def test_full_random_garbage_with_false_headers_loses_nothing() -> None:
    """Garbage may contain FA FB headers: each costs at most a wait, never a valid packet."""
    rng = random.Random(1234)
    sent: list[Packet] = []
    stream = bytearray()
    for _ in range(400):
        junk = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 12)))
        if rng.random() < 0.3:
            junk += b"\xfa\xfb" + bytes((rng.randrange(256),))
        pkt = Packet(
            rng.randrange(256), bytes(rng.randrange(256) for _ in range(rng.randrange(60)))
        )
        sent.append(pkt)
        stream += junk + pkt.encode()
    d2 = Decoder()
    # Trailing zeros complete a false header that is still waiting, without framing anything.
    got_all = d2.feed(bytes(stream) + bytes(300))
    assert got_all == sent
    assert d2.resyncs > 0 and d2.garbage_bytes > 0


def test_fuzz_never_raises_and_recovers() -> None:
    rng = random.Random(99)
    probe = encode_command(Command.ENABLE, 1)
    for _ in range(5000):
        d = Decoder()
        junk = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 64)))
        d.feed(junk)
        # 258 zero bytes complete any false frame without forming a new one
        out = d.feed(bytes(258) + probe)
        assert out[-1:] == [Packet(4, b"\x3b\x01\x00")], junk.hex()
        assert d.pending == 0


@settings(max_examples=300)
@given(st.binary(max_size=600))
def test_decoder_never_raises_and_bounds_its_buffer(data: bytes) -> None:
    d = Decoder()
    d.feed(data)
    assert d.pending <= 258
    assert d.bytes_rx == len(data)
