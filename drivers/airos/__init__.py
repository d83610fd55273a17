"""Ubiquiti airOS radios: link-quality model, HTTP client and poller.

The fake radio is `drivers.airos.fake.FakeAirOs`, not imported here: the daemon does
not load test fakes into its memory.
"""

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
