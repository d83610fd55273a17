"""The Wi-Fi driver's pure record: one RSSI reading, as every source produces it.

Apart from the sources (drivers.wifi.sources, which do I/O) so the decision core can
import it without loading asyncio or a logger.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class RssiSample:
    """One RSSI reading: clock seconds, dBm (None when there is no believable value)."""

    t: float
    rssi_dbm: float | None
    fresh: bool
