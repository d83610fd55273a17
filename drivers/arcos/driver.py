"""ArcosRobot: the asyncio client for a Pioneer P3-AT (ARCOS/AROS, MobileSim) link.

One `run()` task owns the port: open, SYNC0/1/2 handshake (old-session recovery and
baud cycling), OPEN, CONFIG, SONAR and ENABLE (only when wished), then reads SIPs and
reflects the wished wheel speeds as VEL + RVEL (re-sent on change and every 500 ms,
PULSE when idle, the robot's 2 s watchdog is never reached). Silence marks the robot
`stale`; EOF, device errors, a controller reset or long silence end the session and
it reconnects with capped backoff. Cancel or `shutdown()` stops the wheels, disables
the motors and CLOSEs before the port is closed.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections import deque
from collections.abc import Callable

import structlog

from drivers.arcos.codec import (
    CLOSE,
    OPEN,
    PULSE,
    RESET_TYPES,
    SIP_TYPES,
    CodecError,
    Command,
    Decoder,
    Packet,
    PacketType,
    encode_command,
)
from drivers.arcos.sip import (
    ConvFactors,
    Odometry,
    RobotConfig,
    RobotIdentity,
    Sip,
    conv_factors,
    decode_config,
    decode_identity,
    decode_raw_sip,
    sip_from_raw,
    wheel_to_vel_rvel,
)
from drivers.arcos.sonar import SonarRing
from drivers.backoff import Backoff
from drivers.clock import REAL_CLOCK, Clock
from drivers.health import DeviceHealth, LinkState
from drivers.link import LinkError, open_link, set_baudrate, wait_before_retry

log = structlog.get_logger(__name__)

#: Command numbers whose write ends a control-latency measurement.
MOTION_COMMANDS = frozenset({int(Command.VEL), int(Command.RVEL), int(Command.VEL2)})

#: The robot may lose commands closer than 3-5 ms apart (AROS manual; doc pitfall 16).
CMD_SPACING_S = 0.005
#: ARIA StateReflectionRefreshTime: re-send motion / PULSE at least this often.
REFRESH_S = 0.5
SIP_CYCLE_S = 0.1
STANDARD_BAUDS = (9600, 115200, 38400, 19200, 57600)

Listener = Callable[[Sip], None]


class ArcosError(Exception):
    """Base of the driver's own errors; messages are meant for an operator."""


class HandshakeError(ArcosError):
    """The robot never completed SYNC0/1/2."""


class SessionLost(ArcosError):
    """The session ended: EOF, device error, controller reset or silence."""


class NotConnected(ArcosError):
    """An operation needs an open session."""


class _Link(asyncio.Protocol):
    """Forwards the port's bytes and its loss to the robot object."""

    def __init__(self, robot: ArcosRobot) -> None:
        self._robot = robot

    def data_received(self, data: bytes) -> None:
        self._robot._on_bytes(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self._robot._on_link_lost(exc)


class ArcosRobot:
    """A P3-AT base over a serial path or `socket://host:port` (see docs/ARCHITECTURE.md)."""

    def __init__(self, url: str, baud: int = 9600, *, clock: Clock = REAL_CLOCK,
                 subclass_override: str | None = None, lost_after_s: float = 0.5,
                 enable_motors: bool = False, drop_after_s: float = 4.0,
                 sync_timeout_s: float = 1.0, max_misses: int = 10,
                 backoff: Backoff | None = None) -> None:
        self.url = url
        self.baud = baud
        self.clock = clock
        self.subclass_override = subclass_override
        self.lost_after_s = lost_after_s
        self.drop_after_s = max(drop_after_s, lost_after_s)
        self.sync_timeout_s = sync_timeout_s
        self.max_misses = max_misses
        self.backoff = backoff or Backoff(initial_s=0.2, maximum_s=5.0)

        self.connected = False
        self.stale = True
        self.identity: RobotIdentity | None = None
        self.config: RobotConfig | None = None
        self.factors: ConvFactors | None = None
        self.current_baud: int | None = None
        self.last_sip: Sip | None = None
        self.last_error: str | None = None
        self.sonar = SonarRing()
        self.odometry = Odometry()

        self._motors_wish = enable_motors
        self._wheels: tuple[float, float] = (0.0, 0.0)
        self._listeners: list[Listener] = []
        #: Called with the seconds from a SIP's bytes arriving to the wheel command it
        #: caused being written (SPEC 6's control latency), measured on the host's
        #: performance counter, not the clock: it is real time even in the simulator.
        self.on_command_latency: Callable[[float], None] | None = None
        self._rx_perf = 0.0
        self._in_sip: float | None = None  # rx time of the SIP whose listeners are running
        self._latency_t0: float | None = None  # rx time of the SIP behind the pending command
        self._decoder = Decoder()
        self._stats = {"bytes_tx": 0, "sips": 0, "reconnects": 0, "old_sessions": 0,
                       "handshake_failures": 0, "link_errors": 0, "bad_sips": 0,
                       "listener_errors": 0, "sessions": 0}

        self._transport: asyncio.Transport | None = None
        self._opened = False
        self._opened_t = 0.0
        self._last_sip_t: float | None = None
        self._want_packets = False
        self._rxq: deque[Packet] = deque(maxlen=64)
        self._rx_event = asyncio.Event()
        self._lost_event = asyncio.Event()
        self._lost_reason: ArcosError | None = None
        self._port_closed = asyncio.Event()
        self._urgent: deque[bytes] = deque()
        self._normal: deque[tuple[int, bytes]] = deque()
        self._tx_event = asyncio.Event()
        self._wake = asyncio.Event()
        self._sent_motion: tuple[int, int] | None = None
        self._motion_t = -math.inf
        self._any_tx_t = -math.inf
        self._last_write_t = -math.inf  # clock time of the last write, for command spacing
        #: The safe stop owns the line: no queued or reflected command may slip in
        #: between its VEL 0, ENABLE 0 and CLOSE. Cleared when a new session opens.
        self._safe_stopping = False
        self._closing = False
        self._closed = asyncio.Event()
        self._fail_streak = 0
        self._good_baud: int | None = None

    # ------------------------------------------------------------------ public API

    @property
    def counters(self) -> dict[str, int]:
        return {**self._decoder.counters(), **self._stats}

    def health(self) -> DeviceHealth:
        """The robot link's health now (see drivers.health)."""
        if self._closing:
            state = LinkState.CLOSED
        elif self.connected:
            state = LinkState.STALE if self.stale else LinkState.UP
        else:
            state = LinkState.DOWN if self._fail_streak else LinkState.CONNECTING
        counters = self.counters
        return DeviceHealth(
            device="robot", state=state, last_error=self.last_error,
            errors=sum(v for k, v in counters.items() if k.endswith(("errors", "resyncs"))),
            reconnects=counters["reconnects"],
            last_rx_t=self.last_sip.t if self.last_sip is not None else None,
            counters=counters)

    @property
    def motors_wish(self) -> bool:
        return self._motors_wish

    @property
    def wheels_wish(self) -> tuple[float, float]:
        return self._wheels

    def add_listener(self, cb: Listener) -> Callable[[], None]:
        """Call `cb(sip)` synchronously on every decoded SIP; returns the unsubscribe."""
        self._listeners.append(cb)

        def remove() -> None:
            with contextlib.suppress(ValueError):
                self._listeners.remove(cb)

        return remove

    def set_wheels(self, left_mm_s: float, right_mm_s: float) -> None:
        """Wish for these wheel speeds; reflected as VEL + RVEL within one tick."""
        if not (math.isfinite(left_mm_s) and math.isfinite(right_mm_s)):
            raise ValueError(f"wheel speeds must be finite, got {left_mm_s!r}, {right_mm_s!r}")
        wish = (float(left_mm_s), float(right_mm_s))
        if wish != self._wheels and self._in_sip is not None:
            self._latency_t0 = self._in_sip
        self._wheels = wish
        if self._opened:
            # Queue the command now rather than on the tick task's next turn, and write
            # it at once if the line is free: a wheel command follows the SIP that
            # caused it with as little delay as possible.
            self._reflect(self.clock.now())
            self._flush_now()
        self._wake.set()

    def stop(self) -> None:
        """Wheels to zero now: VEL 0 + RVEL 0 ahead of anything queued."""
        if self._wheels != (0.0, 0.0) and self._in_sip is not None:
            self._latency_t0 = self._in_sip
        self._wheels = (0.0, 0.0)
        self._normal = deque(item for item in self._normal
                             if item[0] not in (Command.VEL, Command.RVEL, Command.VEL2))
        if self._opened:
            vel0, rvel0 = encode_command(Command.VEL, 0), encode_command(Command.RVEL, 0)
            # Idempotent: a stop still waiting to be written is not queued twice, so a
            # caller that asserts "stopped" on every tick cannot grow the queue.
            if not (vel0 in self._urgent and rvel0 in self._urgent):
                self._queue_urgent(vel0, rvel0)
                self._flush_now()
            self._sent_motion = (0, 0)
            self._motion_t = self.clock.now()

    def estop(self) -> None:
        """E_STOP (overrides deceleration) ahead of anything queued; the wish becomes zero."""
        self._wheels = (0.0, 0.0)
        self._normal.clear()
        if self._opened:
            self._queue_urgent(encode_command(Command.E_STOP))
            self._flush_now()
            self._sent_motion = (0, 0)
            self._motion_t = self.clock.now()

    def enable_motors(self, on: bool) -> None:
        """Remember the wish (re-applied on every reconnect) and send ENABLE now if open."""
        self._motors_wish = bool(on)
        if not self._opened:
            return
        if on:
            self._normal.append((Command.ENABLE, encode_command(Command.ENABLE, 1)))
            self._tx_event.set()
        else:
            self._queue_urgent(encode_command(Command.ENABLE, 0))

    async def connect(self) -> RobotIdentity:
        """Open the port and run the handshake once. Raises LinkError or HandshakeError."""
        if self._transport is not None and self._opened and self.identity is not None:
            return self.identity
        self._lost_event = asyncio.Event()
        self._lost_reason = None
        self._port_closed = asyncio.Event()
        self._rxq.clear()
        self._decoder.reset()
        self._urgent.clear()
        self._normal.clear()
        self._safe_stopping = False
        transport, _ = await open_link(self.url, self.baud, lambda: _Link(self))
        self._transport = transport
        self.current_baud = self.baud
        try:
            identity = await self._handshake()
            await self._open_session(identity)
        except BaseException:
            # Cancelled after OPEN went out: the robot must still hear ENABLE 0 and CLOSE.
            await self._safe_stop()
            raise
        return identity

    async def run(self) -> None:
        """Keep a session up until cancelled or shut down. Never raises but CancelledError."""
        first = True
        try:
            while not self._closing:
                try:
                    if self._transport is None or not self._opened:
                        await self.connect()
                    if not first:
                        self._stats["reconnects"] += 1
                    first = False
                    self._fail_streak = 0
                    self.backoff.reset()
                    await self._serve()
                except (ArcosError, LinkError, OSError, CodecError) as exc:
                    if self._closing:
                        break  # shutdown() closed the port under the session: not a failure
                    self._note_failure(exc)
                except Exception as exc:  # a driver bug must not end the task
                    log.exception("robot_unexpected_error", url=self.url)
                    self._note_failure(exc)
                if self._closing:
                    break
                # Not on cancel: the port stays open for the safe stop below.
                self._opened = False
                self.connected = False
                self.stale = True
                await self._close_port()
                # A replugged adapter is retried at once (wait_before_retry), not after
                # the backoff that grew while it was away.
                await wait_before_retry(self.url, self.backoff.next_delay(), self.clock, self._closed)
        except asyncio.CancelledError:
            await self._safe_stop()
            raise

    async def shutdown(self) -> None:
        """Wheels 0, ENABLE 0, CLOSE, close the port; stops `run()`. Idempotent."""
        self._closing = True
        self._closed.set()
        await self._safe_stop()

    # ------------------------------------------------------------------ session

    async def _handshake(self) -> RobotIdentity:
        is_serial = not self.url.startswith(("socket://", "rfc2217://"))
        # The configured rate first, then the last rate that worked, then the standard ones.
        first = [self.baud] if self._good_baud in (None, self.baud) else [self.baud, self._good_baud]
        bauds = first + [b for b in STANDARD_BAUDS if b not in first] if is_serial else [self.baud]
        baud_i = 0
        misses = misses_here = sent = 0
        state = 0
        self._want_packets = True
        try:
            while True:
                sent += 1
                if sent > 6 * self.max_misses:
                    raise HandshakeError(f"robot at {self.url}: no handshake after {sent - 1} SYNC packets")
                self._rxq.clear()
                self._write(encode_command(state))
                try:
                    pkt = await self._next_packet(self.sync_timeout_s)
                except TimeoutError:
                    misses += 1
                    misses_here += 1
                    if misses >= self.max_misses:
                        self._stats["handshake_failures"] += 1
                        tried = ", ".join(str(b) for b in bauds) if is_serial else "tcp"
                        raise HandshakeError(
                            f"robot at {self.url} never answered SYNC{state} "
                            f"({misses} tries; baud {tried})") from None
                    if len(bauds) > 1 and misses_here >= 2:
                        baud_i = (baud_i + 1) % len(bauds)
                        misses_here = 0
                        assert self._transport is not None
                        set_baudrate(self._transport, bauds[baud_i])
                        self.current_baud = bauds[baud_i]
                        log.info("robot_baud_cycle", url=self.url, baud=bauds[baud_i])
                    state = 0
                    continue
                if pkt.ptype == state:
                    if state < 2:
                        state += 1
                        continue
                    try:
                        identity = decode_identity(pkt.payload)
                        self._good_baud = bauds[baud_i]
                        return identity
                    except CodecError as exc:
                        log.warning("robot_bad_sync2", url=self.url, error=str(exc))
                        state = 0
                        continue
                if pkt.ptype in SIP_TYPES:
                    # Still in a session someone never closed: CLOSE it, then start over.
                    self._stats["old_sessions"] += 1
                    log.info("robot_old_session", url=self.url)
                    await self._close_old_session()
                else:
                    log.debug("robot_unexpected_sync_reply", ptype=pkt.ptype, state=state)
                state = 0
        finally:
            self._want_packets = False

    async def _close_old_session(self) -> None:
        self._write(encode_command(CLOSE, 1))
        end = self.clock.now() + 0.2
        closes = 1
        while (remaining := end - self.clock.now()) > 0:
            try:
                pkt = await self._next_packet(remaining)
            except TimeoutError:
                break
            if pkt.ptype in SIP_TYPES and closes < 5:
                self._write(encode_command(CLOSE, 1))
                closes += 1
        await self.clock.sleep(SIP_CYCLE_S)

    async def _open_session(self, identity: RobotIdentity) -> None:
        self.identity = identity
        subclass = self.subclass_override or identity.subclass
        self.factors = conv_factors(subclass)
        await self.clock.sleep(SIP_CYCLE_S)
        self.odometry.new_session()
        self._last_sip_t = None
        self._opened = True
        self._opened_t = self.clock.now()
        self._sent_motion = None
        await self._send_paced(encode_command(OPEN, 1))
        self._want_packets = True
        try:
            await self._send_paced(encode_command(Command.CONFIG, 1))
            end = self.clock.now() + 1.0
            while (remaining := end - self.clock.now()) > 0:
                try:
                    pkt = await self._next_packet(remaining)
                except TimeoutError:
                    break
                if pkt.ptype == PacketType.CONFIG:
                    try:
                        self.config = decode_config(pkt.payload)
                    except CodecError as exc:
                        log.warning("robot_bad_config", error=str(exc))
                    break
        finally:
            self._want_packets = False
        await self._send_paced(encode_command(Command.SONAR, 1))
        if self._motors_wish:
            await self._send_paced(encode_command(Command.ENABLE, 1))
        self.connected = True
        self._stats["sessions"] += 1
        log.info("robot_connected", url=self.url, name=identity.name, robot_class=identity.robot_class,
                 subclass=identity.subclass, odometry_subclass=subclass, baud=self.current_baud,
                 motors=self._motors_wish,
                 watchdog_ms=self.config.watchdog_ms if self.config else None)

    async def _serve(self) -> None:
        tasks = {asyncio.create_task(self._tx_loop(), name="arcos-tx"),
                 asyncio.create_task(self._tick_loop(), name="arcos-tick")}
        try:
            await self._lost_event.wait()
        finally:
            for task in tasks:
                task.cancel()
            for task in tasks:
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        raise self._lost_reason or SessionLost("session ended")

    async def _tx_loop(self) -> None:
        while True:
            while not (self._urgent or self._normal):
                self._tx_event.clear()
                await self._tx_event.wait()
            # Commands are spaced as the ARCOS manual asks, counting one written
            # directly by _flush_now too.
            wait_s = self._last_write_t + CMD_SPACING_S - self.clock.now()
            if wait_s > 0 or self._safe_stopping:
                await self.clock.sleep(max(wait_s, CMD_SPACING_S))
                continue
            data = self._urgent.popleft() if self._urgent else self._normal.popleft()[1]
            self._write(data)

    def _flush_now(self) -> None:
        """Write the head of the queue at once if the line is free.

        A wheel command caused by a SIP, or a stop, goes out from the caller's stack
        instead of waiting for the tx task's next turn behind whatever else the event
        loop has ready (HTTP requests under load): that wait was most of the control
        latency's tail.
        """
        # Safe whether or not the tx task is parked: it re-checks the spacing against
        # _last_write_t right before each of its own writes.
        if not self._opened or self._safe_stopping:
            return
        if self.clock.now() - self._last_write_t < CMD_SPACING_S:
            return
        if self._urgent:
            self._write(self._urgent.popleft())
        elif self._normal:
            self._write(self._normal.popleft()[1])

    async def _tick_loop(self) -> None:
        tick = min(0.05, self.lost_after_s / 5.0)
        while True:
            now = self.clock.now()
            since = now - (self._last_sip_t if self._last_sip_t is not None else self._opened_t)
            if since > self.lost_after_s and not self.stale:
                self.stale = True
                log.warning("robot_stale", url=self.url, silent_s=round(since, 3))
            if since > self.drop_after_s:
                self._end_session(SessionLost(f"no SIP from {self.url} for {self.drop_after_s:g} s"))
                return
            self._reflect(now)
            with contextlib.suppress(TimeoutError):
                async with self.clock.timeout(tick):
                    await self._wake.wait()
            self._wake.clear()

    def _reflect(self, now: float) -> None:
        """ARIA state reflection: VEL+RVEL on change or every 500 ms while moving, else PULSE."""
        if self._safe_stopping:
            return
        motion = wheel_to_vel_rvel(*self._wheels)
        due = now - self._motion_t >= REFRESH_S
        if motion != self._sent_motion or (motion != (0, 0) and due):
            self._normal = deque(item for item in self._normal
                                 if item[0] not in (Command.VEL, Command.RVEL, PULSE))
            self._normal.append((Command.VEL, encode_command(Command.VEL, motion[0])))
            self._normal.append((Command.RVEL, encode_command(Command.RVEL, motion[1])))
            self._tx_event.set()
            self._sent_motion = motion
            self._motion_t = now
        elif now - self._any_tx_t >= REFRESH_S and not self._normal:
            self._normal.append((PULSE, encode_command(PULSE)))
            self._tx_event.set()
            self._any_tx_t = now

    # ------------------------------------------------------------------ I/O plumbing

    def _queue_urgent(self, *packets: bytes) -> None:
        self._urgent.extend(packets)
        self._tx_event.set()

    def _write(self, data: bytes) -> None:
        tr = self._transport
        if tr is None or tr.is_closing():
            return
        tr.write(data)
        self._last_write_t = self.clock.now()
        if self._latency_t0 is not None and len(data) > 3 and data[3] in MOTION_COMMANDS:
            latency_s, self._latency_t0 = time.perf_counter() - self._latency_t0, None
            if self.on_command_latency is not None:
                self.on_command_latency(latency_s)
        self._stats["bytes_tx"] += len(data)
        self._any_tx_t = self.clock.now()

    async def _send_paced(self, data: bytes) -> None:
        self._write(data)
        await self.clock.sleep(CMD_SPACING_S)

    async def _next_packet(self, timeout_s: float) -> Packet:
        async with self.clock.timeout(timeout_s):
            while not self._rxq:
                if self._lost_event.is_set():
                    raise self._lost_reason or SessionLost("link lost")
                self._rx_event.clear()
                await self._rx_event.wait()
        return self._rxq.popleft()

    def _on_bytes(self, data: bytes) -> None:
        self._rx_perf = time.perf_counter()
        for pkt in self._decoder.feed(data):
            try:
                self._on_packet(pkt)
            except Exception:  # one bad packet must not kill the reader
                log.exception("robot_packet_handler_error", ptype=pkt.ptype)

    def _on_packet(self, pkt: Packet) -> None:
        if pkt.ptype in RESET_TYPES:
            self._end_session(SessionLost(f"controller reset (packet type 0x{pkt.ptype:02X})"))
            return
        if self._opened and pkt.ptype in SIP_TYPES:
            self._handle_sip(pkt)
            if not self._want_packets:
                return
        if self._want_packets:
            self._rxq.append(pkt)
            self._rx_event.set()

    def _handle_sip(self, pkt: Packet) -> None:
        try:
            raw = decode_raw_sip(pkt.ptype, pkt.payload)
        except CodecError as exc:
            self._stats["bad_sips"] += 1
            self.last_error = f"bad SIP: {exc}"
            return
        assert self.factors is not None
        now = self.clock.now()
        self.odometry.update(raw, self.factors)
        sip = sip_from_raw(raw, self.odometry, now, self.factors)
        self.sonar.update(sip.sonar, now)
        self.last_sip = sip
        self._last_sip_t = now
        if self.stale and self.connected:
            log.info("robot_fresh", url=self.url)
        self.stale = False
        self._stats["sips"] += 1
        self._in_sip = self._rx_perf
        try:
            for cb in tuple(self._listeners):
                try:
                    cb(sip)
                except Exception:  # a listener bug must not stop odometry
                    self._stats["listener_errors"] += 1
                    log.exception("robot_listener_error")
        finally:
            self._in_sip = None

    def _on_link_lost(self, exc: Exception | None) -> None:
        self._port_closed.set()
        self._end_session(SessionLost(f"link to {self.url} lost: {exc or 'EOF'}"))

    def _end_session(self, reason: ArcosError) -> None:
        if not self._lost_event.is_set():
            self._lost_reason = reason
            self._lost_event.set()
            self._rx_event.set()

    def _note_failure(self, exc: BaseException) -> None:
        self.last_error = str(exc) or type(exc).__name__
        if isinstance(exc, LinkError | OSError):
            self._stats["link_errors"] += 1
        self._fail_streak += 1
        if self._fail_streak == 1:
            log.warning("robot_session_failed", url=self.url, error=self.last_error)
        else:
            log.debug("robot_session_failed", url=self.url, error=self.last_error,
                      streak=self._fail_streak)

    async def _safe_stop(self) -> None:
        """Wheels 0, ENABLE 0, CLOSE (paced, ~20 ms), then close the port."""
        self._safe_stopping = True
        self._urgent.clear()
        self._normal.clear()
        self._wheels = (0.0, 0.0)
        tr = self._transport
        if tr is not None and self._opened and not tr.is_closing():
            for data in (encode_command(Command.VEL, 0), encode_command(Command.RVEL, 0),
                         encode_command(Command.ENABLE, 0), encode_command(CLOSE, 1)):
                self._write(data)
                # A paced write must not hold up a cancelled task: bound the whole sequence.
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(0.04):
                        await self.clock.sleep(CMD_SPACING_S)
            log.info("robot_safe_stop", url=self.url)
        self._opened = False
        self.connected = False
        self.stale = True
        await self._close_port()

    async def _close_port(self) -> None:
        tr, self._transport = self._transport, None
        if tr is None:
            return
        if not tr.is_closing():
            tr.close()
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(0.5):
                await self._port_closed.wait()
