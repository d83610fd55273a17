"""Opening a byte link to a device: a serial port or a `socket://` URL.

pyserial-asyncio-fast opens and closes the port in an executor and maps
`socket://host:port` onto a real asyncio TCP transport, so a driver written against
an `asyncio.Protocol` runs unchanged on a USB adapter, a pty, MobileSim or ser2net.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import TypeVar

import serial_asyncio_fast

P = TypeVar("P", bound=asyncio.Protocol)


class LinkError(ConnectionError):
    """The device's port could not be opened; the message names the port."""


async def open_link(url: str, baudrate: int, protocol_factory: Callable[[], P]) -> tuple[asyncio.Transport, P]:
    """Open `url` at `baudrate` and connect `protocol_factory()` to it."""
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


def set_baudrate(transport: asyncio.BaseTransport, baudrate: int) -> None:
    """Change the baud rate of an open serial transport (no-op on TCP links)."""
    port = getattr(transport, "serial", None)
    if port is not None and getattr(port, "is_open", False):
        port.baudrate = baudrate
