"""The recorder: ONE bus subscriber that writes every event and every action to MCAP.

It subscribes `with_actions`, so each item is an event and the actions the brain
returned for it. Its task encodes each item as it arrives (a few tens of microseconds,
between the loop's other work; never inside `publish`, so never on the SIP -> wheel
command path) and collects about `chunk_s` of clock time into a batch, which the
writer thread (`relayd.record.writer`) compresses and writes as one MCAP chunk.

Failures: anything that goes wrong in the recorder or the writer thread ends the
recording, with one warning in the log and `state = "failed"` plus the error in
/status; it unsubscribes from the bus, so nothing queues for it any more. The robot
keeps working: nothing on the control path waits for the recorder.

The subscription's queue holds `queue_len` items (about a minute of a robot's events).
If it ever overflows, the bus drops the oldest items; the recorder notices the count
rising and writes a warning line on `/log` where the gap is, and the count goes into
the file's `recorder` metadata, so replay can say why it diverges there.
"""

from __future__ import annotations

import asyncio
import json
import time
import uuid
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, BinaryIO, Protocol

import structlog

from drivers.arcos.sip import RobotIdentity
from drivers.transport.clock import Clock
from relayd.config.model import Settings
from relayd.core.events import Action, DeviceEvent, DeviceStatus, Event
from relayd.record import RecordingStatus, codec
from relayd.record import off_status as off_status  # here since the daemon may skip this module
from relayd.record import writer as file_writer
from relayd.record.foxglove import VIEWS, Views
from relayd.record.meta import run_info
from relayd.record.writer import (
    Batch,
    ChannelSpec,
    FileSeries,
    McapSink,
    WriterThread,
    channel_spec,
)
from relayd.runtime.bus import Subscription

log = structlog.get_logger(__name__)

#: Clock seconds of messages per MCAP chunk: what a killed daemon loses at most.
CHUNK_S = 1.0
#: How often the recorder's task takes what the bus queued for it (loop seconds).
DRAIN_S = 0.1
#: Items the bus may queue for the recorder (about a minute at a robot's event rate).
QUEUE_LEN = 4096
#: A batch handed over early if it grows this long (a burst of events).
MAX_BATCH = 5000
#: A disk that hangs instead of failing must not grow the daemon's memory without bound:
#: the recording is given up when one chunk's write has taken this long (wall s) ...
STALL_S = 30.0
#: ... or this many chunks wait for the writer (ten minutes of a robot's run).
MAX_PENDING = 600
#: How long a normal shutdown waits for the file's summary to be written (wall s).
CLOSE_TIMEOUT_S = 5.0

Routed = tuple[Event, Sequence[Action]]


class RoutedBus(Protocol):
    def subscribe_with_actions(self, name: str, maxlen: int = ...) -> Subscription[Routed]: ...
    def unsubscribe(self, sub: Any) -> None: ...


class Recorder:
    """Records one daemon's route. `start()`, then `await run()` in a task; `await close()`."""

    def __init__(
        self,
        bus: RoutedBus,
        settings: Settings,
        clock: Clock,
        *,
        path: str | None = None,
        identity: Callable[[], RobotIdentity | None] = lambda: None,
        opener: Callable[[Path], BinaryIO] | None = None,
        chunk_s: float = CHUNK_S,
        queue_len: int = QUEUE_LEN,
        max_pending: int = MAX_PENDING,
        stall_s: float = STALL_S,
        drain_s: float = DRAIN_S,
    ) -> None:
        rec = settings.record
        self.path = path if path is not None else rec.path
        self._bus = bus
        self._clock = clock
        self._identity = identity
        self._chunk_s = chunk_s
        self._max_pending = max_pending
        self._stall_s = stall_s
        self._drain_s = drain_s
        self._sub = bus.subscribe_with_actions("recorder", queue_len)
        self._t0 = clock.now()
        self._ns0 = time.time_ns()
        started = datetime.fromtimestamp(self._ns0 / 1e9, tz=UTC)
        run_id = uuid.uuid4().hex
        series = FileSeries(self.path, started)
        self._sink = McapSink(
            series,
            lambda part: run_info(
                settings, start_unix_ns=self._ns0, clock_t0=self._t0, run_id=run_id, part=part
            ),
            max_file_bytes=int(rec.max_file_mb * 1e6),
            max_total_bytes=int(rec.max_total_mb * 1e6),
            # Looked up now, not at import: tests swap in a writer that fails.
            opener=opener if opener is not None else file_writer.open_file,
        )
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread = WriterThread(self._sink, self._error_from_thread)
        self._views = Views()
        self._specs: dict[type, ChannelSpec] = {}
        self._view_specs = {topic: channel_spec(topic, schema) for topic, schema in VIEWS.items()}
        self._batch = Batch()
        self._batch_t: float | None = None
        self._robot: RobotIdentity | None = None
        self._seen_dropped = 0
        self.state = "recording"
        self.error: str | None = None
        self.events = 0
        self.actions = 0

    # -- status ---------------------------------------------------------------------

    @property
    def dropped(self) -> int:
        return self._sub.dropped

    def status(self) -> RecordingStatus:
        """The `recording` object of /status."""
        return {
            "enabled": True,
            "state": self.state,
            "path": None if self._sink.path is None else str(self._sink.path),
            "files": len(self._sink.files),
            "bytes": self._sink.bytes_written,
            "events": self.events,
            "dropped": self.dropped,
            "error": self.error,
        }

    # -- lifecycle ------------------------------------------------------------------

    def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._thread.start()

    async def run(self) -> None:
        """Drain the subscription every `drain_s` until it is closed (shutdown or failure)."""
        sub = self._sub
        try:
            while self.state == "recording" and not sub.closed:
                # A cadence, not a wake-up per event: one loop turn per drain instead of one
                # per event keeps the loop free for the SIPs (measured: bench/RESULTS.md).
                await asyncio.sleep(self._drain_s)
                while (item := sub.get_nowait()) is not None:
                    self._take(item)
                self._after_drain()
        except Exception as exc:  # noqa: BLE001 - a recorder bug must not reach the supervisor
            self._fail(f"{type(exc).__name__}: {exc}")

    async def close(self) -> None:
        """Normal shutdown: record what is still queued, write the summary, end the thread."""
        if self._loop is None:  # never started (the daemon failed before its devices)
            self._bus.unsubscribe(self._sub)
            self.state = "stopped"
            return
        if self.state == "recording":
            try:
                while (item := self._sub.get_nowait()) is not None:
                    self._take(item)
                self._batch.metadata.append(
                    (
                        "recorder",
                        {
                            "events": str(self.events),
                            "actions": str(self.actions),
                            "dropped": str(self.dropped),
                        },
                    )
                )
                self._handover()
            except Exception as exc:  # noqa: BLE001
                self._fail(f"{type(exc).__name__}: {exc}")
            if self.state == "recording":
                self.state = "stopped"
        self._bus.unsubscribe(self._sub)
        self._thread.stop()
        # Waited in wall time, in a helper thread: on the simulator's virtual-time loop a
        # loop timeout would expire at once while the file is still being finished.
        if not await asyncio.to_thread(self._thread.join, CLOSE_TIMEOUT_S):
            log.warning("recording_close_timeout", path=self.status()["path"])

    # -- items in -------------------------------------------------------------------

    def _spec(self, cls: type) -> ChannelSpec:
        spec = self._specs.get(cls)
        if spec is None:
            spec = self._specs[cls] = channel_spec(codec.topic_of(cls), codec.message_schema(cls))
        return spec

    def _ns(self, t: float) -> int:
        return max(0, self._ns0 + round((t - self._t0) * 1e9))

    def _take(self, item: Routed) -> None:
        if self.state != "recording":
            return  # failed: what is still queued is not recorded
        event, actions = item
        seq = self.events
        self.events += 1
        ns = self._ns(event.t)
        msgs = self._batch.messages
        msgs.append((self._spec(type(event)), ns, codec.encode(event, seq)))
        for i, action in enumerate(actions):
            msgs.append((self._spec(type(action)), ns, codec.encode(action, seq, i)))
        self.actions += len(actions)
        for topic, view in self._views.derive(event, actions, ns):
            msgs.append(
                (self._view_specs[topic], ns, json.dumps(view, separators=(",", ":")).encode())
            )
        if (
            isinstance(event, DeviceEvent)
            and event.device == "robot"
            and event.status is DeviceStatus.UP
        ):
            self._note_robot()
        if self._batch_t is None:
            self._batch_t = event.t
        elif event.t - self._batch_t >= self._chunk_s or len(msgs) >= MAX_BATCH:
            self._handover()
            self._batch_t = event.t

    def _note_robot(self) -> None:
        ident = self._identity()
        if ident is not None and ident != self._robot:
            self._robot = ident
            self._views.name = ident.name  # /log lines name the robot
            self._batch.metadata.append(
                (
                    "robot",
                    {
                        "name": ident.name,
                        "robot_class": ident.robot_class,
                        "subclass": ident.subclass,
                    },
                )
            )

    def _after_drain(self) -> None:
        lost = self._sub.dropped - self._seen_dropped
        if lost > 0:
            self._seen_dropped += lost
            topic, view = self._views.gap(self._ns(self._clock.now()), lost)
            self._batch.messages.append(
                (
                    self._view_specs[topic],
                    self._ns(self._clock.now()),
                    json.dumps(view, separators=(",", ":")).encode(),
                )
            )
        if self._thread.error is not None:
            self._fail(self._thread.error)

    def _handover(self) -> None:
        batch, self._batch = self._batch, Batch()
        thread = self._thread
        busy = thread.busy_since
        if busy is not None and time.monotonic() - busy > self._stall_s:
            self._fail(
                f"the disk is not keeping up: one chunk's write has taken over {self._stall_s:g} s"
            )
            return
        if thread.pending >= self._max_pending:
            self._fail(f"the disk is not keeping up: {thread.pending} chunks waiting to be written")
            return
        if batch.messages or batch.metadata:
            self._thread.submit(batch)

    # -- failure --------------------------------------------------------------------

    def _error_from_thread(self, error: str) -> None:
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self._fail, error)

    def _fail(self, error: str) -> None:
        if self.state == "failed":
            return
        self.state, self.error = "failed", error
        self._batch = Batch()
        log.warning(
            "recording_stopped",
            error=error,
            path=self.status()["path"],
            note="the robot keeps working; nothing more is recorded in this run",
        )
        self._bus.unsubscribe(self._sub)
