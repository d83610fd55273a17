"""Opening a byte link to a device: a serial port, a `socket://` URL or a `memory://` fake.

pyserial-asyncio-fast opens and closes the port in an executor and maps
`socket://host:port` onto a real asyncio TCP transport, so a driver written against
an `asyncio.Protocol` runs unchanged on a USB adapter, a pty, MobileSim or ser2net.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
from collections.abc import Callable
from typing import TypeVar

import serial_asyncio_fast

from drivers import memlink
from drivers.clock import Clock

P = TypeVar("P", bound=asyncio.Protocol)


class LinkError(ConnectionError):
    """The device's port could not be opened; the message names the port."""


async def open_link(url: str, baudrate: int, protocol_factory: Callable[[], P]) -> tuple[asyncio.Transport, P]:
    """Open `url` at `baudrate` and connect `protocol_factory()` to it."""
    if url.startswith(memlink.SCHEME):
        # A fake served in memory (unit tests): the same protocol, no file descriptor.
        try:
            mtransport, mprotocol = await memlink.open_memory_link(url, protocol_factory)
        except memlink.MemoryLinkError as exc:
            raise LinkError(f"cannot open {url}: {exc}") from exc
        return mtransport, mprotocol
    loop = asyncio.get_running_loop()
    kwargs: dict[str, object] = {"baudrate": baudrate}
    if not url.startswith(("socket://", "rfc2217://")):
        # flock the tty so two daemons (or a daemon and a probe) never share a robot.
        kwargs["exclusive"] = True
    try:
        transport, protocol = await serial_asyncio_fast.create_serial_connection(
            loop, protocol_factory, url, **kwargs
        )
    except (OSError, ValueError, Exception) as exc:  # serial.SerialException is an IOError
        raise LinkError(f"cannot open {url}: {exc}") from exc
    return transport, protocol  # type: ignore[return-value]


def port_missing(url: str) -> bool:
    """True when `url` is a device path that is not there now (USB adapter unplugged)."""
    if "://" in url:
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
