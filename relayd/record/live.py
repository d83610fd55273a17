"""The live Foxglove view: the recorder's channels, served as they happen over WebSocket.

Foxglove connects to `ws://<bind>:<port>` (`[foxglove]` in the config) and sees the
relay live with the same topics, schemas and layouts that open a recording: the
channels, their JSON schemas (byte for byte) and the message bodies all come from
`relayd.record.codec` and `relayd.record.foxglove`, the recorder's own sources. The
WebSocket server is the maintained `foxglove-sdk` (Rust, its own threads), on an
ephemeral loopback port behind relayd's own gate (relayd/record/livegate.py: a client
cap, a handshake deadline, the process's shared descriptor account, rate-limited log
lines, and the SDK's listener restarted when it stops accepting).

What it costs the control path: no work inside it. This is ONE bus subscriber (`with_actions`),
so the brain and the wheel command run inside `publish()` before it sees the event;
its task wakes ten times a second, encodes what queued between the loop's other
callbacks, and only for channels a client has subscribed to (no client: no encoding
at all). The SDK queues each
client's messages in its own bounded backlog, dropping the oldest, and writes to the
sockets from its own threads; a client that stops reading loses data, the robot
loses nothing.

Differences from a recording, all because a viewer joins a run already under way:
- `seq` counts the events published since the server started, dropped ones included,
  so a gap in `seq` is an event this view did not send.
- `/state` is latched: when a client subscribes, it first gets the current `mode`,
  `drive_state` and `reason`, then the changes, as in a recording.
- A drop (the subscription's queue overflowed) is a WARNING line on `/log`.
"""

from __future__ import annotations

import asyncio
import errno
import json
import socket
import time
from typing import TYPE_CHECKING, Any

import structlog

from drivers.transport.clock import Clock
from drivers.transport.health import DeviceHealth, LinkState
from relayd.config.model import Settings
from relayd.core.events import Decision
from relayd.record import codec
from relayd.record.foxglove import VIEWS, Views, log_line
from relayd.record.livegate import LiveGate
from relayd.record.recorder import Routed, RoutedBus
from relayd.record.writer import ChannelSpec, channel_spec
from relayd.runtime.fdbudget import FdBudget

if TYPE_CHECKING:  # the SDK itself is imported only when the server is enabled
    from foxglove.websocket import WebSocketServer

log = structlog.get_logger(__name__)

#: Items the bus may queue for the live view (a few seconds of a robot's events): a
#: viewer wants the present, so a longer backlog would only show older data.
QUEUE_LEN = 1024
#: How often the queue is drained and sent (s): what a viewer sees lags by at most this.
DRAIN_S = 0.1
#: Messages the SDK buffers per client before dropping that client's oldest.
CLIENT_BACKLOG = 1024
SUBPROTOCOL = "foxglove.sdk.v1"


def channel_specs() -> list[ChannelSpec]:
    """Every channel a recording may hold, as the recorder writes it (topic, schema name, schema)."""
    types = [*codec.EVENT_TYPES.values(), *codec.ACTION_TYPES.values()]
    specs = [channel_spec(codec.topic_of(cls), codec.message_schema(cls)) for cls in types]
    specs += [channel_spec(topic, schema) for topic, schema in VIEWS.items()]
    return specs


class BindError(Exception):
    """The server could not listen on `[foxglove]`'s bind and port; `key` is the one to change."""

    def __init__(self, text: str, key: str) -> None:
        super().__init__(text)
        self.key = key


class LiveServer:
    """One daemon's live Foxglove server. `start()`, `await run()` in a task, `close()`."""

    def __init__(
        self,
        bus: RoutedBus,
        settings: Settings,
        clock: Clock,
        *,
        queue_len: int = QUEUE_LEN,
        drain_s: float = DRAIN_S,
        budget: FdBudget | None = None,
    ) -> None:
        import foxglove  # the SDK's Rust module is loaded only when the server is enabled

        self._fox = foxglove
        self.settings = settings.foxglove
        self.name = settings.robot.display_name or "relayd"
        self._bus = bus
        self._clock = clock
        self._drain_s = drain_s
        self._sub = bus.subscribe_with_actions("foxglove", queue_len)
        self._t0 = clock.now()
        self._ns0 = time.time_ns()
        # A context of its own: the simulator runs several daemons in one process.
        self._context = foxglove.Context()
        self._by_topic: dict[str, Any] = {}
        for spec in channel_specs():
            self._by_topic[spec.topic] = foxglove.Channel(
                spec.topic,
                message_encoding="json",
                context=self._context,
                schema=foxglove.Schema(
                    name=spec.schema_name, encoding="jsonschema", data=spec.schema
                ),
            )
        self._topic_of = {
            cls: codec.topic_of(cls)
            for cls in (*codec.EVENT_TYPES.values(), *codec.ACTION_TYPES.values())
        }
        self._views = Views(self.name)
        #: Set by the SDK's thread when a client subscribes to /state (a bool: atomic under the GIL).
        self._latch_wanted = False
        self._last: Decision | None = None
        self._server: WebSocketServer | None = None
        self._listen: socket.socket | None = None
        self.gate = LiveGate(
            budget or FdBudget.for_process(), 0, on_upstream_refused=self._restart_sdk
        )
        #: Times the SDK's listener stopped accepting and was started again.
        self.restarts = 0
        self._seen_dropped = 0
        self.port: int | None = None
        self.events = 0
        self.sent = 0
        #: Message bytes handed to the SDK (each subscribed client gets a copy).
        self.sent_bytes = 0
        self.max_message_bytes = 0
        self.error: str | None = None

    @property
    def dropped(self) -> int:
        return self._sub.dropped

    def channel_ids(self) -> dict[str, int]:
        """Each topic's channel id, as clients see it in `advertise`."""
        return {topic: int(ch.id()) for topic, ch in self._by_topic.items()}

    def start(self) -> None:
        """Listen (the gate on `[foxglove]`'s address, the SDK behind it on loopback);
        raises BindError (the daemon reports it as a config error)."""
        s = self.settings
        try:
            self._listen = listen_on(s.bind, s.port)
        except OSError as exc:
            text = exc.strerror or str(exc)
            key = "foxglove.bind" if exc.errno == errno.EADDRNOTAVAIL else "foxglove.port"
            raise BindError(text, key) from None
        self.port = int(self._listen.getsockname()[1])
        try:
            self.gate.upstream_port = self._start_sdk()
        except RuntimeError as exc:
            self._listen.close()
            self._listen = None
            raise BindError(str(exc), "foxglove.port") from None
        self.gate.start(self._listen)
        log.info("foxglove_live", url=f"ws://{s.bind}:{self.port}", channels=len(self._by_topic))

    def _start_sdk(self) -> int:
        """The SDK's server on an ephemeral loopback port, reached only through the gate."""
        from foxglove.websocket import ServerListener

        owner = self

        class Listener(ServerListener):
            """The SDK's callbacks (on its threads): only notes that /state wants its latch."""

            def on_subscribe(self, client: Any, channel: Any) -> None:
                if channel.topic == "/state":
                    owner._latch_wanted = True

        self._server = self._fox.start_server(
            name=self.name,
            host="127.0.0.1",
            port=0,
            context=self._context,
            capabilities=[],
            message_backlog_size=CLIENT_BACKLOG,
            server_listener=Listener(),
        )
        return int(self._server.port)

    def _restart_sdk(self) -> int | None:
        """The SDK refused the gate's connection: its listener is gone. Start it again."""
        old, self._server = self._server, None
        if old is not None:
            try:
                old.stop()
            except Exception as exc:  # noqa: BLE001 - a dead server may fail to stop; start anew anyway
                log.debug("foxglove_stop_failed", error=str(exc))
        try:
            port = self._start_sdk()
        except RuntimeError as exc:
            self.error = f"the Foxglove server could not be restarted: {exc}"
            log.warning("foxglove_restart_failed", error=str(exc))
            return None
        self.restarts += 1
        log.warning("foxglove_restarted", restarts=self.restarts)
        return port

    def health(self) -> DeviceHealth:
        """The live view as /status shows it, under health "foxglove": listening, the
        connections refused (cap, deadline, descriptors), the SDK's restarts, the last error."""
        gate = self.gate
        up = gate.listening and self._server is not None and self.error is None
        return DeviceHealth(
            "foxglove",
            LinkState.UP if up else LinkState.DOWN,
            errors=gate.counters["refused"]
            + gate.counters["late"]
            + gate.counters["upstream_failed"],
            reconnects=self.restarts,
            last_error=self.error or gate.last_error,
        )

    async def run(self) -> None:
        """Drain the subscription every `drain_s` until it is closed."""
        sub = self._sub
        try:
            while not sub.closed:
                # A cadence, not a wake-up per event, as the recorder does: one loop turn
                # per drain keeps the loop free for the SIPs (bench/RESULTS.md).
                await asyncio.sleep(self._drain_s)
                if not sub.closed:
                    self._drain()
        except Exception as exc:  # noqa: BLE001 - a viewer's bug must not reach the supervisor
            self.error = f"{type(exc).__name__}: {exc}"
            log.warning(
                "foxglove_live_stopped",
                error=self.error,
                note="the robot keeps working; the live view sends nothing more",
            )
            self._bus.unsubscribe(sub)

    def close(self) -> None:
        self._bus.unsubscribe(self._sub)
        self.gate.close()
        if self._listen is not None:
            self._listen.close()
            self._listen = None
        server, self._server = self._server, None
        if server is not None:
            server.stop()
        for ch in self._by_topic.values():
            ch.close()

    # -- items out ------------------------------------------------------------------

    def _ns(self, t: float) -> int:
        return max(0, self._ns0 + round((t - self._t0) * 1e9))

    def _drain(self) -> None:
        # Which channels have a subscriber, asked once per drain (a call into the SDK each).
        live = {topic for topic, ch in self._by_topic.items() if ch.has_sinks()}
        if self._latch_wanted and "/state" in live:
            self._latch_wanted = False
            self._latch(self._ns(self._clock.now()))
        while (item := self._sub.get_nowait()) is not None:
            self._take(item, live)
        lost = self._sub.dropped - self._seen_dropped
        if lost > 0:
            self._seen_dropped += lost
            if "/log" in live:
                ns = self._ns(self._clock.now())
                self._send(
                    "/log",
                    ns,
                    log_line(
                        ns,
                        "WARNING",
                        f"live view fell behind: {lost} event(s) not sent",
                        self.name,
                        "relayd.record.live",
                    ),
                )

    def _take(self, item: Routed, live: set[str]) -> None:
        event, actions = item
        seq = self.events + self._sub.dropped
        self.events += 1
        for action in actions:
            if isinstance(action, Decision):
                self._last = action
        if not live:
            return
        ns = self._ns(event.t)
        topic = self._topic_of[type(event)]
        if topic in live:
            self._log(self._by_topic[topic], ns, codec.encode(event, seq))
        for i, action in enumerate(actions):
            topic = self._topic_of[type(action)]
            if topic in live:
                self._log(self._by_topic[topic], ns, codec.encode(action, seq, i))
        for topic, view in self._views.derive(event, actions, ns):
            if topic in live:
                self._send(topic, ns, view)

    def _latch(self, ns: int) -> None:
        """A client newly subscribed to /state: the current values first (every /state
        subscriber gets them again: the same values, harmless to a State Transitions panel)."""
        last = self._last
        if last is None:
            return
        for key, value in (
            ("mode", str(last.mode)),
            ("drive_state", str(last.state)),
            ("reason", last.reason),
        ):
            self._send("/state", ns, {"key": key, "value": value})

    def _send(self, topic: str, ns: int, doc: dict[str, Any]) -> None:
        self._log(self._by_topic[topic], ns, json.dumps(doc, separators=(",", ":")).encode())

    def _log(self, channel: Any, ns: int, data: bytes) -> None:
        # Never blocks: the SDK puts the message in each subscribed client's bounded backlog.
        channel.log(data, log_time=ns)
        self.sent += 1
        self.sent_bytes += len(data)
        if len(data) > self.max_message_bytes:
            self.max_message_bytes = len(data)


def listen_on(host: str, port: int) -> socket.socket:
    """A listening TCP socket on host:port (0 = ephemeral); OSError if it cannot bind."""
    infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    return socket.create_server((host, port), family=infos[0][0], backlog=64)


async def close_soon(server: LiveServer | None, task: asyncio.Task[None] | None) -> None:
    """Shutdown: stop the server (the SDK's stop returns at once), let the task end."""
    if server is not None:
        server.close()
    if task is not None:
        try:
            await asyncio.wait_for(task, 0.5)
        except (asyncio.CancelledError, Exception):  # noqa: BLE001
            pass
