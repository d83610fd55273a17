"""One ARCOS session over one open port: handshake, OPEN, state reflection, safe stop.

A session starts with SYNC0/1/2 (closing a session some earlier client left open,
cycling the baud rate on a serial port that does not answer), then OPEN, CONFIG,
SONAR and ENABLE when wished. While it serves, it reflects the wished wheel speeds as
VEL + RVEL, re-sent on change and every 500 ms (PULSE when idle) so the robot's 2 s
watchdog is never reached; silence marks the robot stale, then ends the session.
It ends on EOF, a device or write error, a controller reset or long silence, and the
robot's state is unknown from that moment. The safe stop (wheels 0, ENABLE 0, CLOSE)
owns the line: nothing queued may slip in between its packets.

The session writes none of the driver's state. It gets a frozen `SessionConfig`, reads
its owner's wishes (motors, wheels), hands each SIP to the owner, returns what the
handshake and OPEN learned as a `SessionInfo`, and reports through two callbacks: the
robot went quiet, and the session ended. The driver (`ArcosRobot`) is the one writer
of what it knows of the robot.

Two callbacks, not one with an end reason: going quiet is not an end (the session goes
on, and the next SIP makes the robot fresh again), so folding it into an end callback
would make "ended" mean "maybe not". The end's reason is already a typed value, the
`ArcosError` that `serve` raises, whose text the driver shows; an enum beside it would
be a second name for the same reason that nothing reads.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

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
from drivers.arcos.protocol import CMD_SPACING_S, ArcosProtocol
from drivers.arcos.sip import (
    ConvFactors,
    RobotConfig,
    RobotIdentity,
    conv_factors,
    decode_config,
    decode_identity,
    wheel_to_vel_rvel,
)
from drivers.transport.clock import Clock
from drivers.transport.link import set_baudrate

log = structlog.get_logger("drivers.arcos.driver")

#: ARIA StateReflectionRefreshTime: re-send motion / PULSE at least this often.
REFRESH_S = 0.5
SIP_CYCLE_S = 0.1
STANDARD_BAUDS = (9600, 115200, 38400, 19200, 57600)
#: The safe stop's writes are bounded in wall time: it runs in cancelled tasks too.
SAFE_STOP_STEP_S = 0.04

#: How far past a deadline the tick loop wakes (its checks are strict comparisons).
DEADLINE_EPS_S = 0.001

_VEL0 = encode_command(Command.VEL, 0)
_RVEL0 = encode_command(Command.RVEL, 0)
_MOTION = (Command.VEL, Command.RVEL, Command.VEL2)


def _wake_up(waiter: asyncio.Future[None] | None) -> None:
    if waiter is not None and not waiter.done():
        waiter.set_result(None)


class ArcosError(Exception):
    """Base of the driver's own errors; messages are meant for an operator."""


class HandshakeError(ArcosError):
    """The robot never completed SYNC0/1/2."""


class SessionLost(ArcosError):
    """The session ended: EOF, device error, controller reset or silence."""


class NotConnected(ArcosError):
    """An operation needs an open session."""


@dataclass(frozen=True, slots=True)
class SessionConfig:
    """What a session is told: where, how fast, and its patience."""

    url: str
    baud: int
    #: The rate the last handshake succeeded at, tried early.
    good_baud: int | None
    max_misses: int
    sync_timeout_s: float
    lost_after_s: float
    drop_after_s: float
    subclass_override: str | None = None


@dataclass(frozen=True, slots=True)
class SessionInfo:
    """What the handshake (identity, the rate that answered) and OPEN (CONFIG) learned."""

    identity: RobotIdentity
    baud: int
    factors: ConvFactors | None = None
    config: RobotConfig | None = None


class SessionOwner(Protocol):
    """The driver, as a session sees it: wishes to reflect, and where SIPs and news go."""

    @property
    def motors_wish(self) -> bool: ...

    @property
    def wheels_wish(self) -> tuple[float, float]: ...

    def handle_sip(self, pkt: Packet, rx_perf: float) -> float | None: ...

    def session_quiet(self, silent_s: float) -> None:
        """No SIP for lost_after_s: doubt the robot (the session goes on; a SIP ends the doubt)."""

    def session_ended(self, reason: ArcosError) -> None:
        """Called once, at once: the session is over, for `reason` (what `serve` raises)."""


class ArcosSession:
    """The life of one connection to the robot, from SYNC0 to CLOSE."""

    def __init__(
        self,
        cfg: SessionConfig,
        owner: SessionOwner,
        *,
        clock: Clock,
        decoder: Decoder,
        counters: dict[str, int],
        on_command_latency: Callable[[float], None] | None = None,
    ) -> None:
        self.cfg = cfg
        self.owner = owner
        self.clock = clock
        self.url = cfg.url
        #: The driver's counters, lent to count into (the session writes no other state of it).
        self.counters = counters
        self.proto = ArcosProtocol(
            clock, self.on_packet, self.on_link_lost, decoder=decoder, stats=counters
        )
        self.proto.on_command_latency = on_command_latency
        #: The rate the port is at now (the handshake cycles it on a silent serial port).
        self.baud = cfg.baud
        self.quiet = False
        #: OPEN was sent: the robot is in a session that must be CLOSEd.
        self.opened = False
        self.opened_t = 0.0
        self.last_sip_t: float | None = None
        self.lost = asyncio.Event()
        self.reason: ArcosError | None = None
        self._sent_motion: tuple[int, int] | None = None
        self._motion_t = -math.inf
        self._pulse_t = -math.inf
        self._waiter: asyncio.Future[None] | None = None

    # ------------------------------------------------------------------ handshake

    async def handshake(self) -> SessionInfo:
        cfg, proto = self.cfg, self.proto
        is_serial = not self.url.startswith(("socket://", "rfc2217://", "memory://"))
        # The configured rate first, then the last rate that worked, then the standard ones.
        good = cfg.good_baud
        first = [cfg.baud] if good in (None, cfg.baud) else [cfg.baud, good]
        bauds = first + [b for b in STANDARD_BAUDS if b not in first] if is_serial else [cfg.baud]
        baud_i = 0
        misses = misses_here = sent = 0
        state = 0
        proto.want_packets = True
        try:
            while True:
                sent += 1
                if sent > 6 * cfg.max_misses:
                    raise HandshakeError(
                        f"robot at {self.url}: no handshake after {sent - 1} SYNC packets"
                    )
                proto.clear_rx()
                proto.write(encode_command(state))
                try:
                    pkt = await proto.next_packet(cfg.sync_timeout_s)
                except TimeoutError:
                    misses += 1
                    misses_here += 1
                    if misses >= cfg.max_misses:
                        self.counters["handshake_failures"] += 1
                        tried = ", ".join(str(b) for b in bauds) if is_serial else "tcp"
                        raise HandshakeError(
                            f"robot at {self.url} never answered SYNC{state} "
                            f"({misses} tries; baud {tried})"
                        ) from None
                    if len(bauds) > 1 and misses_here >= 2 and proto.transport is not None:
                        baud_i = (baud_i + 1) % len(bauds)
                        misses_here = 0
                        set_baudrate(proto.transport, bauds[baud_i])
                        self.baud = bauds[baud_i]
                        log.info("robot_baud_cycle", url=self.url, baud=bauds[baud_i])
                    state = 0
                    continue
                if pkt.ptype == state:
                    if state < 2:
                        state += 1
                        continue
                    try:
                        identity = decode_identity(pkt.payload)
                    except CodecError as exc:
                        log.warning("robot_bad_sync2", url=self.url, error=str(exc))
                        state = 0
                        continue
                    return SessionInfo(identity, bauds[baud_i])
                if pkt.ptype in SIP_TYPES:
                    # Still in a session someone never closed: CLOSE it, then start over.
                    self.counters["old_sessions"] += 1
                    log.info("robot_old_session", url=self.url)
                    await self._close_old_session()
                else:
                    log.debug("robot_unexpected_sync_reply", ptype=pkt.ptype, state=state)
                state = 0
        finally:
            proto.want_packets = False

    async def _close_old_session(self) -> None:
        proto = self.proto
        proto.write(encode_command(CLOSE, 1))
        end = self.clock.now() + 0.2
        closes = 1
        while (remaining := end - self.clock.now()) > 0:
            try:
                pkt = await proto.next_packet(remaining)
            except TimeoutError:
                break
            if pkt.ptype in SIP_TYPES and closes < 5:
                proto.write(encode_command(CLOSE, 1))
                closes += 1
        await self.clock.sleep(SIP_CYCLE_S)

    async def open(
        self, info: SessionInfo, *, on_open: Callable[[SessionInfo], None]
    ) -> SessionInfo:
        """OPEN, CONFIG (its reply read if it comes), SONAR, and ENABLE if wished.

        `on_open` gets the identity and odometry factors just before OPEN goes out, so the
        owner can decode the SIPs that follow; the returned info adds the CONFIG reply."""
        proto = self.proto
        identity = info.identity
        subclass = self.cfg.subclass_override or identity.subclass
        info = SessionInfo(identity, info.baud, conv_factors(subclass))
        await self.clock.sleep(SIP_CYCLE_S)
        on_open(info)
        self.last_sip_t = None
        self.opened = True
        self.opened_t = self.clock.now()
        self._sent_motion = None
        await proto.send_paced(encode_command(OPEN, 1))
        config: RobotConfig | None = None
        proto.want_packets = True
        try:
            await proto.send_paced(encode_command(Command.CONFIG, 1))
            end = self.clock.now() + 1.0
            while (remaining := end - self.clock.now()) > 0:
                try:
                    pkt = await proto.next_packet(remaining)
                except TimeoutError:
                    break
                if pkt.ptype == PacketType.CONFIG:
                    try:
                        config = decode_config(pkt.payload)
                    except CodecError as exc:
                        log.warning("robot_bad_config", error=str(exc))
                    break
        finally:
            proto.want_packets = False
        await proto.send_paced(encode_command(Command.SONAR, 1))
        if self.owner.motors_wish:
            await proto.send_paced(encode_command(Command.ENABLE, 1))
        self.counters["sessions"] += 1
        log.info(
            "robot_connected",
            url=self.url,
            name=identity.name,
            robot_class=identity.robot_class,
            subclass=identity.subclass,
            odometry_subclass=subclass,
            baud=self.baud,
            motors=self.owner.motors_wish,
            watchdog_ms=config.watchdog_ms if config else None,
        )
        return SessionInfo(identity, info.baud, info.factors, config)

    # ------------------------------------------------------------------ serving

    async def serve(self) -> None:
        """Reflect the wishes until the session ends; raises the reason it ended."""
        tasks = {
            asyncio.create_task(self.proto.tx_loop(), name="arcos-tx"),
            asyncio.create_task(self._tick_loop(), name="arcos-tick"),
        }
        try:
            await self.lost.wait()
        finally:
            for task in tasks:
                task.cancel()
            for task in tasks:
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        raise self.reason or SessionLost("session ended")

    async def _tick_loop(self) -> None:
        """Staleness, the session's end on silence, and state reflection, on deadlines.

        It sleeps until the next thing is due (the robot goes stale, the session is
        dropped, VEL/RVEL or PULSE must be re-sent) or until woken by a new wish,
        instead of ticking: at 10 Hz SIPs that is a few wake-ups a second, not twenty.
        """
        cfg = self.cfg
        while True:
            self.proto.check_alive()
            now = self.clock.now()
            since_t = self.last_sip_t if self.last_sip_t is not None else self.opened_t
            since = now - since_t
            if since > cfg.lost_after_s and not self.quiet:
                self.quiet = True
                log.warning("robot_stale", url=self.url, silent_s=round(since, 3))
                self.owner.session_quiet(since)
            if since > cfg.drop_after_s:
                self.end(SessionLost(f"no SIP from {self.url} for {cfg.drop_after_s:g} s"))
                return
            self.reflect(now)
            due = min(since_t + cfg.drop_after_s, self._next_reflection_t())
            if not self.quiet:
                due = min(due, since_t + cfg.lost_after_s)
            # Just past the deadline (the checks are strict), never sooner than a
            # command spacing (a PULSE waiting for a busy queue), never later than
            # lost_after_s (a bound on any missed wake-up).
            delay = min(max(due - now + DEADLINE_EPS_S, CMD_SPACING_S), cfg.lost_after_s)
            await self._sleep(delay)

    def _next_reflection_t(self) -> float:
        if self._sent_motion not in (None, (0, 0)):
            return self._motion_t + REFRESH_S
        return max(self.proto.last_write_t, self._pulse_t) + REFRESH_S

    async def _sleep(self, delay_s: float) -> None:
        """Sleep `delay_s` clock seconds or until `wake()`; a future, no timeout machinery."""
        loop = asyncio.get_running_loop()
        waiter = loop.create_future()
        self._waiter = waiter
        handle = loop.call_later(self.clock.to_real(delay_s), _wake_up, waiter)
        try:
            await waiter
        finally:
            handle.cancel()
            self._waiter = None

    def wake(self) -> None:
        _wake_up(self._waiter)

    def reflect(self, now: float) -> None:
        """ARIA state reflection: VEL+RVEL on change or every 500 ms while moving, else PULSE."""
        proto = self.proto
        if proto.held:
            return
        motion = wheel_to_vel_rvel(*self.owner.wheels_wish)
        due = now - self._motion_t >= REFRESH_S
        if motion != self._sent_motion or (motion != (0, 0) and due):
            proto.drop_queued((Command.VEL, Command.RVEL, PULSE))
            proto.queue(Command.VEL, encode_command(Command.VEL, motion[0]))
            proto.queue(Command.RVEL, encode_command(Command.RVEL, motion[1]))
            self._sent_motion = motion
            self._motion_t = now
        elif now - max(proto.last_write_t, self._pulse_t) >= REFRESH_S and not proto.normal:
            proto.queue(PULSE, encode_command(PULSE))
            self._pulse_t = now

    def send_wheels_now(self) -> None:
        """A new wheel wish: queue it and write it at once if the line is free."""
        if self.opened:
            self.reflect(self.clock.now())
            self.proto.flush_now()
        self.wake()

    def stop_now(self) -> None:
        """VEL 0 + RVEL 0 ahead of anything queued (idempotent while not yet written)."""
        proto = self.proto
        proto.drop_queued(_MOTION)
        if not self.opened:
            return
        # A stop still waiting to be written is not queued twice, so a caller that
        # asserts "stopped" on every tick cannot grow the queue.
        if not (_VEL0 in proto.urgent and _RVEL0 in proto.urgent):
            proto.queue_urgent(_VEL0, _RVEL0)
            proto.flush_now()
        self._sent_motion = (0, 0)
        self._motion_t = self.clock.now()

    def estop_now(self) -> None:
        proto = self.proto
        proto.normal.clear()
        if not self.opened:
            return
        proto.queue_urgent(encode_command(Command.E_STOP))
        proto.flush_now()
        self._sent_motion = (0, 0)
        self._motion_t = self.clock.now()

    def send_enable(self, on: bool) -> None:
        if not self.opened:
            return
        if on:
            self.proto.queue(Command.ENABLE, encode_command(Command.ENABLE, 1))
        else:
            self.proto.queue_urgent(encode_command(Command.ENABLE, 0))

    # ------------------------------------------------------------------ packets in

    def on_packet(self, pkt: Packet) -> None:
        if pkt.ptype in RESET_TYPES:
            self.end(SessionLost(f"controller reset (packet type 0x{pkt.ptype:02X})"))
            return
        if self.opened and pkt.ptype in SIP_TYPES:
            t = self.owner.handle_sip(pkt, self.proto.rx_perf)
            if t is not None:
                self.last_sip_t = t
                self.quiet = False
            if not self.proto.want_packets:
                return
        if self.proto.want_packets:
            self.proto.offer(pkt)

    def on_link_lost(self, exc: Exception | None) -> None:
        self.end(SessionLost(f"link to {self.url} lost: {exc or 'EOF'}"))

    def end(self, reason: ArcosError) -> None:
        """The session is over: from now on nobody knows what the robot does."""
        if self.lost.is_set():
            return
        self.reason = reason
        self.lost.set()
        self.proto.fail_waiters(reason)
        # At once, not when the run loop gets its turn: a controller reading the driver's
        # `connected`/`stale` must stop the wheels now.
        self.owner.session_ended(reason)

    # ------------------------------------------------------------------ safe stop

    async def safe_stop(self) -> None:
        """Wheels 0, ENABLE 0, CLOSE (paced, ~20 ms), then close the port."""
        proto = self.proto
        proto.held = True
        proto.clear_tx()
        if self.opened and proto.writable:
            for data in (
                _VEL0,
                _RVEL0,
                encode_command(Command.ENABLE, 0),
                encode_command(CLOSE, 1),
            ):
                proto.write(data)
                # A paced write must not hold up a cancelled task: bound the whole sequence.
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(SAFE_STOP_STEP_S):
                        await self.clock.sleep(CMD_SPACING_S)
            log.info("robot_safe_stop", url=self.url)
        self.opened = False
        await proto.close()

    async def close(self) -> None:
        """Close the port without the safe stop (the session already failed)."""
        self.opened = False
        await self.proto.close()
