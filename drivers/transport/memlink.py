"""In-memory byte links: a fake device served on `memory://NAME`, no file descriptor.

Unit tests connect a real driver (its real `asyncio.Protocol`) to a protocol-true fake
(its real byte parser) through a pair of in-memory transports instead of a pty or a
TCP socket. Every delivery is a loop callback (`call_soon`/`call_later`), never a
direct call, so the driver sees bytes arrive the way a real transport delivers them,
and the link works unchanged on a loop whose time is virtual.

A `MemoryPort` is the device end: it registers its name while open, and
`drivers.transport.link.open_link("memory://NAME", ...)` connects to it. `LinkFaults` makes the
line hostile in one direction: split writes (one byte at a time or random chunks),
injected garbage, dropped bytes, delay, and a write error on the next write.
"""

from __future__ import annotations

import asyncio
import random
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar

SCHEME = "memory://"

OnData = Callable[[bytes], None]
P = TypeVar("P", bound=asyncio.Protocol)


class MemoryLinkError(ConnectionError):
    """No fake is serving the asked `memory://` name (the cable is unplugged)."""


@dataclass(slots=True)
class LinkFaults:
    """How a line mangles the bytes written into it (one direction).

    `chunk_bytes` splits every write into pieces of at most that many bytes (1 = one
    byte per delivery); `random_chunks` splits at random points instead. `garbage_rate`
    is the probability that a delivery is preceded by 1-8 junk bytes, none of them in
    `garbage_avoid` (a header byte would make a decoder wait for a frame that never
    ends). `drop_rate` is the per-byte probability of a byte being lost. `delay_s` is
    the transit time of every delivery, in loop seconds; order is always kept.
    """

    chunk_bytes: int | None = None
    random_chunks: bool = False
    garbage_rate: float = 0.0
    garbage_avoid: frozenset[int] = frozenset()
    drop_rate: float = 0.0
    delay_s: float = 0.0
    seed: int | None = None
    rng: random.Random = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.chunk_bytes is not None and self.chunk_bytes < 1:
            raise ValueError(f"chunk_bytes must be >= 1, got {self.chunk_bytes!r}")
        for name, value in (("garbage_rate", self.garbage_rate), ("drop_rate", self.drop_rate)):
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {value!r}")
        if self.delay_s < 0:
            raise ValueError(f"delay_s must be >= 0, got {self.delay_s!r}")
        self.rng = random.Random(self.seed)

    def mangle(self, data: bytes) -> list[bytes]:
        """The deliveries that `data` becomes on this line (possibly none)."""
        rng = self.rng
        if self.drop_rate:
            data = bytes(b for b in data if rng.random() >= self.drop_rate)
        if self.garbage_rate and rng.random() < self.garbage_rate:
            allowed = [b for b in range(256) if b not in self.garbage_avoid]
            data = bytes(rng.choice(allowed) for _ in range(rng.randint(1, 8))) + data
        if not data:
            return []
        if self.chunk_bytes is not None:
            n = self.chunk_bytes
            return [data[i : i + n] for i in range(0, len(data), n)]
        if self.random_chunks and len(data) > 1:
            cuts = sorted(rng.sample(range(1, len(data)), rng.randint(1, min(4, len(data) - 1))))
            return [data[a:b] for a, b in zip([0, *cuts], [*cuts, len(data)], strict=True)]
        return [data]


class _Pipe:
    """One direction of a link: an ordered queue of deliveries, one timer at a time."""

    def __init__(
        self, loop: asyncio.AbstractEventLoop, sink: OnData, faults: LinkFaults | None
    ) -> None:
        self._loop = loop
        self._sink = sink
        self.faults = faults
        self._queue: deque[tuple[float, bytes]] = deque()
        self._handle: asyncio.Handle | asyncio.TimerHandle | None = None
        self._on_drained: Callable[[], None] | None = None
        self.closed = False

    def push(self, data: bytes) -> None:
        if self.closed or not data:
            return
        chunks = self.faults.mangle(data) if self.faults is not None else [data]
        due = self._loop.time() + (self.faults.delay_s if self.faults is not None else 0.0)
        for chunk in chunks:
            self._queue.append((due, chunk))
        self._schedule()

    def _schedule(self) -> None:
        if self._handle is not None or not self._queue or self.closed:
            return
        delay = self._queue[0][0] - self._loop.time()
        if delay > 0:
            self._handle = self._loop.call_later(delay, self._deliver)
        else:
            self._handle = self._loop.call_soon(self._deliver)

    def _deliver(self) -> None:
        # One chunk per loop turn: a split write really reaches the reader in pieces.
        self._handle = None
        if self.closed or not self._queue:
            return
        _, chunk = self._queue.popleft()
        self._sink(chunk)
        if not self._queue and self._on_drained is not None:
            callback, self._on_drained = self._on_drained, None
            callback()
        self._schedule()

    @property
    def pending(self) -> int:
        return sum(len(chunk) for _, chunk in self._queue)

    def after_drain(self, callback: Callable[[], None]) -> None:
        """Run `callback` once everything queued has been delivered (a clean close)."""
        if self.closed or not self._queue:
            self._loop.call_soon(callback)
        else:
            self._on_drained = callback

    def close(self) -> None:
        self.closed = True
        self._on_drained = None
        self._queue.clear()
        if self._handle is not None:
            self._handle.cancel()
            self._handle = None


class MemoryTransport(asyncio.Transport):
    """The driver's end of a `memory://` link; behaves as a serial transport does."""

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        port: MemoryPort,
        protocol: asyncio.Protocol,
        url: str,
    ) -> None:
        super().__init__(extra={"peername": url})
        self._loop = loop
        self._port = port
        self._protocol = protocol
        self._url = url
        self._closing = False
        self._lost_sent = False
        self._paused = False
        self._held: list[bytes] = []
        self._write_error: OSError | None = None
        #: device -> driver
        self.rx = _Pipe(loop, self._to_protocol, port.faults_to_driver)
        self.bytes_written = 0

    # -- asyncio.Transport

    def get_protocol(self) -> asyncio.BaseProtocol:
        return self._protocol

    def set_protocol(self, protocol: asyncio.BaseProtocol) -> None:
        if not isinstance(protocol, asyncio.Protocol):
            raise TypeError("a memory link needs a streaming asyncio.Protocol")
        self._protocol = protocol

    def is_closing(self) -> bool:
        return self._closing

    def is_reading(self) -> bool:
        return not self._paused and not self._closing

    def pause_reading(self) -> None:
        self._paused = True

    def resume_reading(self) -> None:
        if not self._paused:
            return
        self._paused = False
        held, self._held = self._held, []
        for chunk in held:
            self._protocol.data_received(chunk)

    def get_write_buffer_size(self) -> int:
        return 0

    def can_write_eof(self) -> bool:
        return False

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if self._closing:
            return
        if self._write_error is not None:
            # What serial_asyncio_fast does when write() raises: the transport dies and
            # connection_lost(exc) is called on the next loop turn.
            exc, self._write_error = self._write_error, None
            self._fatal(exc)
            return
        payload = bytes(data)
        self.bytes_written += len(payload)
        self._port.from_driver(payload)

    def close(self) -> None:
        """Close after the bytes already written reach the device (as a port flushes)."""
        if self._closing:
            return
        self._closing = True
        self.rx.close()
        self._port.driver_closing(self, None)

    def abort(self) -> None:
        self._fatal(None)

    # -- fault injection and the device side

    def fail_next_write(self, exc: OSError | None = None) -> None:
        """The next `write()` fails as a vanished USB port does (EIO)."""
        self._write_error = exc or OSError(5, "Input/output error")

    def _fatal(self, exc: Exception | None) -> None:
        if self._closing and self._lost_sent:
            return
        self._closing = True
        self.rx.close()
        self._port.driver_closing(self, exc, flush=False)

    def _to_protocol(self, chunk: bytes) -> None:
        if self._paused:
            self._held.append(chunk)
        else:
            self._protocol.data_received(chunk)

    def _deliver_lost(self, exc: Exception | None) -> None:
        if self._lost_sent:
            return
        self._lost_sent = True
        self._protocol.connection_lost(exc)

    def hang_up(self, exc: Exception | None) -> None:
        """The device end went away: nothing more arrives, the driver hears connection_lost."""
        self._closing = True
        self.rx.close()
        self._loop.call_soon(self._deliver_lost, exc)


_registry: dict[str, MemoryPort] = {}


class MemoryPort:
    """The device end of a `memory://NAME` link, serving one driver at a time (newest wins).

    The same shape as `drivers.transport.fakeio.PtyPort`: `on_data` gets the driver's bytes,
    `write()` sends bytes to the driver, `hang_up()` pulls the cable (the name
    disappears, so a reconnect fails until `open()` brings it back).
    """

    def __init__(
        self,
        on_data: OnData,
        name: str,
        *,
        on_connect: Callable[[], None] | None = None,
        on_disconnect: Callable[[], None] | None = None,
        faults_to_driver: LinkFaults | None = None,
        faults_to_device: LinkFaults | None = None,
    ) -> None:
        if not name or "/" in name:
            raise ValueError(f"a memory link name must be non-empty without '/', got {name!r}")
        self._on_data = on_data
        self.name = name
        self._on_connect = on_connect
        self._on_disconnect = on_disconnect
        self.faults_to_driver = faults_to_driver
        self.faults_to_device = faults_to_device
        self._open = False
        self._transport: MemoryTransport | None = None
        self._tx: _Pipe | None = None  # driver -> device, for the current connection
        self.connections = 0

    @property
    def url(self) -> str:
        return SCHEME + self.name

    path = url

    @property
    def is_open(self) -> bool:
        return self._open

    @property
    def transport(self) -> MemoryTransport | None:
        """The driver's transport of the current connection (to inject faults into)."""
        return self._transport

    def open(self) -> str:
        """Start serving (again, after a hang-up). Returns the URL a driver opens."""
        owner = _registry.get(self.name)
        if owner is not None and owner is not self:
            raise ValueError(f"{self.url} is already served by another port")
        _registry[self.name] = self
        self._open = True
        return self.url

    def write(self, data: bytes) -> None:
        """Send bytes to the driver; silently dropped while nobody is connected."""
        tr = self._transport
        if tr is not None and data and not tr.is_closing():
            tr.rx.push(bytes(data))

    def hang_up(self) -> None:
        """Pull the cable: the driver's transport is lost, the name stops resolving."""
        if _registry.get(self.name) is self:
            del _registry[self.name]
        self._open = False
        self._drop(ConnectionResetError(f"{self.url} hung up"))

    close = hang_up

    def drop_client(self) -> None:
        """End the current connection only (the port keeps serving)."""
        self._drop(ConnectionResetError(f"{self.url} dropped the connection"))

    def _drop(self, exc: Exception) -> None:
        tr, self._transport = self._transport, None
        if self._tx is not None:
            self._tx.close()
            self._tx = None
        if tr is not None:
            tr.hang_up(exc)
            if self._on_disconnect is not None:
                self._on_disconnect()

    # -- called by the transport and open_link

    def connect(
        self, loop: asyncio.AbstractEventLoop, protocol: asyncio.Protocol
    ) -> MemoryTransport:
        if not self._open:
            raise MemoryLinkError(f"nothing is serving {self.url}")
        if self._transport is not None:
            self.drop_client()
        transport = MemoryTransport(loop, self, protocol, self.url)
        self._transport = transport
        self._tx = _Pipe(loop, self._on_data, self.faults_to_device)
        self.connections += 1
        if self._on_connect is not None:
            self._on_connect()
        return transport

    def from_driver(self, data: bytes) -> None:
        if self._tx is not None:
            self._tx.push(data)

    def driver_closing(
        self, transport: MemoryTransport, exc: Exception | None, *, flush: bool = True
    ) -> None:
        loop = transport._loop
        if transport is not self._transport:
            loop.call_soon(transport._deliver_lost, exc)
            return
        tx, self._tx, self._transport = self._tx, None, None

        def finish() -> None:
            if tx is not None:
                tx.close()
            transport._deliver_lost(exc)
            if self._on_disconnect is not None:
                self._on_disconnect()

        if tx is not None and flush:
            tx.after_drain(finish)
        else:
            loop.call_soon(finish)


def lookup(url: str) -> MemoryPort:
    """The port serving `url` (`memory://NAME`); MemoryLinkError if none is."""
    name = url[len(SCHEME) :] if url.startswith(SCHEME) else url
    port = _registry.get(name)
    if port is None or not port.is_open:
        raise MemoryLinkError(f"nothing is serving {SCHEME}{name}")
    return port


async def open_memory_link(
    url: str, protocol_factory: Callable[[], P]
) -> tuple[MemoryTransport, P]:
    """Connect `protocol_factory()` to the fake serving `url`, as `open_link` does for ports."""
    loop = asyncio.get_running_loop()
    port = lookup(url)
    protocol = protocol_factory()
    transport = port.connect(loop, protocol)
    # A real transport calls connection_made on a later loop turn; so does this one.
    loop.call_soon(protocol.connection_made, transport)
    # Give connection_made its turn before the caller writes, as create_connection does.
    await asyncio.sleep(0)
    return transport, protocol
