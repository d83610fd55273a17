"""A recording that declares a huge chunk, or whose chunk fails its CRC, is refused by the one
reader replay and calibrate --from share, before anything is decompressed."""

from __future__ import annotations

import struct
import tracemalloc
from pathlib import Path

import pytest
from mcap.writer import CompressionType, Writer

from relayd.calibrate.sources import SourceError, iter_recording
from relayd.record.reader import CHUNK_SIZE_LIMIT, RecordingError, iter_messages, read_recording


def _recording(path: Path) -> None:
    with path.open("wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start("relayd", "test")
        schema = w.register_schema("sip", "jsonschema", b"{}")
        ch = w.register_channel("/robot/sip", "json", schema)
        for i in range(50):
            w.add_message(ch, i, b'{"t": %d, "sip": {}}' % i, i)
        w.finish()


def _chunk_offset(data: bytes) -> int:
    i = 8  # past the magic
    while i < len(data):
        opcode, length = data[i], struct.unpack_from("<Q", data, i + 1)[0]
        if opcode == 0x06:  # Chunk
            return i
        i += 9 + length
    raise AssertionError("no chunk")


def _declaring(path: Path, size: int) -> Path:
    data = bytearray(path.read_bytes())
    at = _chunk_offset(bytes(data)) + 9 + 16  # opcode, length, start and end times
    struct.pack_into("<Q", data, at, size)
    out = path.with_name(f"declares-{size}.mcap")
    out.write_bytes(bytes(data))
    return out


def _crc_broken(path: Path) -> Path:
    data = bytearray(path.read_bytes())
    at = _chunk_offset(bytes(data))
    data[at + 9 + 40] ^= 0xFF  # a byte of the compressed records
    out = path.with_name("crc.mcap")
    out.write_bytes(bytes(data))
    return out


@pytest.mark.parametrize("declared", [CHUNK_SIZE_LIMIT + 1, 3 << 30])
def test_a_chunk_declaring_more_than_the_cap_is_refused_before_any_work(
    tmp_path: Path, declared: int
) -> None:
    good = tmp_path / "good.mcap"
    _recording(good)
    assert len(list(iter_messages(good, frozenset({"/robot/sip"})))) == 50
    bomb = _declaring(good, declared)
    # The peak of what Python allocated while refusing it (tracemalloc, not the process's
    # ru_maxrss: a worker that grew in an earlier test would hide any growth here).
    tracemalloc.start()
    try:
        with pytest.raises(RecordingError, match=f"declares {declared} bytes"):
            read_recording(bomb)
        with pytest.raises(SourceError, match=f"declares {declared} bytes"):
            list(iter_recording(bomb))
        _now, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 50 * 1024 * 1024  # nothing near the declared size was allocated


def test_calibrate_refuses_a_bad_chunk_crc_as_replay_does(tmp_path: Path) -> None:
    good = tmp_path / "good.mcap"
    _recording(good)
    broken = _crc_broken(good)
    with pytest.raises(RecordingError):
        read_recording(broken)
    with pytest.raises(SourceError, match="not a readable MCAP recording"):
        list(iter_recording(broken))
