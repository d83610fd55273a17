"""`relayd probe ...`: read-only bring-up tools, one device each.

Every probe prints its answer on stdout (parseable with --json), so while it runs the
drivers' log lines go to stderr at WARNING and up; `warnings_to_stderr` does that
once for all of them and restores whatever logging the caller had.

A probe piped into a reader that stops early (`relayd probe robot | head -1`) stops
like one whose `--seconds` ran out: at its next line, quietly (no traceback, no log
line), with exit code 0, as `head` got what it asked for. `emit` is how a probe
prints so it notices.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from collections.abc import Iterator

import structlog


@contextlib.contextmanager
def warnings_to_stderr() -> Iterator[None]:
    previous = structlog.get_config() if structlog.is_configured() else None
    # The whole pipeline is replaced, processors too: the caller's may be the daemon's
    # stdlib-bound ones (add_logger_name needs a logging.Logger), which a PrintLogger breaks.
    structlog.configure(
        processors=[
            structlog.processors.add_log_level,
            structlog.processors.TimeStamper(fmt="iso"),
            structlog.dev.ConsoleRenderer(colors=False),
        ],
        wrapper_class=structlog.make_filtering_bound_logger(logging.WARNING),
        logger_factory=structlog.PrintLoggerFactory(sys.stderr),
        cache_logger_on_first_use=False,
    )
    try:
        yield
    finally:
        if previous is None:
            structlog.reset_defaults()
        else:
            structlog.configure(**previous)


def emit(text: str) -> bool:
    """Print `text` as one record on stdout now; False once the reader has gone.

    After False the probe must stop: stdout then points at /dev/null, so the
    interpreter's flush at exit does not raise a second BrokenPipeError, and later
    prints would succeed without anyone reading them.
    """
    try:
        print(text, flush=True)
    except BrokenPipeError:
        _stdout_to_devnull()
        return False
    return True


def _stdout_to_devnull() -> None:
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        return  # not a real file (a test's capture): nothing to flush at exit
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
    finally:
        os.close(devnull)
