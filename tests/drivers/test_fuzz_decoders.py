"""Fuzzing the decoders where bytes and text from devices enter relayd.

The per-codec test files already fuzz the pure functions one input at a time
(tests/drivers/arcos/test_codec.py: clean streams at any split, garbage without sync bytes in
one chunk; test_pantilt_codec.py: the reply decoders on random bytes;
test_wifi_parsers.py and test_airos_model.py: the text and JSON parsers). This file
adds what they leave out, each with hypothesis:

* ARCOS: *arbitrary* garbage (false FA FB headers included) before valid packets, the
  whole stream cut into arbitrary chunks; SIP, SYNC2 and CONFIGpac payload decoding;
  and the driver's own packet path (a valid SIP after bad ones is taken as is).
* Pan-tilt: the driver's reply assembly (stray bytes before a request, the reply in
  arbitrary chunks) followed by the Maestro and SSC-32 reply decoders.
* Wi-Fi: the RSSI *sources* (state across reads): after any garbage file or `iw`
  output, a valid one gives a fresh sample with its level.
* airOS: any bytes around a real status document raise only AirOsDataError, and the
  document itself, decoded after them, gives the same link quality as alone.

Properties: nothing but the documented error type escapes; valid input after garbage
still decodes. Example counts keep the file under ~30 s on the shared machine.
"""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, assume, event, example, given, settings
from hypothesis import strategies as st

from drivers.airos.model import AirOsDataError, decode_stations, decode_status
from drivers.arcos.codec import SIP_TYPES, CodecError, Decoder, Packet, decode_command
from drivers.arcos.driver import ArcosRobot
from drivers.arcos.sip import (
    RawSip,
    RobotIdentity,
    conv_factors,
    decode_config,
    decode_identity,
    decode_raw_sip,
    encode_config,
    encode_identity,
)
from drivers.pantilt import maestro as mc
from drivers.pantilt import ssc32 as sc
from drivers.pantilt.base import ServoCalibration
from drivers.pantilt.session import ReplyError
from drivers.wifi.fake import format_proc_row, link_quality_for
from drivers.wifi.parsers import PROC_HEADER_1, PROC_HEADER_2, parse_proc_net_wireless
from drivers.wifi.sources import IwSource, ProcfsSource

FUZZ = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow], max_examples=1000)
FEW = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow], max_examples=400)


def _chunks(data: bytes, cuts: list[int]) -> Iterator[bytes]:
    points = sorted({min(max(c, 0), len(data)) for c in cuts})
    for a, b in zip([0, *points], [*points, len(data)], strict=True):
        yield data[a:b]


# ---------------------------------------------------------------------- ARCOS stream

packets = st.builds(Packet, st.integers(0, 255), st.binary(max_size=120))
# Garbage biased towards the bytes that confuse a framer: sync pairs and small counts.
garbage = st.lists(
    st.one_of(
        st.binary(max_size=12),
        st.just(b"\xfa\xfb"),
        st.just(b"\xfa"),
        st.builds(lambda n: b"\xfa\xfb" + bytes((n,)), st.integers(0, 255)),
    ),
    max_size=8,
).map(b"".join)


SENTINEL = Packet(0xAB, b"end")


@FUZZ
@given(
    junk=garbage,
    pkts=st.lists(packets, min_size=1, max_size=3),
    cuts=st.lists(st.integers(0, 2000), max_size=12),
)
def test_arcos_packets_after_any_garbage_at_any_split(
    junk: bytes, pkts: list[Packet], cuts: list[int]
) -> None:
    # Garbage that holds a whole valid frame of its own is not garbage.
    assume(Decoder().feed(junk + bytes(258)) == [])
    # 258 zero bytes complete any false frame still waiting without forming a new one
    # (a real robot's next SIPs do the same); a false frame is at most 258 bytes long,
    # so whatever the garbage did, the packet after the padding must come out.
    stream = junk + b"".join(p.encode() for p in pkts) + bytes(258) + SENTINEL.encode()
    d = Decoder()
    out: list[Packet] = []
    for chunk in _chunks(stream, cuts):
        out += d.feed(chunk)
    assert out[-1] == SENTINEL and d.pending == 0
    if all(p in pkts for p in out[:-1]):
        # No false frame happened to pass the checksum: every real packet, in order.
        assert out == [*pkts, SENTINEL]
    assert d.bytes_rx == len(stream)


@FUZZ
@given(
    junk=st.binary(max_size=80).filter(lambda b: b"\xfa\xfb" not in b),
    pkt=packets,
    cuts=st.lists(st.integers(0, 400), max_size=10),
)
def test_arcos_packet_after_syncless_garbage_always_decodes(
    junk: bytes, pkt: Packet, cuts: list[int]
) -> None:
    # Garbage without a sync pair may still end in FA: the packet's own FA FB follows.
    d = Decoder()
    out: list[Packet] = []
    for chunk in _chunks(junk + pkt.encode(), cuts):
        out += d.feed(chunk)
    assert out == [pkt]
    assert d.pending == 0
    assert d.garbage_bytes == len(junk)


# ---------------------------------------------------------------------- ARCOS payloads

sonar = st.lists(st.tuples(st.integers(0, 255), st.integers(0, 0xFFFF)), max_size=16)
raw_sips = st.builds(
    RawSip,
    moving=st.booleans(),
    x_raw=st.integers(0, 0xFFFF),
    y_raw=st.integers(0, 0xFFFF),
    th_raw=st.integers(-32768, 32767),
    left_raw=st.integers(-32768, 32767),
    right_raw=st.integers(-32768, 32767),
    battery_dv=st.integers(0, 255),
    stall_bumpers=st.integers(0, 0xFFFF),
    control=st.integers(-32768, 32767),
    flags=st.integers(0, 0xFFFF),
    compass=st.integers(0, 255),
    sonar=sonar.map(tuple),
    battery_x10=st.one_of(st.none(), st.integers(0, 0xFFFF)),
)


@FUZZ
@given(ptype=st.sampled_from([0x32, 0x33, 0x20, 0x02, 0x90, 0x00]), payload=st.binary(max_size=252))
def test_arcos_payload_decoders_raise_only_codec_error(ptype: int, payload: bytes) -> None:
    for decode in (
        lambda: decode_raw_sip(ptype, payload),
        lambda: decode_identity(payload),
        lambda: decode_config(payload),
        lambda: decode_command(Packet(ptype, payload)),
    ):
        try:
            decode()
        except CodecError:
            pass


# Found by a random seed: the junk's FA FB and the first packet's FA open a false frame of
# 250 bytes whose body sums to 0 and whose "checksum" is the zero padding, so it passes and
# swallows the bad SIP and the good one.
_SWALLOWED = RawSip(
    moving=True,
    x_raw=0,
    y_raw=0,
    th_raw=0,
    left_raw=0,
    right_raw=-15934,
    battery_dv=0,
    stall_bumpers=0,
    control=-1,
    flags=1024,
    compass=0,
    sonar=((100, 0), (0, 767)),
    digin=255,
    digout=255,
    battery_x10=4297,
)


@FEW
@given(bad=st.lists(st.binary(max_size=60), min_size=1, max_size=4), good=raw_sips, junk=garbage)
@example(bad=[b"\xd2H$z6\x94>\xaey\xb1z\xb8\xaeL"], good=_SWALLOWED, junk=b"\xfa\xfb")
def test_arcos_driver_takes_a_valid_sip_after_bad_ones(
    bad: list[bytes], good: RawSip, junk: bytes
) -> None:
    """The driver's own packet path: bad SIPs are counted, the next good one is used.

    The oracle is what the decoder delivers, not what was sent: the 16-bit checksum lets
    about one false frame in 65536 through, and a false frame that starts in the junk
    swallows the real packets after it (the decoder cannot tell it from a real one). The
    robot sends the good SIP again after the padding, as it does every cycle; by then any
    false frame is over (at most 258 bytes), so that one is always taken.
    """
    robot = ArcosRobot("socket://127.0.0.1:9")
    robot.factors = conv_factors("p3at-sh")
    seen: list[Any] = []
    robot.add_listener(seen.append)
    good_pkt = Packet(*good.encode())
    sent = [*(Packet(0x32, b) for b in bad), good_pkt]
    stream = junk + b"".join(p.encode() for p in sent) + bytes(258) + good_pkt.encode()
    delivered = Decoder().feed(stream)
    sips = [p for p in delivered if p.ptype in SIP_TYPES]
    for pkt in sips:
        robot.handle_sip(pkt, 0.0)  # raises if anything but a CodecError escapes decoding
    assert robot.counters["listener_errors"] == 0
    undecodable = sum(1 for p in sips if not _decodes(p))
    # Every SIP the driver is given is either counted bad or used; none is lost.
    assert robot.counters["bad_sips"] == undecodable
    assert robot.counters["sips"] == len(sips) - undecodable == len(seen)
    if delivered[-len(sent) - 1 : -1] == sent:
        valid_bad = sum(1 for b in bad if _decodes(Packet(0x32, b)))
        assert robot.counters["bad_sips"] >= len(bad) - valid_bad
    else:
        event("a false frame passed the checksum and swallowed real packets")
    assert delivered[-1] == good_pkt
    assert robot.last_sip is not None and seen and seen[-1] is robot.last_sip
    sip = robot.last_sip
    assert sip.battery_v == (good.battery_x10 or good.battery_dv) / 10.0
    assert sip.left_mm_s == good.left_raw and sip.right_mm_s == good.right_raw
    assert sip.moving == good.moving
    assert all(math.isfinite(v) for v in (sip.x_mm, sip.y_mm, sip.theta_deg, sip.rotvel_deg_s))
    for i, r in enumerate(robot.sonar.ranges_mm):
        assert r is None or 0 <= r <= 5000, (i, r)


def _decodes(pkt: Packet) -> bool:
    try:
        decode_raw_sip(pkt.ptype, pkt.payload)
    except CodecError:
        return False
    return True


@FEW
@given(
    name=st.text(st.characters(min_codepoint=1, max_codepoint=255), max_size=20),
    cut=st.integers(0, 200),
)
def test_arcos_identity_and_config_round_trip_or_codec_error(name: str, cut: int) -> None:
    ident = RobotIdentity(name, "Pioneer", "p3at-sh")
    assert decode_identity(encode_identity(ident)) == ident
    cfg = encode_config(ident)
    assert decode_config(cfg).name == name
    try:
        decode_config(cfg[:cut])  # older firmware ends early; a torn one is a CodecError
    except CodecError:
        pass


# ---------------------------------------------------------------------- pan-tilt replies


class _Transport:
    def is_closing(self) -> bool:
        return False

    def write(self, data: bytes) -> None:
        pass


def _assemble(pt: Any, stray: bytes, reply: bytes, cuts: list[int], size: int) -> bytes:
    """Drive the driver's reply assembly synchronously: stray bytes, then a request's reply."""
    loop = asyncio.new_event_loop()
    try:
        pt._on_data(stray)  # nobody is waiting: dropped and counted
        fut = loop.create_future()
        pt._rx.clear()
        pt._waiter = (size, fut)
        for chunk in _chunks(reply, cuts):
            if chunk:
                pt._on_data(chunk)
        assert fut.done()
        return bytes(fut.result())
    finally:
        pt._waiter = None
        loop.close()


def _pantilt(protocol: str) -> Any:
    cal = {0: ServoCalibration(), 1: ServoCalibration()}
    if protocol == "maestro":
        pt: Any = mc.MaestroPanTilt("/dev/null", 115200, cal)
    else:
        pt = sc.Ssc32PanTilt("/dev/null", 9600, cal)
    pt._transport = _Transport()
    pt._ready = True
    return pt


@FUZZ
@given(
    stray=st.binary(max_size=20),
    quarter=st.integers(0, mc.MAX_14BIT),
    extra=st.binary(max_size=3),
    cuts=st.lists(st.integers(0, 8), max_size=4),
    noise=st.binary(min_size=1, max_size=3),
)
def test_maestro_reply_after_stray_bytes_at_any_split(
    stray: bytes, quarter: int, extra: bytes, cuts: list[int], noise: bytes
) -> None:
    pt = _pantilt("maestro")
    reply = _assemble(pt, stray, bytes((quarter & 0xFF, quarter >> 8)) + extra, cuts, 2)
    assert mc.decode_position_us(reply) == quarter / 4.0
    assert pt.counters["stray_bytes"] == len(stray) + len(extra)
    # Any bytes in the reply's place: decoders raise ReplyError or give a value.
    for decode in (mc.decode_position_us, mc.decode_moving_state, mc.decode_errors):
        try:
            decode(noise)
        except ReplyError:
            pass


@FUZZ
@given(
    stray=st.binary(max_size=20),
    pulse10=st.integers(0, 255),
    moving=st.booleans(),
    reply=st.binary(max_size=3),
)
def test_ssc32_reply_after_stray_bytes(
    stray: bytes, pulse10: int, moving: bool, reply: bytes
) -> None:
    pt = _pantilt("ssc32")
    assert sc.decode_pulse_us(_assemble(pt, stray, bytes((pulse10,)), [], 1)) == pulse10 * 10
    assert sc.decode_movement(_assemble(pt, b"", b"+" if moving else b".", [], 1)) is moving
    assert pt.counters["stray_bytes"] == len(stray)
    for decode in (sc.decode_pulse_us, sc.decode_movement):
        try:
            decode(reply)
        except ReplyError:
            pass


# ---------------------------------------------------------------------- Wi-Fi sources

_text = st.one_of(
    st.text(st.characters(exclude_categories=["Cs"]), max_size=300),
    st.lists(st.sampled_from(list(" \t:.|-0123456789wlan1\n")), max_size=200).map("".join),
)


@pytest.fixture(scope="module")
def loop() -> Iterator[asyncio.AbstractEventLoop]:
    lp = asyncio.new_event_loop()
    yield lp
    lp.close()


@FEW
@given(junk=st.lists(_text, min_size=1, max_size=3), level=st.integers(-95, -20))
def test_procfs_source_after_garbage_files_reads_a_valid_one(
    tmp_path_factory: pytest.TempPathFactory,
    loop: asyncio.AbstractEventLoop,
    junk: list[str],
    level: int,
) -> None:
    path: Path = tmp_path_factory.mktemp("procfs") / "wireless"
    src = ProcfsSource("wlan1", path=path)
    for text in junk:
        assume("wlan1" not in parse_proc_net_wireless(text))
        path.write_text(text, encoding="utf-8")
        sample = loop.run_until_complete(src.read())
        assert not sample.fresh and sample.rssi_dbm is None
    row = format_proc_row(
        "wlan1",
        link=link_quality_for(level),
        link_updated=True,
        level=level,
        level_updated=True,
        misc=len(junk),
    )
    path.write_text(PROC_HEADER_1 + "\n" + PROC_HEADER_2 + "\n" + row + "\n", encoding="utf-8")
    sample = loop.run_until_complete(src.read())
    assert sample.fresh and sample.rssi_dbm == level
    assert src.available and src.last_error is None


class _ScriptedIw(IwSource):
    """`iw` output from a list instead of a subprocess."""

    def __init__(self, outputs: list[str]) -> None:
        super().__init__("wlan1")
        self.outputs = outputs

    async def _run(self) -> str:
        return self.outputs.pop(0)


IW_LINK = (
    "Connected to 34:fc:b9:74:cf:d0 (on wlan1)\n\tSSID: relay\n\tfreq: 5260\n"
    "\tRX: 149879 bytes ({rx} packets)\n\tTX: 4747 bytes (33 packets)\n"
    "\tsignal: {dbm} dBm\n\ttx bitrate: 6.0 MBit/s\n"
)


@FEW
@given(junk=st.lists(_text, min_size=1, max_size=3), level=st.integers(-95, -20))
def test_iw_source_after_garbage_output_reads_a_valid_one(
    loop: asyncio.AbstractEventLoop, junk: list[str], level: int
) -> None:
    src = _ScriptedIw([*junk, IW_LINK.format(rx=900, dbm=level)])
    for _ in junk:
        sample = loop.run_until_complete(src.read())
        # Garbage that happens to read as a link may carry a level; never a crash.
        assert sample.rssi_dbm is None or -130 <= sample.rssi_dbm <= 0
    sample = loop.run_until_complete(src.read())
    assert sample.rssi_dbm == level
    assert sample.fresh


# ---------------------------------------------------------------------- airOS JSON

FIXTURES = sorted((Path(__file__).parents[1] / "fixtures" / "airos").glob("status_cgi_*.json"))


@pytest.fixture(scope="module")
def documents() -> list[tuple[bytes, Any]]:
    out = []
    for p in FIXTURES:
        raw = p.read_bytes()
        out.append((raw, decode_status(raw, t=0.0).to_json()))
    assert out, "no airOS fixtures"
    return out


@FUZZ
@given(
    which=st.integers(0, 10),
    before=st.binary(max_size=40),
    after=st.binary(max_size=40),
    cut=st.integers(0, 10_000),
    flip=st.integers(0, 10_000),
    byte=st.integers(0, 255),
)
def test_airos_any_bytes_around_a_document_then_the_document(
    documents: list[tuple[bytes, Any]],
    which: int,
    before: bytes,
    after: bytes,
    cut: int,
    flip: int,
    byte: int,
) -> None:
    raw, expected = documents[which % len(documents)]
    mutated = bytearray(raw)
    mutated[flip % len(raw)] = byte
    for blob in (
        before + raw + after,
        raw[: cut % len(raw)],
        bytes(mutated),
        before,
        after,
        json.dumps(json.loads(raw)["wireless"]).encode(),
    ):
        for decode in (lambda b: decode_status(b, t=0.0), decode_stations):
            try:
                decode(blob)
            except AirOsDataError:
                pass
    # The decoders keep no state: the real document still gives what it gives alone.
    assert decode_status(raw, t=0.0).to_json() == expected
