"""A one-line progress display for `relayd sim` on a terminal.

Rewrites a single line (carriage return, no newline), cut to the terminal's width so
it never wraps, at most every `every_s` wall seconds, so a fast simulation does not flood the terminal; prints nothing when the
stream is not a terminal (CI logs, pipes), where the summary alone is useful.
"""

from __future__ import annotations

import os
import shutil
import sys
import time
from typing import Any, TextIO

#: The width taken when the terminal reports none.
DEFAULT_COLUMNS = 80
#: A relay's reason while its daemon has not had the base's first SIP: it is starting.
STARTING_REASON = "no_sip"


def progress_text(
    rec: dict[str, Any],
    duration_s: float,
    width: int | None = None,
    started: set[str] | None = None,
) -> str:
    """The progress line for one trace record, at most `width` characters if given.

    Time, leader and throughput come first; relays follow while they fit, and the
    ones that do not are counted (`+2`) rather than wrapped onto a new line,
    which a carriage return cannot rewrite. A relay reads `name:state/RSSI^l/gap`;
    with `started` (the relays seen past their first SIP), one not in it that waits
    for its first SIP reads `starting`, not the `fault` its daemon reports.
    """
    parts = [
        f"t={rec['t']:.1f}/{duration_s:.0f}s",
        f"leader=({rec['leader']['x']:.1f},{rec['leader']['y']:.1f})",
        f"e2e={rec['e2e_mbps']:4.1f}Mbps" + (" BROKEN" if rec["broken"] else ""),
    ]
    relays = []
    for r in rec["relays"]:
        rssi = r["rssi_l_dbm"]
        state = r["state"]
        if started is not None and r["name"] not in started and r.get("reason") == STARTING_REASON:
            state = "starting"
        relays.append(
            f"{r['name']}:{state}"
            + (f"/{rssi:.0f}dBm" if isinstance(rssi, int | float) else "")
            + f"/{r['gap_m']:.1f}m"
        )
    text = " ".join(parts + relays)
    if width is None or len(text) <= width:
        return text
    for shown in range(len(relays) - 1, -1, -1):
        text = " ".join([*parts, *relays[:shown], f"+{len(relays) - shown}"])
        if len(text) <= width:
            return text
    return text[:width]


class ProgressLine:
    """Call it with each trace record; `close()` ends the line."""

    def __init__(
        self,
        duration_s: float,
        stream: TextIO | None = None,
        every_s: float = 0.25,
        enabled: bool | None = None,
    ) -> None:
        self.stream = sys.stderr if stream is None else stream
        self.duration_s = duration_s
        self.every_s = every_s
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self._last = 0.0
        self._width = 0
        self.lines = 0
        self._started: set[str] = set()

    def __call__(self, rec: dict[str, Any]) -> None:
        if not self.enabled:
            return
        for r in rec["relays"]:
            if r.get("reason") != STARTING_REASON:
                self._started.add(r["name"])
        now = time.monotonic()
        if now - self._last < self.every_s:
            return
        self._last = now
        # One column short of the terminal: writing the last column wraps on some terminals.
        text = progress_text(rec, self.duration_s, self._columns() - 1, self._started)
        pad = max(0, self._width - len(text))
        self._width = len(text)
        self.stream.write("\r" + text + " " * pad)
        self.stream.flush()
        self.lines += 1

    def _columns(self) -> int:
        # Asked each time: the user may resize the terminal during a long run.
        # A terminal that reports 0 columns (a serial console, some CI ptys) has no known
        # width: take the usual 80 rather than cutting the line to nothing useful.
        try:
            columns = os.get_terminal_size(self.stream.fileno()).columns
        except (AttributeError, OSError, ValueError):
            columns = shutil.get_terminal_size().columns
        return max(20, columns) if columns > 0 else DEFAULT_COLUMNS

    def close(self) -> None:
        if self.enabled and self.lines:
            self.stream.write("\n")
            self.stream.flush()
