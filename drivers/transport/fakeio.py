"""Real byte pipes for protocol-true fake devices: pseudo-terminals and loopback TCP.

A fake device is a pure "device side" object that receives bytes and writes bytes.
These ports connect it to a driver exactly as hardware would be connected: over a
real pty whose slave path the driver opens with pyserial, or over a loopback TCP
socket the driver reaches with a `socket://` URL (as with MobileSim or ser2net).

A port can hang up (the USB adapter is pulled) and come back: the pty variant keeps
a stable symlink (`link_path`) that it re-points at the new slave, as udev does with
/dev/serial/by-id names.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import tty
from collections.abc import Callable
from pathlib import Path

OnData = Callable[[bytes], None]


class PtyPort:
    """The device end of a pseudo-terminal; the driver opens `path`."""

    def __init__(self, on_data: OnData, link_path: str | os.PathLike[str] | None = None) -> None:
        self._on_data = on_data
        self._link = Path(link_path) if link_path is not None else None
        self._master: int | None = None
        self._slave: int | None = None
        self._slave_name = ""
        self._out = bytearray()
        self._loop: asyncio.AbstractEventLoop | None = None

    @property
    def path(self) -> str:
        """What a driver opens: the stable link if one was asked for, else the pty slave."""
        return str(self._link) if self._link is not None else self._slave_name

    @property
    def is_open(self) -> bool:
        return self._master is not None

    def open(self) -> str:
        """Create the pty (again, after a hang-up) and start reading. Returns `path`."""
        if self._master is not None:
            return self.path
        self._loop = asyncio.get_running_loop()
        master, slave = os.openpty()
        # Raw mode before any driver opens it: no echo, no line discipline, 8 bits clean.
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._slave_name = os.ttyname(slave)
        if self._link is not None:
            tmp = self._link.with_name(self._link.name + ".new")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(self._slave_name)
            tmp.replace(self._link)
        self._loop.add_reader(master, self._readable)
        return self.path

    def _readable(self) -> None:
        if self._master is None:
            return
        try:
            data = os.read(self._master, 65536)
        except BlockingIOError:
            return
        except OSError:
            # EIO: no process has the slave open right now; keep the port, wait for one.
            return
        if data:
            self._on_data(data)

    def write(self, data: bytes) -> None:
        """Send bytes to the driver; silently dropped while hung up (like a dead cable)."""
        if self._master is None or not data:
            return
        if self._out:
            self._out += data
            return
        try:
            n = os.write(self._master, data)
        except BlockingIOError:
            n = 0
        except OSError:
            return
        if n < len(data) and self._loop is not None:
            self._out += data[n:]
            self._loop.add_writer(self._master, self._writable)

    def _writable(self) -> None:
        if self._master is None or self._loop is None:
            return
        try:
            n = os.write(self._master, self._out)
        except BlockingIOError:
            return
        except OSError:
            self._out.clear()
            n = 0
        del self._out[:n]
        if not self._out:
            self._loop.remove_writer(self._master)

    def hang_up(self) -> None:
        """Close both ends, as a pulled USB adapter does. `open()` brings it back."""
        if self._master is None:
            return
        if self._loop is not None:
            self._loop.remove_reader(self._master)
            self._loop.remove_writer(self._master)
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None
        self._out.clear()
        if self._link is not None:
            with contextlib.suppress(FileNotFoundError):
                self._link.unlink()

    close = hang_up


class TcpPort:
    """A loopback TCP listener that serves one client at a time (the newest wins)."""

    def __init__(
        self,
        on_data: OnData,
        host: str = "127.0.0.1",
        port: int = 0,
        on_connect: Callable[[], None] | None = None,
    ) -> None:
        self._on_data = on_data
        self._on_connect = on_connect
        self.host = host
        self.port = port
        self._server: asyncio.Server | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._tasks: set[asyncio.Task[None]] = set()

    @property
    def url(self) -> str:
        return f"socket://{self.host}:{self.port}"

    @property
    def is_open(self) -> bool:
        return self._server is not None

    async def open(self) -> str:
        if self._server is None:
            self._server = await asyncio.start_server(self._client, self.host, self.port)
            self.port = self._server.sockets[0].getsockname()[1]
        return self.url

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._writer is not None:
            self._writer.close()
        self._writer = writer
        if self._on_connect is not None:
            self._on_connect()
        try:
            while data := await reader.read(65536):
                self._on_data(data)
        except (ConnectionError, OSError):
            pass
        finally:
            if self._writer is writer:
                self._writer = None
            writer.close()

    def write(self, data: bytes) -> None:
        if self._writer is not None and not self._writer.is_closing():
            self._writer.write(data)

    def drop_client(self) -> None:
        """Close the current connection (the bridge hung up); the listener stays."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    async def close(self) -> None:
        self.drop_client()
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None
