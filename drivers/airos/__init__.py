"""Ubiquiti airOS radios: link-quality model, HTTP client and poller.

The fake radio is `drivers.airos.fake.FakeAirOs`, not imported here: the daemon does
not load test fakes into its memory.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from drivers.airos.client import (
        AirOsAuthError,
        AirOsClient,
        AirOsConnectionError,
        AirOsNotFound,
        AirOsSessionExpired,
        AirOsTimeoutError,
        legacy_tls_context,
    )
    from drivers.airos.model import (
        RSSI_OFFSET_DB,
        AirOsDataError,
        AirOsError,
        LinkQuality,
        Station,
        decode_stations,
        decode_status,
        parse_stations,
        parse_status,
    )
    from drivers.airos.poller import AirOsPoller

# Names load on first use (PEP 562): importing a pure record such as
# drivers.arcos.sip must not load the I/O driver, asyncio or serial with it,
# since the decision core imports those records (docs/ARCHITECTURE.md).
_WHERE: dict[str, str] = {
    "AirOsAuthError": "drivers.airos.client",
    "AirOsClient": "drivers.airos.client",
    "AirOsConnectionError": "drivers.airos.client",
    "AirOsDataError": "drivers.airos.model",
    "AirOsError": "drivers.airos.model",
    "AirOsNotFound": "drivers.airos.client",
    "AirOsPoller": "drivers.airos.poller",
    "AirOsSessionExpired": "drivers.airos.client",
    "AirOsTimeoutError": "drivers.airos.client",
    "LinkQuality": "drivers.airos.model",
    "RSSI_OFFSET_DB": "drivers.airos.model",
    "Station": "drivers.airos.model",
    "decode_stations": "drivers.airos.model",
    "decode_status": "drivers.airos.model",
    "legacy_tls_context": "drivers.airos.client",
    "parse_stations": "drivers.airos.model",
    "parse_status": "drivers.airos.model",
}


def __getattr__(name: str) -> Any:
    try:
        module = _WHERE[name]
    except KeyError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    return getattr(importlib.import_module(module), name)


__all__ = [
    "RSSI_OFFSET_DB",
    "AirOsAuthError",
    "AirOsClient",
    "AirOsConnectionError",
    "AirOsDataError",
    "AirOsError",
    "AirOsNotFound",
    "AirOsPoller",
    "AirOsSessionExpired",
    "AirOsTimeoutError",
    "LinkQuality",
    "Station",
    "decode_stations",
    "decode_status",
    "legacy_tls_context",
    "parse_stations",
    "parse_status",
]
