"""ProcfsWriter: the fake Wi-Fi adapter, a /proc/net/wireless-format file.

The simulator calls `write(level_dbm)` at sample_hz with the simulated RSSI at the
current scan angle; a real `ProcfsSource` pointed at the file reads it exactly as it
reads the kernel's file. Each `write` is one update: the level carries the '.' UPDATED
mark and the `misc` discard counter (cfg80211: rx drop misc) grows by one, so a reader
can tell a new update from a re-read even when the level repeats. The file is replaced
atomically (temp file + os.replace), so a reader never sees a torn file.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from drivers.wifi.parsers import PROC_HEADER_1, PROC_HEADER_2

#: the kernel's row format (net/wireless/wext-proc.c)
_ROW = "%6s: %04x  %3d%c  %3d%c  %3d%c  %6d %6d %6d %6d %6d   %6d\n"


def format_proc_row(
    interface: str,
    *,
    status: int = 0,
    link: int = 0,
    link_updated: bool = False,
    level: int = 0,
    level_updated: bool = False,
    noise: int = -256,
    noise_updated: bool = False,
    nwid: int = 0,
    crypt: int = 0,
    frag: int = 0,
    retry: int = 0,
    misc: int = 0,
    missed_beacon: int = 0,
) -> str:
    """One interface row exactly as the kernel prints it."""
    return _ROW % (
        interface,
        status,
        link,
        "." if link_updated else " ",
        level,
        "." if level_updated else " ",
        noise,
        "." if noise_updated else " ",
        nwid,
        crypt,
        frag,
        retry,
        misc,
        missed_beacon,
    )


def link_quality_for(level_dbm: int) -> int:
    """cfg80211's wext quality: level + 110 clamped to 0..70 (wext-compat.c)."""
    return max(0, min(70, level_dbm + 110))


class ProcfsWriter:
    """Writes `path` in /proc/net/wireless format for one interface (plus fixed extras)."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        interface: str = "wlan1",
        *,
        other_rows: Mapping[str, str] | None = None,
    ) -> None:
        self.path = Path(path)
        self.interface = interface
        #: extra interfaces' rows (already formatted) kept in the file, e.g. the laptop's own
        self.other_rows = dict(other_rows or {})
        self.updates = 0
        self._row: str | None = None
        self._tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.{id(self):x}.tmp")

    def write(
        self, level_dbm: float, link: int | None = None, noise_dbm: float | None = -95
    ) -> None:
        """Publish one update with this level (any integer dBm, even impossible ones).

        `link` defaults to cfg80211's quality for the level; `noise_dbm=None` prints the
        kernel's -256 "invalid" noise without its mark, as cfg80211 does.
        """
        level = round(level_dbm)
        self.updates += 1
        self._row = format_proc_row(
            self.interface,
            link=link_quality_for(level) if link is None else int(link),
            link_updated=True,
            level=level,
            level_updated=True,
            noise=-256 if noise_dbm is None else round(noise_dbm),
            noise_updated=noise_dbm is not None,
            misc=self.updates,
        )
        self._publish()

    def write_disassociated(self) -> None:
        """The row the kernel prints when not associated: zeros, no marks."""
        self.updates += 1
        self._row = format_proc_row(self.interface)
        self._publish()

    def remove_interface(self) -> None:
        """The adapter is unplugged: its row disappears (the file stays)."""
        self._row = None
        self._publish()

    def unlink(self) -> None:
        """Delete the file (as on a machine without any wireless device)."""
        self.path.unlink(missing_ok=True)

    def text(self) -> str:
        rows = [r if r.endswith("\n") else r + "\n" for r in self.other_rows.values()]
        if self._row is not None:
            rows.append(self._row)
        return f"{PROC_HEADER_1}\n{PROC_HEADER_2}\n" + "".join(rows)

    def _publish(self) -> None:
        data = self.text().encode("ascii")
        with open(self._tmp, "wb") as f:
            f.write(data)
        os.replace(self._tmp, self.path)
