"""structlog configuration: one event per line, key=value on a terminal, JSON for the journal.

In JSON mode each line is prefixed with the syslog priority (`<4>`), which journald
parses from stdout by default, so `journalctl -p warning -u relayd` works.

Every line goes through one pipeline: structlog events are handed to the stdlib root
logger, and stdlib records (aiohttp, asyncio, `warnings.warn` via `captureWarnings`)
are rendered by the same processors, so each has the prefix, a level and a timestamp.
Tracebacks never carry frame locals: a login routine's locals hold the AP password.
aiohttp's report of a malformed request (a client's mistake, not ours) is turned into
one rate-limited INFO line without a traceback.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Sequence
from typing import Any, TextIO

import structlog
from aiohttp.http_exceptions import HttpProcessingError

from relayd.runtime.ratelimit import LogRateLimit

_PRIORITY = {"debug": 7, "info": 6, "warning": 4, "error": 3, "critical": 2, "exception": 3}
#: Malformed-request lines: the first at once, then at most one per this period with a count.
BAD_REQUEST_LOG_EVERY_S = 10.0
#: Loggers of relayd's own code: they follow `log.level` down to debug; the root (aiohttp,
#: asyncio, everything else) stays at info or above.
OWN_LOGGERS = ("relayd", "drivers", "bench")


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
    def _stream(self) -> TextIO:
        return sys.stdout if self._name == "stdout" else sys.stderr

    def write(self, text: str) -> int:
        return int(self._stream.write(text))

    def flush(self) -> None:
        self._stream.flush()

    def isatty(self) -> bool:
        return self._stream.isatty()


class BadRequestFilter(logging.Filter):
    """aiohttp.server's "Error handling request" for a malformed request: INFO, no traceback.

    A malformed request is the client's mistake and anyone can send one; logged with a
    traceback at ERROR it looks like a relayd bug and fills the journal. The line keeps
    what matters (peer, aiohttp's message) and is rate-limited with a count.
    """

    def __init__(self, every_s: float = BAD_REQUEST_LOG_EVERY_S) -> None:
        super().__init__("aiohttp.server")
        self.limit = LogRateLimit(every_s)

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if not isinstance(exc, HttpProcessingError):
            return True
        count = self.limit.hit("bad_request", time.monotonic())
        if count is None:
            return False
        peer = record.args[0] if isinstance(record.args, tuple) and record.args else None
        record.msg = "api_malformed_request from %s: %s (%d in the last %g s at most)"
        record.args = (peer, exc.message or type(exc).__name__, count, self.limit.every_s)
        record.levelno, record.levelname = logging.INFO, "INFO"
        record.exc_info, record.exc_text = None, None
        return True


_BAD_REQUEST_FILTER = BadRequestFilter()


def _renderers(fmt: str, stream: Any, journal: bool) -> list[Any]:
    if fmt == "json":
        out: list[Any] = [
            # Never the frames' locals: they hold passwords (the airOS login's form).
            structlog.processors.ExceptionRenderer(
                structlog.tracebacks.ExceptionDictTransformer(show_locals=False)
            ),
            structlog.processors.JSONRenderer(),
        ]
        return [*out, _journal_priority] if journal else out
    # rich's traceback (ConsoleRenderer's default when rich is installed) shows locals.
    return [
        structlog.dev.ConsoleRenderer(
            colors=stream.isatty(), exception_formatter=structlog.dev.plain_traceback
        )
    ]


def setup_logging(
    level: str = "info",
    fmt: str = "console",
    stream: Any = None,
    *,
    journal: bool = True,
    extra: Sequence[Any] = (),
) -> None:
    """Configure structlog and route every stdlib logger (aiohttp, asyncio, warnings) through it.

    Logs go to stdout by default (journald reads it); pass `StdStream("stderr")` for
    commands whose stdout is data. `journal=False` drops the `<N>` priority prefix of
    JSON lines, for files read by tools rather than journald (sim.log). `extra`
    processors add fields to every line, structlog's and the stdlib's alike.
    """
    stream = stream or StdStream("stdout")
    numeric = logging.getLevelNamesMapping()[level.upper()]
    shared: list[Any] = [
        structlog.contextvars.merge_contextvars,
        *extra,
        structlog.stdlib.add_logger_name,
        structlog.processors.add_log_level,
        structlog.processors.TimeStamper(fmt="iso", utc=True),
    ]
    structlog.configure(
        processors=[
            *shared,
            structlog.processors.StackInfoRenderer(),
            structlog.stdlib.ProcessorFormatter.wrap_for_formatter,
        ],
        # Filtering happens here, before any work, so debug calls cost nothing at info.
        wrapper_class=structlog.make_filtering_bound_logger(numeric),
        logger_factory=structlog.stdlib.LoggerFactory(),
        cache_logger_on_first_use=False,
    )
    handler = logging.StreamHandler(stream)
    handler.setFormatter(
        structlog.stdlib.ProcessorFormatter(
            foreign_pre_chain=[*shared, structlog.stdlib.ExtraAdder()],
            processors=[
                structlog.stdlib.ProcessorFormatter.remove_processors_meta,
                *_renderers(fmt, stream, journal),
            ],
        )
    )
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(max(numeric, logging.INFO))
    for name in OWN_LOGGERS:
        logging.getLogger(name).setLevel(numeric)
    logging.getLogger("aiohttp.access").setLevel(logging.WARNING)
    server = logging.getLogger("aiohttp.server")
    if _BAD_REQUEST_FILTER not in server.filters:
        server.addFilter(_BAD_REQUEST_FILTER)
    logging.captureWarnings(True)
