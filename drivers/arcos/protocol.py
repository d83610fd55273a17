"""The ARCOS byte layer: one asyncio protocol per open port.

`ArcosProtocol` owns what is about bytes on the line and nothing about the robot: the
receive buffer and packet decoder, a small queue of packets a waiting handshake asks
for, and the transmit side, two queues (urgent before normal) written no closer than
the 5 ms the ARCOS manual asks between commands. It also stamps the control latency
(a SIP's arrival to the wheel command it caused) at the moment that command is
written, and turns a transport that dies under a write into an immediate loss.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from collections.abc import Callable, Iterable

import structlog

from drivers.arcos.codec import Command, Decoder, Packet
from drivers.transport.clock import Clock
from drivers.transport.link import close_link

log = structlog.get_logger(__name__)

#: Command numbers whose write ends a control-latency measurement.
MOTION_COMMANDS = frozenset({int(Command.VEL), int(Command.RVEL), int(Command.VEL2)})
#: The robot may lose commands closer than 3-5 ms apart (AROS manual).
CMD_SPACING_S = 0.005
#: Packets kept for a waiting handshake; more means nobody is reading them.
RX_QUEUE_MAX = 64
#: How long close() waits for the port to report itself closed (an executor job).
CLOSE_WAIT_S = 0.5

OnPacket = Callable[[Packet], None]
OnLost = Callable[[Exception | None], None]


class ArcosProtocol(asyncio.Protocol):
    """Bytes in, packets out; paced packets in, bytes out."""

    def __init__(
        self,
        clock: Clock,
        on_packet: OnPacket,
        on_lost: OnLost,
        *,
        decoder: Decoder | None = None,
        stats: dict[str, int] | None = None,
    ) -> None:
        self.clock = clock
        self._on_packet = on_packet
        self._on_lost = on_lost
        self.transport: asyncio.Transport | None = None
        #: The owner's decoder and counters, so their counts outlive one port.
        self.decoder = decoder if decoder is not None else Decoder()
        self.stats = stats if stats is not None else {"bytes_tx": 0}
        #: perf_counter() when the bytes being decoded arrived (control latency's start).
        self.rx_perf = 0.0
        #: Packets for a handshake awaiting replies (`want_packets`), oldest first.
        self.want_packets = False
        self._rxq: deque[Packet] = deque(maxlen=RX_QUEUE_MAX)
        self._rx_event = asyncio.Event()
        self._lost: BaseException | None = None
        self._lost_reported = False
        self._closed = asyncio.Event()
        self._closing = False
        self.urgent: deque[bytes] = deque()
        self.normal: deque[tuple[int, bytes]] = deque()
        self._tx_event = asyncio.Event()
        #: While True nothing queued is written: the safe stop owns the line.
        self.held = False
        self.last_write_t = -math.inf
        #: perf_counter() of the SIP behind the pending wheel command, if any.
        self.latency_t0: float | None = None
        self.on_command_latency: Callable[[float], None] | None = None

    # ---- asyncio.Protocol

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        if isinstance(transport, asyncio.Transport):
            self.transport = transport

    def data_received(self, data: bytes) -> None:
        self.rx_perf = time.perf_counter()
        for pkt in self.decoder.feed(data):
            try:
                self._on_packet(pkt)
            except Exception:  # one bad packet must not kill the reader
                log.exception("robot_packet_handler_error", ptype=pkt.ptype)

    def connection_lost(self, exc: Exception | None) -> None:
        self._closed.set()
        self._lose(exc)

    # ---- receive side

    def offer(self, pkt: Packet) -> None:
        """Keep `pkt` for a handshake waiting in `next_packet`."""
        self._rxq.append(pkt)
        self._rx_event.set()

    def clear_rx(self) -> None:
        self._rxq.clear()

    async def next_packet(self, timeout_s: float) -> Packet:
        """The next offered packet within `timeout_s` clock seconds (TimeoutError if none).

        Raises the loss reason once the link is gone.
        """
        async with self.clock.timeout(timeout_s):
            while not self._rxq:
                if self._lost is not None:
                    raise self._lost
                self._rx_event.clear()
                await self._rx_event.wait()
        return self._rxq.popleft()

    def fail_waiters(self, reason: BaseException) -> None:
        """Wake a waiting `next_packet` with `reason` (the session ended)."""
        if self._lost is None:
            self._lost = reason
        self._rx_event.set()

    # ---- transmit side

    @property
    def writable(self) -> bool:
        tr = self.transport
        return tr is not None and not tr.is_closing()

    def write(self, data: bytes) -> None:
        """Write one packet now (no pacing); a dead transport is reported as lost at once."""
        tr = self.transport
        if tr is None or tr.is_closing():
            if tr is not None and not self._closing:
                self._lose(ConnectionError("serial transport closed under a write"))
            return
        tr.write(data)
        if tr.is_closing() and not self._closing:
            # pyserial-asyncio aborts the transport inside write() on a fatal error (EIO
            # from a vanished adapter) but reports connection_lost only after closing the
            # port in an executor: that can be long after the robot should have stopped.
            self._lose(ConnectionError("fatal write error on the serial transport"))
            return
        now = self.clock.now()
        self.last_write_t = now
        if self.latency_t0 is not None and len(data) > 3 and data[3] in MOTION_COMMANDS:
            latency_s, self.latency_t0 = time.perf_counter() - self.latency_t0, None
            if self.on_command_latency is not None:
                self.on_command_latency(latency_s)
        self.stats["bytes_tx"] += len(data)

    async def send_paced(self, data: bytes) -> None:
        self.write(data)
        await self.clock.sleep(CMD_SPACING_S)

    def queue_urgent(self, *packets: bytes) -> None:
        self.urgent.extend(packets)
        self._tx_event.set()

    def queue(self, cmd: int, packet: bytes) -> None:
        self.normal.append((cmd, packet))
        self._tx_event.set()

    def drop_queued(self, cmds: Iterable[int]) -> None:
        """Forget queued normal packets of these command numbers (superseded wishes)."""
        drop = frozenset(int(c) for c in cmds)
        if any(item[0] in drop for item in self.normal):
            self.normal = deque(item for item in self.normal if item[0] not in drop)

    def clear_tx(self) -> None:
        self.urgent.clear()
        self.normal.clear()

    def flush_now(self) -> None:
        """Write the head of the queue at once if the line is free.

        A wheel command caused by a SIP, or a stop, goes out from the caller's stack
        instead of waiting for the tx task's next turn behind whatever else the event
        loop has ready (HTTP requests under load): that wait was most of the control
        latency's tail. Safe whether or not the tx task is parked: it re-checks the
        spacing right before each of its own writes.
        """
        if self.held or self.clock.now() - self.last_write_t < CMD_SPACING_S:
            return
        if self.urgent:
            self.write(self.urgent.popleft())
        elif self.normal:
            self.write(self.normal.popleft()[1])

    async def tx_loop(self) -> None:
        """Write the queues, urgent first, spaced CMD_SPACING_S apart; runs until cancelled."""
        while True:
            while not (self.urgent or self.normal):
                self._tx_event.clear()
                await self._tx_event.wait()
            wait_s = self.last_write_t + CMD_SPACING_S - self.clock.now()
            if wait_s > 0 or self.held:
                await self.clock.sleep(max(wait_s, CMD_SPACING_S))
                continue
            self.write(self.urgent.popleft() if self.urgent else self.normal.popleft()[1])

    # ---- lifecycle

    def check_alive(self) -> None:
        """Report a transport that closed itself (a read error) without waiting for the port."""
        tr = self.transport
        if tr is not None and tr.is_closing() and not self._closing:
            self._lose(ConnectionError("serial transport closed by a read or write error"))

    def _lose(self, exc: Exception | None) -> None:
        if self._lost_reported:
            return
        self._lost_reported = True
        # The owner names the reason (usually via fail_waiters); this is the fallback.
        self._on_lost(exc)
        self.fail_waiters(ConnectionError(f"link lost: {exc or 'EOF'}"))

    async def close(self) -> None:
        """Close the port and wait (bounded) for it to report itself closed."""
        self._closing = True
        tr, self.transport = self.transport, None
        if tr is None:
            return
        # Drains what is queued (the CLOSE packet), and ends with the port closed even
        # when the transport's own background close never reports back.
        await close_link(tr, self._closed, timeout_s=CLOSE_WAIT_S)
