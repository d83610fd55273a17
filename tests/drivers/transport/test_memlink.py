"""The in-memory link: ordering, faults, close and hang-up semantics, open_link routing."""

from __future__ import annotations

import asyncio

import pytest

from drivers.transport.link import LinkError, open_link
from drivers.transport.memlink import LinkFaults, MemoryPort
from tests.support import until

pytestmark = pytest.mark.virtual_time

PAYLOAD = bytes(range(40))


class Recorder(asyncio.Protocol):
    def __init__(self) -> None:
        self.chunks: list[bytes] = []
        self.made = False
        self.lost: list[Exception | None] = []

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.made = True

    def data_received(self, data: bytes) -> None:
        self.chunks.append(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost.append(exc)


async def test_bytes_flow_both_ways_in_order() -> None:
    got = bytearray()
    port = MemoryPort(got.extend, "flow")
    url = port.open()
    try:
        transport, proto = await open_link(url, 9600, Recorder)
        assert proto.made
        transport.write(b"abc")
        transport.write(b"def")
        port.write(b"xyz")
        # Nothing is delivered from the writer's stack: only on a later loop turn.
        assert got == b"" and proto.chunks == []
        await until(lambda: got == b"abcdef" and b"".join(proto.chunks) == b"xyz", "delivery")
        transport.close()
        await until(lambda: proto.lost == [None], "connection_lost")
    finally:
        port.close()


async def test_unserved_name_is_a_link_error() -> None:
    with pytest.raises(LinkError, match="memory://nobody"):
        await open_link("memory://nobody", 9600, Recorder)


async def test_one_byte_chunks_and_random_chunks_keep_the_stream() -> None:
    for faults in (LinkFaults(chunk_bytes=1), LinkFaults(random_chunks=True, seed=3)):
        port = MemoryPort(lambda _d: None, "split", faults_to_driver=faults)
        url = port.open()
        try:
            _, proto = await open_link(url, 9600, Recorder)
            port.write(PAYLOAD)
            await until(lambda p=proto: b"".join(p.chunks) == PAYLOAD, "the payload")  # type: ignore[misc]
            assert len(proto.chunks) > 1
            if faults.chunk_bytes == 1:
                assert all(len(c) == 1 for c in proto.chunks)
        finally:
            port.close()


async def test_garbage_drop_and_delay() -> None:
    port = MemoryPort(
        lambda _d: None,
        "hostile",
        faults_to_driver=LinkFaults(garbage_rate=1.0, garbage_avoid=frozenset({0xFA}), seed=1),
    )
    url = port.open()
    try:
        _, proto = await open_link(url, 9600, Recorder)
        port.write(b"\xfa\xfb")
        await until(lambda: b"".join(proto.chunks).endswith(b"\xfa\xfb"), "the packet")
        data = b"".join(proto.chunks)
        assert len(data) > 2 and 0xFA not in data[:-2]
    finally:
        port.close()

    port = MemoryPort(lambda _d: None, "lossy", faults_to_driver=LinkFaults(drop_rate=0.5, seed=2))
    url = port.open()
    try:
        _, proto = await open_link(url, 9600, Recorder)
        port.write(bytes(200))
        port.write(b"!")
        await asyncio.sleep(0.01)
        assert 0 < len(b"".join(proto.chunks)) < 201
    finally:
        port.close()

    port = MemoryPort(lambda _d: None, "slow", faults_to_driver=LinkFaults(delay_s=0.05))
    url = port.open()
    try:
        loop = asyncio.get_running_loop()
        _, proto = await open_link(url, 9600, Recorder)
        t0 = loop.time()
        port.write(b"late")
        await until(lambda: proto.chunks, "the delayed bytes")
        assert loop.time() - t0 >= 0.05 - 1e-6
    finally:
        port.close()


async def test_close_flushes_what_was_written_then_reports_lost() -> None:
    got = bytearray()
    disconnects: list[int] = []
    port = MemoryPort(
        got.extend,
        "flush",
        on_disconnect=lambda: disconnects.append(1),
        faults_to_device=LinkFaults(chunk_bytes=1),
    )
    url = port.open()
    try:
        transport, proto = await open_link(url, 9600, Recorder)
        transport.write(b"CLOSE")
        transport.close()
        transport.write(b"late")  # ignored: the transport is closing
        await until(lambda: proto.lost, "connection_lost")
        assert got == b"CLOSE" and disconnects == [1]
    finally:
        port.close()


async def test_hang_up_loses_the_connection_and_the_name() -> None:
    port = MemoryPort(lambda _d: None, "plug")
    url = port.open()
    transport, proto = await open_link(url, 9600, Recorder)
    port.hang_up()
    await until(lambda: proto.lost, "connection_lost")
    assert isinstance(proto.lost[0], ConnectionResetError)
    assert transport.is_closing()
    with pytest.raises(LinkError):
        await open_link(url, 9600, Recorder)
    port.open()
    transport2, proto2 = await open_link(url, 9600, Recorder)
    transport2.close()
    await until(lambda: proto2.lost, "second connection_lost")
    port.close()


async def test_write_error_kills_the_transport_at_once() -> None:
    port = MemoryPort(lambda _d: None, "eio")
    url = port.open()
    try:
        transport, proto = await open_link(url, 9600, Recorder)
        port_transport = port.transport
        assert port_transport is transport
        port_transport.fail_next_write()
        transport.write(b"x")
        assert transport.is_closing()
        await until(lambda: proto.lost, "connection_lost")
        assert isinstance(proto.lost[0], OSError)
    finally:
        port.close()


async def test_a_second_client_replaces_the_first() -> None:
    port = MemoryPort(lambda _d: None, "newest")
    url = port.open()
    try:
        _, first = await open_link(url, 9600, Recorder)
        _, second = await open_link(url, 9600, Recorder)
        await until(lambda: first.lost, "the first connection to be dropped")
        port.write(b"hi")
        await until(lambda: second.chunks, "bytes on the second")
        assert first.chunks == []
    finally:
        port.close()


def test_fault_parameters_are_checked() -> None:
    with pytest.raises(ValueError):
        LinkFaults(chunk_bytes=0)
    with pytest.raises(ValueError):
        LinkFaults(drop_rate=1.5)
    with pytest.raises(ValueError):
        LinkFaults(delay_s=-1)
    with pytest.raises(ValueError):
        MemoryPort(lambda _d: None, "a/b")
