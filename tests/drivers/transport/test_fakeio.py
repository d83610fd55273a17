"""The byte pipes the fakes use: a real pty and a loopback socket, opened by the real link code."""

from __future__ import annotations

import asyncio

from drivers.transport.fakeio import PtyPort, TcpPort
from drivers.transport.link import open_link
from tests.support import until


class Collect(asyncio.Protocol):
    def __init__(self) -> None:
        self.data = bytearray()
        self.got = asyncio.Event()
        self.lost = asyncio.Event()

    def data_received(self, data: bytes) -> None:
        self.data += data
        self.got.set()

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost.set()


async def test_pty_round_trip_and_hang_up(tmp_path) -> None:
    received = bytearray()
    port = PtyPort(received.extend, link_path=tmp_path / "robot")
    path = port.open()
    transport, proto = await open_link(path, 9600, Collect)
    transport.write(b"\xfa\xfb\x00")
    port.write(bytes(range(256)))
    await until(lambda: len(proto.data) >= 256 and len(received) >= 3, "both directions delivered")
    assert bytes(proto.data) == bytes(range(256))  # raw: no CR/LF or 0x11/0x13 mangling
    assert bytes(received) == b"\xfa\xfb\x00"
    port.hang_up()
    async with asyncio.timeout(2):
        await proto.lost.wait()
    assert not (tmp_path / "robot").exists()
    port.open()
    transport2, proto2 = await open_link(port.path, 9600, Collect)
    port.write(b"back")
    async with asyncio.timeout(2):
        await proto2.got.wait()
    transport2.close()
    # pyserial-asyncio-fast flushes and closes the port in executor threads, then calls
    # connection_lost: on a loaded machine that takes more than a few loop turns, so
    # wait for it rather than leave its closing task to the leak check.
    async with asyncio.timeout(10):
        await proto2.lost.wait()
    port.close()


async def test_tcp_round_trip() -> None:
    received = bytearray()
    port = TcpPort(received.extend)
    url = await port.open()
    transport, proto = await open_link(url, 9600, Collect)
    transport.write(b"hello")
    await until(lambda: len(received) >= 5, "the driver's bytes at the device")
    port.write(b"world")
    async with asyncio.timeout(2):
        await proto.got.wait()
    assert bytes(proto.data) == b"world"
    transport.close()
    await port.close()
