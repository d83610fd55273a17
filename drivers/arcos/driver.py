"""ArcosRobot: the asyncio client for a Pioneer P3-AT (ARCOS/AROS, MobileSim) link.

The facade the daemon and the tools use (its public API is listed in
docs/ARCHITECTURE.md). One `run()` task keeps a session up: each session
(`session.py`) does the handshake, state reflection and safe stop over one port
whose bytes an `ArcosProtocol` (`protocol.py`) decodes and paces. When a session
ends, the robot's state is unknown at once (`connected` False, `stale` True) and
`run()` reconnects through the shared loop (`drivers.transport.reconnect`). Cancel or
`shutdown()` stops the wheels, disables the motors and CLOSEs before the port is
closed.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Callable

import structlog

from drivers.arcos.codec import CodecError, Decoder, Packet
from drivers.arcos.protocol import CMD_SPACING_S, MOTION_COMMANDS
from drivers.arcos.session import (
    REFRESH_S,
    SIP_CYCLE_S,
    STANDARD_BAUDS,
    ArcosError,
    ArcosSession,
    HandshakeError,
    NotConnected,
    SessionConfig,
    SessionInfo,
    SessionLost,
)
from drivers.arcos.sip import (
    ConvFactors,
    Odometry,
    RobotConfig,
    RobotIdentity,
    Sip,
    decode_raw_sip,
    sip_from_raw,
)
from drivers.arcos.sonar import SonarRing
from drivers.transport.backoff import Backoff
from drivers.transport.clock import REAL_CLOCK, Clock
from drivers.transport.health import DeviceHealth, LinkState
from drivers.transport.link import LinkError, open_link
from drivers.transport.reconnect import Failure, Reconnect, expecting

log = structlog.get_logger(__name__)

__all__ = [
    "CMD_SPACING_S",
    "MOTION_COMMANDS",
    "REFRESH_S",
    "SIP_CYCLE_S",
    "STANDARD_BAUDS",
    "ArcosError",
    "ArcosRobot",
    "HandshakeError",
    "NotConnected",
    "SessionLost",
]

Listener = Callable[[Sip], None]

#: What ends a session as device trouble; anything else out of a session is a bug.
_describe = expecting(ArcosError, LinkError, OSError, CodecError)


class ArcosRobot:
    """A P3-AT base over a serial path, `socket://host:port` or `memory://name`."""

    def __init__(
        self,
        url: str,
        baud: int = 9600,
        *,
        clock: Clock = REAL_CLOCK,
        subclass_override: str | None = None,
        lost_after_s: float = 0.5,
        enable_motors: bool = False,
        drop_after_s: float = 4.0,
        sync_timeout_s: float = 1.0,
        max_misses: int = 10,
        backoff: Backoff | None = None,
    ) -> None:
        self.url = url
        self.baud = baud
        self.clock = clock
        self.subclass_override = subclass_override
        self.lost_after_s = lost_after_s
        self.drop_after_s = max(drop_after_s, lost_after_s)
        self.sync_timeout_s = sync_timeout_s
        self.max_misses = max_misses
        self.backoff = backoff or Backoff(initial_s=0.2, maximum_s=5.0)

        # What the driver knows of the robot: its one writer is this class (a session
        # reports what it learns through SessionInfo and the session_* callbacks).
        self._connected = False
        self._stale = True
        self.identity: RobotIdentity | None = None
        self.config: RobotConfig | None = None
        self.factors: ConvFactors | None = None
        self.current_baud: int | None = None
        #: The rate the last handshake succeeded at, tried early on the next one.
        self.good_baud: int | None = None
        self.last_sip: Sip | None = None
        self.last_error: str | None = None
        self.sonar = SonarRing()
        self.odometry = Odometry()
        self.decoder = Decoder()
        self.stats = {
            "bytes_tx": 0,
            "sips": 0,
            "old_sessions": 0,
            "handshake_failures": 0,
            "link_errors": 0,
            "bad_sips": 0,
            "listener_errors": 0,
            "sessions": 0,
        }
        #: Called with the seconds from a SIP's bytes arriving to the wheel command it
        #: caused being written (the control latency), measured on the host's
        #: performance counter, not the clock: it is real time even in the simulator.
        self.on_command_latency: Callable[[float], None] | None = None

        self._motors_wish = enable_motors
        self._wheels: tuple[float, float] = (0.0, 0.0)
        self._listeners: list[Listener] = []
        self._in_sip: float | None = None  # rx time of the SIP whose listeners are running
        self._session: ArcosSession | None = None
        self._reconnect = Reconnect(
            log.bind(url=url), "robot_session_failed", backoff=self.backoff, clock=clock, url=url
        )
        self._closing = False
        self._closed = asyncio.Event()

    # ------------------------------------------------------------------ public API

    @property
    def connected(self) -> bool:
        """A session is open and its port alive (a port that died is seen at once)."""
        self._notice_dead_link()
        return self._connected

    @property
    def stale(self) -> bool:
        """No SIP within `lost_after_s`, or no session, or its port died: doubt the robot."""
        self._notice_dead_link()
        return self._stale

    def _notice_dead_link(self) -> None:
        # A serial transport that failed a read or write closes itself at once but
        # reports connection_lost only after closing the port in an executor. Whoever
        # asks first (the control loop, every tick) ends the session there and then,
        # so no timer has to poll for it.
        session = self._session
        if session is not None:
            session.proto.check_alive()

    @property
    def counters(self) -> dict[str, int]:
        return {**self.decoder.counters(), **self.stats, "reconnects": self._reconnect.reconnects}

    def health(self) -> DeviceHealth:
        """The robot link's health now (see drivers.transport.health)."""
        if self._closing:
            state = LinkState.CLOSED
        elif self.connected:
            state = LinkState.STALE if self.stale else LinkState.UP
        else:
            state = LinkState.DOWN if self._reconnect.failures else LinkState.CONNECTING
        counters = self.counters
        return DeviceHealth(
            device="robot",
            state=state,
            last_error=self.last_error,
            errors=sum(v for k, v in counters.items() if k.endswith(("errors", "resyncs"))),
            reconnects=counters["reconnects"],
            last_rx_t=self.last_sip.t if self.last_sip is not None else None,
            counters=counters,
        )

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
        if wish != self._wheels:
            self._caused_by_sip()
        self._wheels = wish
        if self._session is not None:
            # Queued and, the line being free, written from this stack: a wheel
            # command follows the SIP that caused it with as little delay as possible.
            self._session.send_wheels_now()

    def stop(self) -> None:
        """Wheels to zero now: VEL 0 + RVEL 0 ahead of anything queued."""
        if self._wheels != (0.0, 0.0):
            self._caused_by_sip()
        self._wheels = (0.0, 0.0)
        if self._session is not None:
            self._session.stop_now()

    def estop(self) -> None:
        """E_STOP (overrides deceleration) ahead of anything queued; the wish becomes zero."""
        self._wheels = (0.0, 0.0)
        if self._session is not None:
            self._session.estop_now()

    def enable_motors(self, on: bool) -> None:
        """Remember the wish (re-applied on every reconnect) and send ENABLE now if open."""
        self._motors_wish = bool(on)
        if self._session is not None:
            self._session.send_enable(self._motors_wish)

    async def connect(self) -> RobotIdentity:
        """Open the port and run the handshake once. Raises LinkError or HandshakeError."""
        old = self._session
        if old is not None and old.opened and self.identity is not None and not old.lost.is_set():
            return self.identity
        session = ArcosSession(
            SessionConfig(
                url=self.url,
                baud=self.baud,
                good_baud=self.good_baud,
                max_misses=self.max_misses,
                sync_timeout_s=self.sync_timeout_s,
                lost_after_s=self.lost_after_s,
                drop_after_s=self.drop_after_s,
                subclass_override=self.subclass_override,
            ),
            self,
            clock=self.clock,
            decoder=self.decoder,
            counters=self.stats,
            on_command_latency=self._command_latency,
        )
        self.decoder.reset()
        self._session = session
        await open_link(self.url, self.baud, lambda: session.proto)
        self.current_baud = self.baud
        try:
            info = await session.handshake()
            self.current_baud = self.good_baud = info.baud
            info = await session.open(info, on_open=self._on_open)
        except BaseException:
            # Cancelled after OPEN went out: the robot must still hear ENABLE 0 and CLOSE.
            self.current_baud = session.baud
            await self._safe_stop()
            raise
        self.config = info.config
        self._connected = True
        return info.identity

    async def run(self) -> None:
        """Keep a session up until cancelled or shut down. Never raises but CancelledError."""
        try:
            await self._reconnect.run(
                self.connect,
                self._serve,
                stop=self._closed,
                describe=_describe,
                on_failure=self._failed,
                after_loss=self._after_loss,
            )
        except asyncio.CancelledError:
            await self._safe_stop()
            raise

    async def shutdown(self) -> None:
        """Wheels 0, ENABLE 0, CLOSE, close the port; stops `run()`. Idempotent."""
        self._closing = True
        self._reconnect.close()
        self._closed.set()
        await self._safe_stop()

    # ------------------------------------------------------------------ internals

    def _on_open(self, info: SessionInfo) -> None:
        """The session is about to OPEN: SIPs may follow, decoded with these factors."""
        self.identity = info.identity
        self.factors = info.factors
        self.odometry.new_session()

    def session_quiet(self, silent_s: float) -> None:
        """The session heard no SIP for lost_after_s: doubt the robot."""
        self._stale = True

    def session_ended(self, reason: ArcosError) -> None:
        """The session is over: from now on nobody knows what the robot does."""
        self.last_error = str(reason)
        self._connected = False
        self._stale = True

    def handle_sip(self, pkt: Packet, rx_perf: float) -> float | None:
        """Decode a SIP, update odometry and sonar, call the listeners; its clock time."""
        try:
            raw = decode_raw_sip(pkt.ptype, pkt.payload)
        except CodecError as exc:
            self.stats["bad_sips"] += 1
            self.last_error = f"bad SIP: {exc}"
            return None
        factors = self.factors
        if factors is None:  # a SIP before the handshake told us the robot's subclass
            return None
        now = self.clock.now()
        self.odometry.update(raw, factors)
        sip = sip_from_raw(raw, self.odometry, now, factors)
        self.sonar.update(sip.sonar, now)
        self.last_sip = sip
        if self.stale and self.connected:
            log.info("robot_fresh", url=self.url)
        self._stale = False
        self.stats["sips"] += 1
        self._in_sip = rx_perf
        try:
            for cb in tuple(self._listeners):
                try:
                    cb(sip)
                except Exception:  # a listener bug must not stop odometry
                    self.stats["listener_errors"] += 1
                    log.exception("robot_listener_error")
        finally:
            self._in_sip = None
        return now

    async def _serve(self) -> None:
        session = self._session
        if session is None:
            raise NotConnected(f"robot at {self.url}: no session after connect")
        await session.serve()

    def _failed(self, exc: Exception, failure: Failure, text: str) -> None:
        if isinstance(exc, LinkError | OSError):
            self.stats["link_errors"] += 1
        self.last_error = text

    async def _after_loss(self) -> None:
        # Not on cancel or shutdown: the port stays open for the safe stop.
        self._connected = False
        self._stale = True
        if self._session is not None:
            await self._session.close()

    def _caused_by_sip(self) -> None:
        # A wheel wish changed inside a SIP listener: time that SIP to its command.
        if self._in_sip is not None and self._session is not None:
            self._session.proto.latency_t0 = self._in_sip

    def _command_latency(self, latency_s: float) -> None:
        if self.on_command_latency is not None:
            self.on_command_latency(latency_s)

    async def _safe_stop(self) -> None:
        self._wheels = (0.0, 0.0)
        session = self._session
        if session is not None:
            await session.safe_stop()
        self._connected = False
        self._stale = True
