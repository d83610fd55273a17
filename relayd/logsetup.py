"""structlog configuration: one event per line, key=value on a terminal, JSON for the journal.

In JSON mode each line is prefixed with the syslog priority (`<4>`), which journald
parses from stdout by default, so `journalctl -p warning -u relayd` works.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence
from typing import Any

import structlog

_PRIORITY = {"debug": 7, "info": 6, "warning": 4, "error": 3, "critical": 2, "exception": 3}


def _journal_priority(_: Any, method: str, rendered: str) -> str:
    return f"<{_PRIORITY.get(method, 6)}>{rendered}"


class StdStream:
    """sys.stdout or sys.stderr looked up at each write, not at configuration time.

    Logging configured once must survive the process swapping its standard streams
    (pytest's capture does, per test); holding the old object would write into a
    closed file.
    """

    def __init__(self, name: str) -> None:
        if name not in ("stdout", "stderr"):
            raise ValueError(f"not a standard stream: {name!r}")
        self._name = name

    @property
    def _stream(self) -> Any:
        return getattr(sys, self._name)

    def write(self, text: str) -> int:
        return int(self._stream.write(text))

    def flush(self) -> None:
        self._stream.flush()

    def isatty(self) -> bool:
        return bool(getattr(self._stream, "isatty", lambda: False)())


def setup_logging(level: str = "info", fmt: str = "console", stream: Any = None, *,
                  journal: bool = True, extra: Sequence[Any] = ()) -> None:
    """Configure structlog and route stdlib loggers (aiohttp, asyncio) through it.

    Logs go to stdout by default (journald reads it); pass `StdStream("stderr")` for
    commands whose stdout is data. `journal=False` drops the `<N>` priority prefix of
    JSON lines, for files read by tools rather than journald (sim.log). `extra`
    processors add fields to every line, structlog's and the stdlib's alike.
    """
    stream = stream or StdStream("stdout")
    numeric = getattr(logging, level.upper())
    shared: list[Any] = [
        structlog.contextvars.merge_contextvars,
        *extra,
        structlog.processors.add_log_level,
        structlog.processors.TimeStamper(fmt="iso", utc=True),
    ]
    if fmt == "json":
        renderer: list[Any] = [
            structlog.processors.dict_tracebacks,
            structlog.processors.JSONRenderer(),
            *([_journal_priority] if journal else []),
        ]
    else:
        renderer = [structlog.dev.ConsoleRenderer(colors=stream.isatty())]
    structlog.configure(
        processors=[*shared, structlog.processors.StackInfoRenderer(), *renderer],
        wrapper_class=structlog.make_filtering_bound_logger(numeric),
        logger_factory=structlog.PrintLoggerFactory(stream),
        cache_logger_on_first_use=False,
    )
    handler = logging.StreamHandler(stream)
    handler.setFormatter(
        structlog.stdlib.ProcessorFormatter(
            foreign_pre_chain=shared,
            processors=[structlog.stdlib.ProcessorFormatter.remove_processors_meta,
                        *(p for p in renderer if p is not _journal_priority)],
        )
    )
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(max(numeric, logging.INFO))
    logging.getLogger("aiohttp.access").setLevel(logging.WARNING)
