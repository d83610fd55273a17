"""Wi-Fi RSSI of the Yagi's USB adapter: nl80211, /proc/net/wireless and `iw` sources.

`make_source(kind, interface)` builds the source the config names; every source gives
`RssiSample(t, rssi_dbm, fresh)` through `await read()` or `stream(sample_hz)`.
`ProcfsWriter` is the fake adapter (a /proc/net/wireless-format file) for tests and
the simulator.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from drivers.wifi.factory import SOURCE_KINDS, SourceKind, make_source
    from drivers.wifi.fake import ProcfsWriter
    from drivers.wifi.nl80211 import Nl80211Source
    from drivers.wifi.parsers import RSSI_MIN_DBM, plausible_rssi_dbm
    from drivers.wifi.records import RssiSample
    from drivers.wifi.sources import (
        PROC_NET_WIRELESS,
        IwSource,
        ProcfsSource,
        RssiSource,
    )

# Names load on first use (PEP 562): importing a pure record such as
# drivers.arcos.sip must not load the I/O driver, asyncio or serial with it,
# since the decision core imports those records (docs/ARCHITECTURE.md).
_WHERE: dict[str, str] = {
    "IwSource": "drivers.wifi.sources",
    "Nl80211Source": "drivers.wifi.nl80211",
    "PROC_NET_WIRELESS": "drivers.wifi.sources",
    "ProcfsSource": "drivers.wifi.sources",
    "ProcfsWriter": "drivers.wifi.fake",
    "RSSI_MIN_DBM": "drivers.wifi.parsers",
    "RssiSample": "drivers.wifi.records",
    "RssiSource": "drivers.wifi.sources",
    "SOURCE_KINDS": "drivers.wifi.factory",
    "SourceKind": "drivers.wifi.factory",
    "make_source": "drivers.wifi.factory",
    "plausible_rssi_dbm": "drivers.wifi.parsers",
}


def __getattr__(name: str) -> Any:
    try:
        module = _WHERE[name]
    except KeyError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    return getattr(importlib.import_module(module), name)


__all__ = [
    "PROC_NET_WIRELESS",
    "RSSI_MIN_DBM",
    "SOURCE_KINDS",
    "IwSource",
    "Nl80211Source",
    "ProcfsSource",
    "ProcfsWriter",
    "RssiSample",
    "RssiSource",
    "SourceKind",
    "make_source",
    "plausible_rssi_dbm",
]
