"""The wifi driver the config names, built by `make_source`."""

from __future__ import annotations

import os
from typing import Literal

from drivers.transport.clock import REAL_CLOCK, Clock
from drivers.wifi.nl80211 import Nl80211Source
from drivers.wifi.parsers import RSSI_MIN_DBM
from drivers.wifi.sources import (
    PROC_NET_WIRELESS,
    IwSource,
    ProcfsSource,
    RssiSource,
)

SourceKind = Literal["nl80211", "procfs", "iw"]
SOURCE_KINDS: tuple[str, ...] = ("nl80211", "procfs", "iw")


def make_source(
    kind: str,
    interface: str,
    *,
    path: str | os.PathLike[str] | None = None,
    clock: Clock = REAL_CLOCK,
    min_dbm: float = RSSI_MIN_DBM,
    iw_path: str = "iw",
) -> RssiSource:
    """The RSSI source of `kind` for `interface`.

    `path` is the /proc/net/wireless-format file of the "procfs" source (default the
    kernel's); the other kinds ignore it, so a daemon can pass `[wifi] procfs_path`
    whatever the source. `iw_path` is the `iw` binary of the "iw" source.
    """
    if kind == "nl80211":
        return Nl80211Source(interface, clock=clock, min_dbm=min_dbm)
    if kind == "procfs":
        return ProcfsSource(
            interface,
            path=PROC_NET_WIRELESS if path is None else path,
            clock=clock,
            min_dbm=min_dbm,
        )
    if kind == "iw":
        return IwSource(interface, clock=clock, min_dbm=min_dbm, iw_path=iw_path)
    raise ValueError(f"unknown RSSI source {kind!r}; expected one of {', '.join(SOURCE_KINDS)}")
