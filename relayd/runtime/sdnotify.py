"""systemd's notify protocol (sd_notify(3)), written in the project.

One AF_UNIX/SOCK_DGRAM datagram of newline-separated KEY=value lines per call to
$NOTIFY_SOCKET ('@' prefix = Linux abstract namespace). Not under systemd (no
NOTIFY_SOCKET) every call is a no-op. The watchdog is enabled when $WATCHDOG_USEC is
set and $WATCHDOG_PID is unset or names this process; the daemon should pet at half
that interval, and only while its control loop ticks.

A notification that cannot be delivered is logged and counted, never raised: losing
one STATUS line must not take the robot down.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Mapping

import structlog

log = structlog.get_logger(__name__)


class SdNotifier:
    """Send READY/STATUS/STOPPING/WATCHDOG to systemd when running under it."""

    def __init__(self, environ: Mapping[str, str] | None = None, *, pid: int | None = None) -> None:
        env = os.environ if environ is None else environ
        pid = os.getpid() if pid is None else pid
        self.errors = 0
        self._address: str | bytes | None = None
        raw = env.get("NOTIFY_SOCKET", "")
        if raw.startswith("@"):
            self._address = b"\0" + raw[1:].encode()
        elif raw.startswith("/"):
            self._address = raw
        elif raw:
            log.warning("sd_notify_bad_socket", notify_socket=raw)
        self.enabled: bool = self._address is not None
        self.watchdog_interval_s: float | None = None
        usec = env.get("WATCHDOG_USEC", "")
        watchdog_pid = env.get("WATCHDOG_PID", "")
        if usec:
            try:
                usec_value = int(usec)
            except ValueError:
                usec_value = 0
                log.warning("sd_watchdog_bad_usec", watchdog_usec=usec)
            for_us = not watchdog_pid or watchdog_pid == str(pid)
            if usec_value > 0 and for_us and self.enabled:
                # sd_watchdog_enabled(3): pet at half the interval.
                self.watchdog_interval_s = usec_value / 2_000_000
        self._sock: socket.socket | None = None

    def _send(self, message: str) -> bool:
        if self._address is None:
            return False
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                # A datagram either goes now or not at all: never block the event loop.
                self._sock.setblocking(False)
            self._sock.sendto(message.encode(), self._address)
        except OSError as exc:
            self.errors += 1
            log.warning("sd_notify_failed", message=message.split("=", 1)[0], error=str(exc))
            return False
        return True

    def notify(self, **fields: str | int) -> bool:
        """Send arbitrary assignments, e.g. notify(READY=1, STATUS="up"); True if sent."""
        lines = []
        for key, value in fields.items():
            text = str(value).replace("\n", " ")
            lines.append(f"{key}={text}")
        return self._send("\n".join(lines))

    def ready(self) -> None:
        self.notify(READY=1, STATUS="running")

    def status(self, text: str) -> None:
        self.notify(STATUS=text)

    def stopping(self) -> None:
        self.notify(STOPPING=1, STATUS="stopping")

    def watchdog(self) -> None:
        if self.watchdog_interval_s is not None:
            self.notify(WATCHDOG=1)

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
