"""What a recording says about itself: MCAP metadata records, written and read.

- `relayd`: the relayd version, the recording format, the start time (UTC and the
  daemon clock's reading then), the run id and part number of a rotated series, and
  the effective config as JSON with secrets removed.
- `robot`: the base's identity from its SYNC2 answer (name, class, subclass), written
  when the robot first connects (and again if a different robot answers).
- `recorder`: written on a normal shutdown: events, actions and events lost.

Secrets: relayd's config never holds a secret value, only where one comes from (an
environment variable's name or a file's path), and those are kept because replay
needs a config that validates. What is removed: credentials written into a URL
(`http://user:password@host`), the only place a secret value could still slip into
the TOML.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from relayd import __version__
from relayd.config.model import Settings
from relayd.record.codec import FORMAT


def strip_userinfo(url: str) -> str:
    """A URL without any `user:password@` part."""
    parts = urlsplit(url)
    if "@" not in parts.netloc:
        return url
    host = parts.netloc.rsplit("@", 1)[1]
    return urlunsplit(parts._replace(netloc=host))


def recordable_config(settings: Settings) -> dict[str, Any]:
    """The effective config, as JSON data, safe to write into a file that leaves the robot."""
    doc = settings.model_dump(mode="json")

    def scrub(node: Any) -> Any:
        if isinstance(node, dict):
            return {k: scrub(v) for k, v in node.items()}
        if isinstance(node, list):
            return [scrub(v) for v in node]
        if isinstance(node, str) and "://" in node:
            return strip_userinfo(node)
        return node

    scrubbed: dict[str, Any] = scrub(doc)
    return scrubbed


@dataclass(frozen=True, slots=True)
class RunInfo:
    """The `relayd` metadata record of one file."""

    version: str
    format: int
    start_time: str
    start_unix_ns: int
    clock_t0: float
    run_id: str
    part: int
    config: dict[str, Any]

    def to_metadata(self) -> dict[str, str]:
        return {
            "version": self.version,
            "format": str(self.format),
            "start_time": self.start_time,
            "start_unix_ns": str(self.start_unix_ns),
            "clock_t0": repr(self.clock_t0),
            "run_id": self.run_id,
            "part": str(self.part),
            "config": json.dumps(self.config, sort_keys=True, separators=(",", ":")),
        }

    @classmethod
    def from_metadata(cls, data: dict[str, str]) -> RunInfo:
        """Raises KeyError/ValueError on a record that is not ours."""
        return cls(
            version=data["version"],
            format=int(data["format"]),
            start_time=data["start_time"],
            start_unix_ns=int(data["start_unix_ns"]),
            clock_t0=float(data["clock_t0"]),
            run_id=data["run_id"],
            part=int(data["part"]),
            config=_config_object(data["config"]),
        )


def _config_object(text: str) -> dict[str, Any]:
    """The recorded config: a JSON object, or ValueError saying what it is instead."""
    try:
        config = json.loads(text)
    except RecursionError:
        raise ValueError("config: nested too deeply to be a relayd config") from None
    if not isinstance(config, dict):
        raise ValueError(f"config: a JSON {type(config).__name__}, not an object")
    return config


#: The recorder's counts in its metadata record.
RECORDER_COUNTS = ("events", "actions", "dropped")


def recorder_counts(data: dict[str, str]) -> dict[str, str]:
    """The recorder's metadata, its counts checked; ValueError naming a count that is not one."""
    for key in RECORDER_COUNTS:
        value = data.get(key)
        if value is not None and not (value.isascii() and value.isdigit()):
            raise ValueError(f"{key}: {value[:40]!r} is not a count")
    return data


def run_info(
    settings: Settings, *, start_unix_ns: int, clock_t0: float, run_id: str, part: int
) -> RunInfo:
    start = datetime.fromtimestamp(start_unix_ns / 1e9, tz=UTC).isoformat(timespec="milliseconds")
    return RunInfo(
        version=__version__,
        format=FORMAT,
        start_time=start,
        start_unix_ns=start_unix_ns,
        clock_t0=clock_t0,
        run_id=run_id,
        part=part,
        config=recordable_config(settings),
    )
