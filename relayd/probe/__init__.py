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
    quiet = structlog.make_filtering_bound_logger(logging.WARNING)
    if previous is not None and isinstance(previous["logger_factory"], structlog.stdlib.LoggerFactory):
        # relayd's own pipeline (relayd.logsetup; the command line points it at stderr):
        # its processors need stdlib loggers, so keep them and only raise the level.
        structlog.configure(wrapper_class=quiet)
    else:
        structlog.reset_defaults()
        structlog.configure(wrapper_class=quiet, logger_factory=structlog.PrintLoggerFactory(sys.stderr))
    try:
        yield
    finally:
        if previous is None:
            structlog.reset_defaults()
        else:
            structlog.configure(**previous)
