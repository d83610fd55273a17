"""`relayd probe ...`: read-only bring-up tools, one device each.

Every probe prints its answer on stdout (parseable with --json), so while it runs the
drivers' log lines go to stderr at WARNING and up; `warnings_to_stderr` does that
once for all of them and restores whatever logging the caller had.
"""

from __future__ import annotations

import contextlib
import logging
import sys
from collections.abc import Iterator

import structlog


@contextlib.contextmanager
def warnings_to_stderr() -> Iterator[None]:
    previous = structlog.get_config() if structlog.is_configured() else None
    # The whole pipeline is replaced, processors too: the caller's may be the daemon's
    # stdlib-bound ones (add_logger_name needs a logging.Logger), which a PrintLogger breaks.
    structlog.configure(
        processors=[structlog.processors.add_log_level,
                    structlog.processors.TimeStamper(fmt="iso"),
                    structlog.dev.ConsoleRenderer(colors=False)],
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
