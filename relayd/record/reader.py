"""Reading a recording back: metadata, and each event with the actions recorded for it.

The file is read record by record in file order with the `mcap` library's stream
reader (CRCs checked), so a file without its summary (a daemon killed with SIGKILL,
a disk that filled up) is read up to its last complete chunk. Messages are taken a
chunk at a time: a chunk that does not decompress, fails its CRC or holds a message
that does not decode is not used at all. Every error names the byte offset where the
file broke, the number of complete chunks before it and the last clock time read.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from mcap.exceptions import EndOfFile, InvalidMagic
from mcap.records import Channel, Chunk, Footer, McapRecord, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from relayd.core.events import Action, Event
from relayd.record import codec
from relayd.record.meta import RunInfo, recorder_counts

#: No record of ours comes near this: a bigger length field is a corrupt file.
RECORD_SIZE_LIMIT = 1 << 30
#: A chunk that says it expands beyond this is refused before it is decompressed (the
#: recorder's chunks are about 1 MiB; a 10 KB file once declared 3 GB of zeros).
CHUNK_SIZE_LIMIT = 64 << 20
#: What one file may expand to in all: the work per file is bounded.
TOTAL_SIZE_LIMIT = 2 << 30
#: The compressions a chunk may use (the recorder writes lz4). zstd's output is bounded by
#: the declared size; lz4's by its ratio (at most ~255:1) times RECORD_SIZE_LIMIT's chunk.
COMPRESSIONS = ("", "zstd", "lz4")


class RecordingError(Exception):
    """A file that cannot be read (whole); the message says where it broke."""

    def __init__(self, path: str | Path, message: str, offset: int | None = None) -> None:
        where = f" at byte {offset}" if offset is not None else ""
        super().__init__(
            f"{path}: {message}{where}" if offset is None else f"{path}{where}: {message}"
        )
        self.offset = offset


@dataclass(slots=True)
class Step:
    """One recorded event and the actions the brain returned for it, in order."""

    seq: int
    event: Event
    actions: list[Action] = field(default_factory=list)
    #: The actions as recorded (JSON data without the envelope), for exact comparison.
    docs: list[dict[str, Any]] = field(default_factory=list)


@dataclass(slots=True)
class Recording:
    path: Path
    info: RunInfo
    steps: list[Step]
    robot: dict[str, str] | None = None
    recorder: dict[str, str] | None = None
    topics: dict[str, int] = field(default_factory=dict)
    chunks: int = 0
    #: False when the file has no summary (the recorder never finished it).
    complete: bool = True
    #: Where reading stopped early (with `partial=True`), else None.
    broke: str | None = None

    @property
    def actions(self) -> int:
        return sum(len(s.actions) for s in self.steps)


def action_doc(action: Action) -> dict[str, Any]:
    """An action as comparable data: its type name and fields, as the recorder writes them."""
    doc: dict[str, Any] = {"type": type(action).__name__}
    doc.update(codec.to_json(action))
    return doc


class _Chunked:
    """Decodes the messages of one chunk; nothing of a chunk is kept unless all of it reads."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.schemas: dict[int, str] = {}
        self.channels: dict[int, tuple[str, str]] = {}
        self.topics: dict[str, int] = {}
        self.events: dict[int, Event] = {}
        self.acts: dict[int, list[tuple[int, Action, dict[str, Any]]]] = {}
        self.last_t: float | None = None

    def take(self, records: list[McapRecord], offset: int) -> None:
        events: dict[int, Event] = {}
        acts: dict[int, list[tuple[int, Action, dict[str, Any]]]] = {}
        topics: dict[str, int] = {}
        last_t = self.last_t
        for rec in records:
            if isinstance(rec, Schema):
                self.schemas[rec.id] = rec.name
            elif isinstance(rec, Channel):
                self.channels[rec.id] = (rec.topic, self.schemas.get(rec.schema_id, ""))
            elif isinstance(rec, Message):
                topic, schema = self.channels.get(rec.channel_id, ("?", ""))
                topics[topic] = topics.get(topic, 0) + 1
                if not schema.startswith("relayd."):
                    continue  # a Foxglove view: derived, not needed to replay
                name = schema.removeprefix("relayd.")
                try:
                    doc = json.loads(rec.data)
                    if not isinstance(doc, dict):
                        raise TypeError(f"a JSON {type(doc).__name__}, not an object")
                    seq = _count(doc.pop("seq"), "seq")
                    if name in codec.EVENT_TYPES:
                        event = codec.decode(codec.EVENT_TYPES[name], doc)
                        if not abs(event.t) <= MAX_EVENT_T:
                            raise ValueError(f"t: {event.t!r} is not a time of a run")
                        events[seq] = event
                        last_t = event.t
                    elif name in codec.ACTION_TYPES:
                        i = _count(doc.pop("i"), "i")
                        action = codec.decode(codec.ACTION_TYPES[name], doc)
                        acts.setdefault(seq, []).append((i, action, {"type": name, **doc}))
                    else:
                        raise codec.DecodeError(f"unknown message type {schema}")
                except (ValueError, KeyError, TypeError, RecursionError) as exc:
                    raise RecordingError(
                        self.path, f"a {topic} message in the chunk does not decode: {exc}", offset
                    ) from None
        self.events.update(events)
        for seq, items in acts.items():
            self.acts.setdefault(seq, []).extend(items)
        for topic, n in topics.items():
            self.topics[topic] = self.topics.get(topic, 0) + n
        self.last_t = last_t


#: An event time beyond this (s, either sign) is no clock reading of a run: a recording
#: holding one is refused, where the brain would overflow on it (1e308 once did).
MAX_EVENT_T = 1e10


def _count(value: Any, key: str) -> int:
    """A message's `seq` or `i`: a whole number >= 0 (it orders the file's steps)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise TypeError(f"{key}: {value!r} is not a count")
    return value


class _Cursor:
    """Where the record being read starts (so an error can name it)."""

    def __init__(self) -> None:
        self.start = 0


def _records(f: BinaryIO, cursor: _Cursor) -> Iterator[tuple[int, McapRecord]]:
    """(offset where the record starts, record), in file order, chunks not expanded."""
    reader = StreamReader(
        f, emit_chunks=True, validate_crcs=True, record_size_limit=RECORD_SIZE_LIMIT
    )
    records = iter(reader.records)
    while True:
        cursor.start = f.tell()
        try:
            rec = next(records)
        except StopIteration:
            return
        yield cursor.start, rec


def chunk_refusal(chunk: Chunk, expanded_bytes: int) -> str | None:
    """Why a chunk is not decompressed (None: it may be): the checks before any work."""
    if chunk.compression not in COMPRESSIONS:
        return f"compression {chunk.compression!r} is not one relayd writes"
    if chunk.uncompressed_size > CHUNK_SIZE_LIMIT:
        return f"declares {chunk.uncompressed_size} bytes, more than {CHUNK_SIZE_LIMIT}"
    if expanded_bytes > TOTAL_SIZE_LIMIT:
        return f"the file expands to more than {TOTAL_SIZE_LIMIT} bytes"
    return None


def iter_messages(path: Path, topics: frozenset[str]) -> Iterator[tuple[str, int, bytes]]:
    """(topic, log time, data) of the messages on `topics`, in log-time order, read with the
    same checks as read_recording (CRCs, the chunk caps); RecordingError says where not."""
    try:
        f = path.open("rb")
    except OSError as exc:
        raise RecordingError(path, f"cannot open: {exc.strerror or exc}") from None
    channels: dict[int, str] = {}
    out: list[tuple[str, int, bytes]] = []
    expanded = chunks = 0
    cursor = _Cursor()
    with f:
        try:
            for offset, rec in _records(f, cursor):
                inner: list[McapRecord] = [rec]
                if isinstance(rec, Chunk):
                    expanded += rec.uncompressed_size
                    refused = chunk_refusal(rec, expanded)
                    if refused is not None:
                        raise RecordingError(path, f"chunk {chunks + 1}: {refused}", offset)
                    inner = breakup_chunk(rec, validate_crc=True)
                    chunks += 1
                for r in inner:
                    if isinstance(r, Channel):
                        channels[r.id] = r.topic
                    elif isinstance(r, Message) and channels.get(r.channel_id) in topics:
                        out.append((channels[r.channel_id], r.log_time, r.data))
        except RecordingError:
            raise
        except InvalidMagic:
            raise RecordingError(path, "not an MCAP file (bad magic)", 0) from None
        except Exception as exc:  # noqa: BLE001 - a corrupt length or field fails in many ways
            raise RecordingError(
                path, f"unreadable ({type(exc).__name__}: {exc})", cursor.start
            ) from None
    out.sort(key=lambda m: m[1])
    return iter(out)


def _cut_at(f: BinaryIO, offset: int) -> bool:
    """Whether the record at `offset` runs past the end of the file (a cut, not a corruption)."""
    size = f.seek(0, 2)
    if size - offset < 9:
        return True
    f.seek(offset + 1)
    length = int.from_bytes(f.read(8), "little")
    return offset + 9 + length > size


# Complexity: one check per way an MCAP file can be broken, each naming where.
def read_recording(path: str | Path, *, partial: bool = False) -> Recording:  # noqa: C901
    """Read a whole recording; RecordingError names where a broken one broke.

    With `partial`, a file that breaks (or ends without its summary) gives what it held
    up to its last complete chunk, with `broke` saying where it stopped.
    """
    p = Path(path)
    try:
        f = p.open("rb")
    except OSError as exc:
        raise RecordingError(p, f"cannot open: {exc.strerror or exc}") from None
    info: RunInfo | None = None
    robot = recorder = None
    chunked = _Chunked(p)
    chunks = 0
    expanded = 0
    complete = False
    broke: str | None = None
    cursor = _Cursor()
    with f:
        try:
            for offset, rec in _records(f, cursor):
                if isinstance(rec, Chunk):
                    expanded += rec.uncompressed_size
                    refused = chunk_refusal(rec, expanded)
                    if refused is not None:
                        raise RecordingError(p, f"chunk {chunks + 1}: {refused}", offset)
                    try:
                        records = breakup_chunk(rec, validate_crc=True)
                    except Exception as exc:  # noqa: BLE001 - decompression, CRC or record errors alike
                        raise RecordingError(
                            p,
                            f"chunk {chunks + 1} is corrupt ({type(exc).__name__}: {exc})",
                            offset,
                        ) from None
                    chunked.take(records, offset)
                    chunks += 1
                elif isinstance(rec, Metadata):
                    if rec.name == "relayd":
                        try:
                            info = RunInfo.from_metadata(rec.metadata)
                        except (KeyError, ValueError) as exc:
                            raise RecordingError(
                                p, f"bad relayd metadata ({exc})", offset
                            ) from None
                    elif rec.name == "robot":
                        robot = dict(rec.metadata)
                    elif rec.name == "recorder":
                        try:
                            recorder = recorder_counts(dict(rec.metadata))
                        except ValueError as exc:
                            raise RecordingError(
                                p, f"bad recorder metadata ({exc})", offset
                            ) from None
                elif isinstance(rec, Schema | Channel | Message):
                    chunked.take([rec], offset)
                elif isinstance(rec, Footer):
                    complete = True
        except RecordingError as exc:
            if not partial or info is None:
                raise
            broke = str(exc)
        except InvalidMagic:
            raise RecordingError(p, "not an MCAP file (bad magic)", 0) from None
        except Exception as exc:  # noqa: BLE001 - a corrupt length or field fails in many ways
            offset = cursor.start
            last = ""
            if chunked.last_t is not None:
                t0 = info.clock_t0 if info is not None else 0.0
                last = f", the last event read {chunked.last_t - t0:.3f} s into the recording"
            if isinstance(exc, EndOfFile) or _cut_at(f, offset):
                why = (
                    f"the file ends without its summary (the recorder did not finish it: "
                    f"a killed daemon or a full disk?); {chunks} complete chunk(s) before it{last}"
                )
            else:
                why = f"corrupt record ({type(exc).__name__}: {exc}); {chunks} complete chunk(s) before it{last}"
            if not partial or info is None:
                raise RecordingError(p, why, offset) from None
            broke = f"{p} at byte {offset}: {why}"
    if info is None:
        raise RecordingError(p, "no relayd metadata: not a relayd recording")
    steps = _steps(p, chunked)
    return Recording(
        p,
        info,
        steps,
        robot=robot,
        recorder=recorder,
        topics=chunked.topics,
        chunks=chunks,
        complete=complete,
        broke=broke,
    )


def _steps(p: Path, chunked: _Chunked) -> list[Step]:
    steps = []
    for seq in sorted(chunked.events):
        items = sorted(chunked.acts.get(seq, []), key=lambda x: x[0])
        if [i for i, _, _ in items] != list(range(len(items))):
            raise RecordingError(
                p, f"event {seq}: its actions are not numbered 0..{len(items) - 1}"
            )
        steps.append(
            Step(seq, chunked.events[seq], [a for _, a, _ in items], [d for _, _, d in items])
        )
    orphans = set(chunked.acts) - set(chunked.events)
    if orphans:
        raise RecordingError(
            p,
            f"actions recorded for {len(orphans)} event(s) that are not in the file "
            f"(first: event {min(orphans)})",
        )
    return steps


def join_parts(parts: list[Recording]) -> Recording:
    """The parts of one rotated run as one recording; RecordingError if they are not that.

    Replay needs a run from its first part: the brain's state at the start of part k
    comes from the events of the parts before it.
    """
    first = parts[0]
    run_id = first.info.run_id
    for k, part in enumerate(parts, start=1):
        if part.info.run_id != run_id:
            raise RecordingError(part.path, f"is from another run than {first.path}")
        if part.info.part != k:
            raise RecordingError(
                part.path,
                f"is part {part.info.part} of its run; replay needs parts 1..{part.info.part} "
                "in order (a part starts with the brain's state from the parts before)",
            )
        if k < len(parts) and (not part.complete or part.broke is not None):
            raise RecordingError(part.path, "is cut short but is not the last part given")
    if len(parts) == 1:
        return first
    steps = [s for p in parts for s in p.steps]
    topics: dict[str, int] = {}
    for p in parts:
        for topic, n in p.topics.items():
            topics[topic] = topics.get(topic, 0) + n
    last = parts[-1]
    return Recording(
        first.path,
        first.info,
        steps,
        robot=next((p.robot for p in parts if p.robot), None),
        recorder=last.recorder,
        topics=topics,
        chunks=sum(p.chunks for p in parts),
        complete=last.complete,
        broke=last.broke,
    )
