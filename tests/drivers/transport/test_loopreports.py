"""A serial port that fails under its transport is one warning line, not an ERROR traceback.

pyserial-asyncio-fast hands a failed write to the loop's exception handler before it
tells the protocol; the 60-minute soak logged each servo pty hang-up there as asyncio
ERRORs with two tracebacks. The drivers' reconnect loop already reports the loss, so
`drivers.transport.link` turns that report into one `serial_transport_failed` warning. Real ptys.
"""

from __future__ import annotations

import asyncio
import os
import pty
import tty
from typing import Any

from structlog.testing import capture_logs

from drivers.transport.link import close_link, open_link
from tests.support import until


class _Lost(asyncio.Protocol):
    def __init__(self) -> None:
        self.closed = asyncio.Event()

    def connection_lost(self, exc: Exception | None) -> None:
        self.closed.set()


def _pty() -> tuple[int, str]:
    master, slave = pty.openpty()
    tty.setraw(master)
    name = os.ttyname(slave)
    os.close(slave)
    return master, name


async def test_a_hung_up_port_is_one_warning_and_other_reports_pass_through() -> None:
    loop = asyncio.get_running_loop()
    seen: list[dict[str, Any]] = []
    loop.set_exception_handler(lambda _lp, context: seen.append(context))
    master, name = _pty()
    try:
        transport, proto = await open_link(name, 115200, _Lost)
        os.close(master)  # the device goes away: the slave side now fails with EIO
        master = -1
        with capture_logs() as logs:

            def written_until_closed() -> bool:
                # The failed write is reported at once or on a later try.
                if proto.closed.is_set():
                    return True
                transport.write(b"\x84\x00\x70\x2e")
                return False

            await until(
                written_until_closed, "the port closed after a failed write", 10.0, poll_s=0.01
            )
        failed = [e for e in logs if e["event"] == "serial_transport_failed"]
        assert failed and failed[0]["log_level"] == "warning", logs
        assert failed[0]["port"] == name and "exc_info" not in failed[0]
        assert seen == [], "a serial I/O failure reached the previous handler"
        await close_link(transport, proto.closed)
        # Anything else still reaches the handler that was there before.
        loop.call_exception_handler({"message": "something else"})
        assert [c["message"] for c in seen] == ["something else"]
    finally:
        if master >= 0:
            os.close(master)
        loop.set_exception_handler(None)


async def test_reopening_does_not_stack_handlers() -> None:
    loop = asyncio.get_running_loop()
    handlers = []
    for _ in range(3):
        master, name = _pty()
        try:
            transport, proto = await open_link(name, 115200, _Lost)
            handlers.append(loop.get_exception_handler())
            await close_link(transport, proto.closed)
        finally:
            os.close(master)
    assert handlers[0] is handlers[1] is handlers[2]
    loop.set_exception_handler(None)


async def test_the_api_and_serial_filters_stack_once_whatever_the_order() -> None:
    from relayd.api.server import install_accept_error_limit

    loop = asyncio.get_running_loop()
    install_accept_error_limit(loop)
    master, name = _pty()
    try:
        transport, proto = await open_link(name, 115200, _Lost)
        await close_link(transport, proto.closed)
        installed = loop.get_exception_handler()
        install_accept_error_limit(
            loop
        )  # the serial filter now wraps the API's: still no second one
        transport, proto = await open_link(name, 115200, _Lost)
        await close_link(transport, proto.closed)
        assert loop.get_exception_handler() is installed
    finally:
        os.close(master)
        loop.set_exception_handler(None)
