"""Opening a byte link to a device: a serial port, a `socket://` URL or a `memory://` fake.

pyserial-asyncio-fast opens and closes the port in an executor and maps
`socket://host:port` onto a real asyncio TCP transport, so a driver written against
an `asyncio.Protocol` runs unchanged on a USB adapter, a pty, MobileSim or ser2net.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import threading
from collections.abc import Callable
from typing import Any, TypeVar

import serial
import serial_asyncio_fast
import structlog

from drivers.transport import memlink
from drivers.transport.clock import Clock
from drivers.transport.loopreports import add_report_filter

P = TypeVar("P", bound=asyncio.Protocol)

log = structlog.get_logger(__name__)

#: How long a closing link may take to report connection_lost before we close the OS
#: port ourselves (wall seconds: executor latency does not scale with the sim clock).
CLOSE_WAIT_S = 1.0


class LinkError(ConnectionError):
    """The device's port could not be opened; the message names the port."""


async def open_link(
    url: str, baudrate: int, protocol_factory: Callable[[], P]
) -> tuple[asyncio.Transport, P]:
    """Open `url` at `baudrate` and connect `protocol_factory()` to it."""
    if url.startswith(memlink.SCHEME):
        # A fake served in memory (unit tests): the same protocol, no file descriptor.
        try:
            mtransport, mprotocol = await memlink.open_memory_link(url, protocol_factory)
        except memlink.MemoryLinkError as exc:
            raise LinkError(f"cannot open {url}: {exc}") from exc
        return mtransport, mprotocol
    loop = asyncio.get_running_loop()
    add_report_filter(loop, "serial_failure", _serial_failure_report)
    if "://" in url:
        # socket://, rfc2217://, loop://: pyserial-asyncio's own path (TCP transport).
        try:
            transport, protocol = await serial_asyncio_fast.create_serial_connection(
                loop, protocol_factory, url, baudrate=baudrate
            )
        except (OSError, ValueError, Exception) as exc:  # serial.SerialException is an IOError
            raise LinkError(f"cannot open {url}: {exc}") from exc
        return transport, protocol  # type: ignore[return-value]
    # A device path: we open the Serial ourselves so that a cancelled open cannot leak it.
    # The executor keeps opening after our await is cancelled; the port it then opens
    # holds the tty's flock, and nothing but us could ever close it again.
    opening = loop.run_in_executor(None, _open_serial, url, baudrate)
    try:
        port = await asyncio.shield(opening)
    except asyncio.CancelledError:
        opening.add_done_callback(_close_opened)
        raise
    except (OSError, ValueError, Exception) as exc:  # serial.SerialException is an IOError
        raise LinkError(f"cannot open {url}: {exc}") from exc
    try:
        stransport, sprotocol = await serial_asyncio_fast.connection_for_serial(
            loop, protocol_factory, port
        )
    except BaseException:
        port.close()
        raise
    return stransport, sprotocol  # type: ignore[return-value]


def _serial_failure_report(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> bool:
    """A serial transport's fatal I/O error as one warning line (a drivers.transport.loopreports filter).

    pyserial-asyncio-fast reports a port that fails under it (a USB adapter pulled, a pty
    hung up) to the loop's exception handler, which asyncio logs at ERROR with two
    tracebacks, and then tells the protocol through connection_lost. The driver's
    reconnect loop already logs that loss and counts it in health(); an unplugged device
    is an expected event, not a bug, so here it is one warning without a traceback.
    """
    exc = context.get("exception")
    transport = context.get("transport")
    if not (
        isinstance(transport, serial_asyncio_fast.SerialTransport) and isinstance(exc, OSError)
    ):
        return False
    port = serial_port(transport)
    log.warning(
        "serial_transport_failed",
        port=port.port if port is not None else None,
        what=context.get("message"),
        error=str(exc),
    )
    return True


class LockedSerial(serial.Serial):
    """A pyserial port whose close() may be called from any thread, any number of times.

    pyserial-asyncio closes the port in an executor thread; our bounded close path
    may close it too when that background close never comes. Plain pyserial close()
    is not idempotent across threads (two threads can both see the fd open and
    os.close it twice, the second time perhaps a fresh port's fd).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._close_lock = threading.Lock()
        super().__init__(*args, **kwargs)

    def close(self) -> None:
        with self._close_lock:
            super().close()


def _open_serial(url: str, baudrate: int) -> LockedSerial:
    # flock the tty so two daemons (or a daemon and a probe) never share a robot.
    return LockedSerial(url, baudrate=baudrate, exclusive=True)


def _close_opened(fut: asyncio.Future[LockedSerial]) -> None:
    if not fut.cancelled() and fut.exception() is None:
        fut.result().close()
        log.info("serial_open_cancelled_closed", port=fut.result().port)


#: The kernel's table of file locks: flock(2) holders, with their PID and inode.
PROC_LOCKS = "/proc/locks"


def lock_holder(url: str, proc_locks: str = PROC_LOCKS) -> int | None:
    """The PID that holds `url`'s flock now (0: held, PID not visible here), or None.

    Read from /proc/locks, without opening the port: opening a tty is already touching
    the device (DTR rises), which a check before start must not do. None as well when
    `url` is not a device path (socket://, memory://), is missing, or the table cannot
    be read (not Linux): the open itself still refuses a locked port then.
    """
    if not url or "://" in url:
        return None
    try:
        st = os.stat(url)
        with open(proc_locks, encoding="ascii", errors="replace") as table:
            lines = table.read().splitlines()
    except OSError:
        return None
    inode = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    for line in lines:
        # "1: FLOCK  ADVISORY  WRITE 1234 00:19:567 0 EOF"; waiters ("1: -> FLOCK ...") hold nothing.
        fields = line.split()
        if len(fields) < 6 or fields[1] != "FLOCK" or fields[5] != inode:
            continue
        try:
            return int(fields[4])
        except ValueError:
            return 0
    return None


def holder_text(pid: int) -> str:
    """`PID 1234 (relayd run -c /etc/relayd/relayd.toml)`, as much as can be read."""
    if pid <= 0:
        return "a process whose PID is not visible here"
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            cmdline = f.read(512).replace(b"\0", b" ").decode(errors="replace").strip()
    except OSError:
        cmdline = ""
    return f"PID {pid} ({cmdline})" if cmdline else f"PID {pid}"


def held_ports(ports: list[tuple[str, str]]) -> list[str]:
    """One line per (key, url) whose port another process holds, naming it and its holder."""
    return [
        f"{key}: {url} is in use by {holder_text(pid)}; stop that process first "
        "(two programs must never share a device)"
        for key, url in ports
        if (pid := lock_holder(url)) is not None
    ]


def serial_port(transport: asyncio.BaseTransport | None) -> serial.Serial | None:
    """The OS serial port under a serial transport (None for TCP and memory links)."""
    if isinstance(transport, serial_asyncio_fast.SerialTransport):
        return transport.serial
    return None


async def close_link(
    transport: asyncio.Transport,
    closed: asyncio.Event,
    *,
    abort: bool = False,
    timeout_s: float = CLOSE_WAIT_S,
) -> bool:
    """Close `transport`, wait (bounded) for its `closed` event, and always end with the port closed.

    `closed` is set by the protocol's connection_lost. pyserial-asyncio reports that
    only after closing the port in a background task and an executor: a task that is
    cancelled, never scheduled or stuck (tcdrain on a dead adapter) would otherwise
    leave the port open and flocked forever, and every reopen would fail. So after the
    wait, or when cancelled, a port still open is closed here. `abort` drops
    unwritten bytes instead of draining them. Returns True if connection_lost came.
    """
    port = serial_port(transport)
    if not transport.is_closing():
        if abort:
            transport.abort()
        else:
            transport.close()
    try:
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(timeout_s):
                await closed.wait()
    finally:
        if port is not None and port.is_open:
            force_close(transport)
    return closed.is_set()


def force_close(transport: asyncio.BaseTransport) -> None:
    """Close a serial transport's OS port now, without waiting for its background close."""
    port = serial_port(transport)
    if port is None or not port.is_open:
        return
    log.warning("serial_close_forced", port=port.port)
    if isinstance(transport, serial_asyncio_fast.SerialTransport):
        # A write that never drained keeps a writer on the fd: drop it before the fd goes.
        transport.flush()
        if not transport.is_closing():
            transport.abort()
    with contextlib.suppress(OSError, serial.SerialException):
        port.reset_output_buffer()  # a real tty's close() would wait for it to drain
    port.close()


def port_missing(url: str) -> bool:
    """True when `url` is a device path that is not there now (USB adapter unplugged)."""
    if not url or "://" in url:  # no port at all (an HTTP device), or not a device path
        return False
    return not os.path.exists(url)


#: How often a reconnect loop looks for an unplugged port to come back (clock seconds).
REPLUG_POLL_S = 0.1


async def wait_before_retry(url: str, delay_s: float, clock: Clock, stop: asyncio.Event) -> None:
    """Wait `delay_s` clock seconds before the next open of `url`, or less.

    Returns early when `stop` is set, and also as soon as an unplugged port (its path
    missing when the wait began) exists again: a replugged adapter is retried at once
    instead of after a backoff that grew while it was away. Looking for a path is
    cheap, so the short poll costs nothing; a port that is present but failing still
    waits the whole backoff.
    """
    absent = port_missing(url)
    with contextlib.suppress(TimeoutError):
        async with clock.timeout(delay_s):
            if not absent:
                await stop.wait()
                return
            while not stop.is_set() and port_missing(url):
                with contextlib.suppress(TimeoutError):
                    async with clock.timeout(REPLUG_POLL_S):
                        await stop.wait()


def set_baudrate(transport: asyncio.BaseTransport, baudrate: int) -> None:
    """Change the baud rate of an open serial transport (no-op on TCP and memory links)."""
    if isinstance(transport, serial_asyncio_fast.SerialTransport):
        port = transport.serial
        if port is not None and port.is_open:
            port.baudrate = baudrate
