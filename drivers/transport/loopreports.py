"""Filters in front of an event loop's exception handler, each installed once per loop.

asyncio reports some expected events through the loop's exception handler, which logs
them at ERROR with tracebacks: a serial port failing under its transport (drivers.transport.link),
accept() failing under descriptor exhaustion (relayd.api.server). Each filter takes the
reports it knows and passes every other one to the handler that was there before it.
The set of filters per loop is kept here, not read from the handler in force: another
filter installed later wraps the earlier one, so the top handler alone cannot say.
"""

from __future__ import annotations

import asyncio
import weakref
from collections.abc import Callable
from typing import Any

#: A filter: True if it has dealt with the report, False to pass it on.
ReportFilter = Callable[[asyncio.AbstractEventLoop, dict[str, Any]], bool]

_INSTALLED: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, set[str]] = (
    weakref.WeakKeyDictionary()
)


def add_report_filter(
    loop: asyncio.AbstractEventLoop, name: str, report_filter: ReportFilter
) -> None:
    """Put `report_filter` in front of `loop`'s exception handler, unless `name` is there already."""
    names = _INSTALLED.setdefault(loop, set())
    if name in names:
        return
    names.add(name)
    previous = loop.get_exception_handler()

    def handler(lp: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        if report_filter(lp, context):
            return
        if previous is not None:
            previous(lp, context)
        else:
            lp.default_exception_handler(context)

    loop.set_exception_handler(handler)
