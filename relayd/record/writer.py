"""The recorder's file side: MCAP files written by one thread, rotated, size-limited.

The event loop hands over one *batch* per chunk (about 1 s of messages, already
encoded); this thread adds them to the `mcap` writer and closes the chunk with
`Writer.flush()`, which compresses it and writes it to the file. So the event loop
never waits for compression or the disk, and a daemon killed with SIGKILL leaves a
file that reads up to its last completed chunk (the OS has every byte written).

Compression is lz4, not zstd (the `mcap` default): measured here, the `zstandard`
module holds the GIL while it compresses, so the event loop's thread waited on it
(a timer's wake-up p50 went from 0.09 to 2.5 ms with a thread compressing), while
`lz4.frame` releases it (0.09 ms) and is five times faster. zstd would make files
about 40 % smaller; at about 26 MB per robot hour that is not worth a SIP's latency.

Files (`FileSeries`): `record.path` is a directory (one file per run,
`relayd-<UTC start>.mcap`) or a file ending in `.mcap`. A file reaching `max_file_mb`
is finished (summary and footer) and the next part of the run begins (`<stem>.2.mcap`,
...); before each file is opened, the oldest recordings in that directory are deleted
until the new file fits under `max_total_mb`.

Any exception here (a full disk, a file system gone read-only) ends the recording:
the file is left as it is (readable up to its last chunk), the error is reported once
to the event loop, and every later batch is dropped.
"""

from __future__ import annotations

import json
import queue
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any, BinaryIO

from mcap.writer import CompressionType, Writer

from relayd import __version__
from relayd.record.meta import RunInfo

#: The mcap writer's own size limit on a chunk, kept out of the way: chunks end on time.
CHUNK_BYTES_LIMIT = 64 * 1024 * 1024
#: Messages added between two GIL hand-overs (about 0.15 ms of the writer's Python work).
YIELD_EVERY = 16


@dataclass(frozen=True, slots=True)
class ChannelSpec:
    """A channel's topic and schema, encoded once per recorder and shared by its messages."""

    topic: str
    schema_name: str
    schema: bytes


def channel_spec(topic: str, schema: dict[str, Any]) -> ChannelSpec:
    return ChannelSpec(
        topic, str(schema["title"]), json.dumps(schema, separators=(",", ":")).encode()
    )


@dataclass(slots=True)
class Batch:
    """One chunk's worth: messages (spec, log time ns, JSON bytes) and metadata records."""

    messages: list[tuple[ChannelSpec, int, bytes]] = field(default_factory=list)
    metadata: list[tuple[str, dict[str, str]]] = field(default_factory=list)


class FileSeries:
    """File names of one run and the total-size limit of the directory they go to."""

    def __init__(self, path: str | Path, started: datetime) -> None:
        p = Path(path)
        if p.suffix == ".mcap":
            self.dir, self.stem = p.parent, p.stem
            self._pattern = re.compile(rf"^{re.escape(self.stem)}(\.\d+)?\.mcap$")
        else:
            self.dir = p
            self.stem = f"relayd-{started.strftime('%Y%m%dT%H%M%SZ')}"
            k = 1
            while (self.dir / f"{self.stem}.mcap").exists():
                k += 1
                self.stem = f"relayd-{started.strftime('%Y%m%dT%H%M%SZ')}-{k}"
            self._pattern = re.compile(r"^relayd-.*\.mcap$")

    def path(self, part: int) -> Path:
        return self.dir / (f"{self.stem}.mcap" if part == 1 else f"{self.stem}.{part}.mcap")

    def recordings(self) -> list[Path]:
        if not self.dir.is_dir():
            return []
        return [p for p in self.dir.iterdir() if self._pattern.match(p.name) and p.is_file()]

    def make_room(self, need_bytes: int, max_total_bytes: int) -> list[Path]:
        """Delete the oldest recordings until `need_bytes` more fit; returns what was deleted."""
        files = sorted(self.recordings(), key=lambda p: p.stat().st_mtime)
        total = sum(p.stat().st_size for p in files)
        deleted = []
        while files and total + need_bytes > max_total_bytes:
            oldest = files.pop(0)
            total -= oldest.stat().st_size
            oldest.unlink()
            deleted.append(oldest)
        return deleted


def open_file(path: Path) -> BinaryIO:
    return path.open("wb")


class McapSink:
    """The current file's mcap writer; lives in the writer thread only."""

    def __init__(
        self,
        series: FileSeries,
        info: Callable[[int], RunInfo],
        *,
        max_file_bytes: int,
        max_total_bytes: int,
        opener: Callable[[Path], BinaryIO] = open_file,
    ) -> None:
        self.series = series
        self._info = info
        self._max_file = max_file_bytes
        self._max_total = max_total_bytes
        self._opener = opener
        self._stream: BinaryIO | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        #: Metadata records every part repeats (the robot's identity once known).
        self._sticky: dict[str, dict[str, str]] = {}
        self.part = 0
        self.path: Path | None = None
        self.bytes_done = 0  # bytes in finished parts
        self.bytes_written = 0
        self.files: list[Path] = []

    def _open_next(self) -> Writer:
        self.part += 1
        self.series.dir.mkdir(parents=True, exist_ok=True)
        self.series.make_room(self._max_file, self._max_total)
        path = self.series.path(self.part)
        stream = self._opener(path)
        self._stream, self.path = stream, path
        self.files.append(path)
        writer = self._writer = Writer(
            stream, chunk_size=CHUNK_BYTES_LIMIT, compression=CompressionType.LZ4
        )
        self._channels, self._schemas = {}, {}
        writer.start(profile="", library=f"relayd {__version__}")
        writer.add_metadata("relayd", self._info(self.part).to_metadata())
        for name, data in self._sticky.items():
            writer.add_metadata(name, data)
        return writer

    def write(self, batch: Batch) -> None:
        writer = self._writer if self._writer is not None else self._open_next()
        for name, meta in batch.metadata:
            if name == "robot":
                self._sticky[name] = meta
            writer.add_metadata(name, meta)
        channels = self._channels
        for k, (spec, ns, data) in enumerate(batch.messages):
            if k % YIELD_EVERY == 0:
                # The mcap writer is Python code holding the GIL: let the event loop's thread
                # in between (a waiting thread would otherwise wait up to the 5 ms switch
                # interval, a SIP's whole latency budget).
                time.sleep(0)
            cid = channels.get(spec.topic)
            if cid is None:
                sid = self._schemas.get(spec.schema_name)
                if sid is None:
                    sid = self._schemas[spec.schema_name] = writer.register_schema(
                        spec.schema_name, "jsonschema", spec.schema
                    )
                cid = channels[spec.topic] = writer.register_channel(spec.topic, "json", sid)
            writer.add_message(cid, log_time=ns, data=data, publish_time=ns)
        time.sleep(0)
        writer.flush()  # type: ignore[no-untyped-call]  # mcap's; the chunk ends here: compressed and handed to the OS
        size = self._stream.tell() if self._stream is not None else 0
        # Read by the event loop for /status: one int, replaced whole.
        self.bytes_written = self.bytes_done + size
        if size >= self._max_file:
            self.finish()

    def finish(self) -> None:
        """Summary and footer on the current file; the next batch opens the next part."""
        writer, stream = self._writer, self._stream
        self._writer = self._stream = None
        if writer is None or stream is None:
            return
        try:
            writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer.finish has no annotations
            self.bytes_done += stream.tell()
            self.bytes_written = self.bytes_done
        finally:
            stream.close()

    def abandon(self) -> None:
        """After an error: close the file as it is (readable up to its last chunk)."""
        stream, self._writer, self._stream = self._stream, None, None
        if stream is not None:
            try:
                stream.close()
            except OSError:
                pass


class WriterThread:
    """Runs a sink in its own thread; `submit` never blocks, errors are reported once."""

    def __init__(self, sink: McapSink, on_error: Callable[[str], None]) -> None:
        self.sink = sink
        self._queue: queue.SimpleQueue[Batch | None] = queue.SimpleQueue()
        self._on_error = on_error
        self.error: str | None = None
        #: Batches submitted and not yet written (read by the event loop: one int).
        self.pending = 0
        #: time.monotonic() when the write in progress began; None while idle.
        self.busy_since: float | None = None
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="relayd-recorder", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def submit(self, batch: Batch) -> None:
        with self._lock:
            self.pending += 1
        self._queue.put(batch)

    def stop(self) -> None:
        """Finish the current file after the batches already submitted, then end the thread."""
        self._queue.put(None)

    def join(self, timeout_s: float) -> bool:
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def _run(self) -> None:
        while True:
            batch = self._queue.get()
            if batch is None:
                break
            self.busy_since = time.monotonic()
            try:
                if self.error is None:
                    self.sink.write(batch)
            except Exception as exc:  # noqa: BLE001 - a full disk must not end the daemon
                self._fail(exc)
            finally:
                self.busy_since = None
                with self._lock:
                    self.pending -= 1
        if self.error is None:
            try:
                self.sink.finish()
            except Exception as exc:  # noqa: BLE001
                self._fail(exc)

    def _fail(self, exc: BaseException) -> None:
        self.error = f"{type(exc).__name__}: {exc}"
        self.sink.abandon()
        self._on_error(self.error)
