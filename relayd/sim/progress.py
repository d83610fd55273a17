"""A one-line progress display for `relayd sim` on a terminal.

Rewrites a single line (carriage return, no newline) at most every `every_s` wall
seconds, so a fast simulation does not flood the terminal; prints nothing when the
stream is not a terminal (CI logs, pipes), where the summary alone is useful.
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO


def progress_text(rec: dict[str, Any], duration_s: float) -> str:
    """The progress line for one trace record."""
    parts = [f"t={rec['t']:6.1f}/{duration_s:.0f}s",
             f"leader=({rec['leader']['x']:.1f},{rec['leader']['y']:.1f})",
             f"e2e={rec['e2e_mbps']:4.1f}Mbps" + (" BROKEN" if rec["broken"] else "")]
    for r in rec["relays"]:
        rssi = r["rssi_l_dbm"]
        parts.append(f"{r['name']}:{r['state']}"
                     + (f"/{rssi:.0f}dBm" if isinstance(rssi, int | float) else "")
                     + f"/gap {r['gap_m']:.1f}m")
    return "  ".join(parts)


class ProgressLine:
    """Call it with each trace record; `close()` ends the line."""

    def __init__(self, duration_s: float, stream: TextIO | None = None, every_s: float = 0.25,
                 enabled: bool | None = None) -> None:
        self.stream = sys.stderr if stream is None else stream
        self.duration_s = duration_s
        self.every_s = every_s
        isatty = getattr(self.stream, "isatty", None)
        self.enabled = bool(isatty and isatty()) if enabled is None else enabled
        self._last = 0.0
        self._width = 0
        self.lines = 0

    def __call__(self, rec: dict[str, Any]) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._last < self.every_s:
            return
        self._last = now
        text = progress_text(rec, self.duration_s)
        pad = max(0, self._width - len(text))
        self._width = len(text)
        self.stream.write("\r" + text + " " * pad)
        self.stream.flush()
        self.lines += 1

    def close(self) -> None:
        if self.enabled and self.lines:
            self.stream.write("\n")
            self.stream.flush()
