"""Ubiquiti airOS radios: link-quality model, HTTP client, poller, and a fake radio."""

from drivers.airos.client import (
    AirOsAuthError,
    AirOsClient,
    AirOsConnectionError,
    AirOsNotFound,
    AirOsSessionExpired,
    AirOsTimeoutError,
    legacy_tls_context,
)
from drivers.airos.fake import FakeAirOs
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
    "FakeAirOs",
    "LinkQuality",
    "Station",
    "decode_stations",
    "decode_status",
    "legacy_tls_context",
    "parse_stations",
    "parse_status",
]
