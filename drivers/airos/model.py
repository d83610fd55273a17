"""Typed airOS link quality and the pure, defensive parsers of `/status.cgi` and `/sta.cgi`.

The radios' JSON has unit traps (docs/PROTOCOLS.md 4.3-4.4) that this module resolves once:

* `rssi` is not dBm: it is `signal + 96` (the Atheros "RSSI" above a -96 dBm floor);
  `signal`/`noisef`/`noisefloor` are dBm.
* `ccq` is per-mille in status.cgi (738 = 73.8 %) but percent in sta.cgi; both become `ccq_pct`.
* rates are strings ("243") in status.cgi and floats in sta.cgi, both Mbit/s.

Every field is parsed on its own: a missing, mistyped or implausible value becomes None and
never raises. Only a document that is not JSON at all, or has no `wireless` object / is not a
station array, is a `AirOsDataError` (the caller counts it).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

#: rssi = signal_dbm + RSSI_OFFSET_DB on every capture (status.cgi and wstalist).
RSSI_OFFSET_DB = 96

# Plausibility bounds: outside them a value is a parsing accident, not a measurement.
_DBM_RANGE = (-130.0, 10.0)
_RSSI_RANGE = (0.0, 127.0)
_PCT_RANGE = (0.0, 100.0)
_MBPS_RANGE = (0.0, 100_000.0)

_NUMBER_PREFIX = re.compile(r"^\s*([-+]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+]?\d+)?)")


class AirOsError(Exception):
    """Base of every airOS client error; messages never contain credentials."""


class AirOsDataError(AirOsError, ValueError):
    """The radio answered something that is not an airOS status/station document."""


@dataclass(frozen=True, slots=True)
class Station:
    """One associated peer: from sta.cgi on an AP, or the AP itself as seen by a station."""

    mac: str | None
    signal_dbm: float | None
    ccq_pct: float | None
    tx_mbps: float | None
    rx_mbps: float | None
    noise_dbm: float | None = None
    name: str | None = None

    @property
    def rssi(self) -> float | None:
        return None if self.signal_dbm is None else self.signal_dbm + RSSI_OFFSET_DB

    def to_json(self) -> dict[str, Any]:
        return {
            "mac": self.mac,
            "name": self.name,
            "signal_dbm": self.signal_dbm,
            "noise_dbm": self.noise_dbm,
            "ccq_pct": self.ccq_pct,
            "tx_mbps": self.tx_mbps,
            "rx_mbps": self.rx_mbps,
        }


@dataclass(frozen=True, slots=True)
class LinkQuality:
    """One poll of one radio, `t` in clock seconds."""

    t: float
    signal_dbm: float | None
    rssi: float | None
    noise_dbm: float | None
    ccq_pct: float | None
    tx_mbps: float | None
    rx_mbps: float | None
    stations: tuple[Station, ...] = ()
    mode: str | None = None  # "ap" | "sta" | None when the radio says something else
    essid: str | None = None
    frequency_mhz: float | None = None
    hostname: str | None = None

    @property
    def best_station(self) -> Station | None:
        """The strongest station with a signal (RSSI^b on the rear AP)."""
        heard = [s for s in self.stations if s.signal_dbm is not None]
        return max(heard, key=lambda s: s.signal_dbm or 0.0) if heard else None

    @property
    def best_station_signal_dbm(self) -> float | None:
        best = self.best_station
        return None if best is None else best.signal_dbm

    def station_signal_dbm(self, mac: str) -> float | None:
        """Signal of the station with this MAC (case-insensitive, ':' or '-'), None if absent."""
        want = _norm_mac(mac)
        for s in self.stations:
            if s.mac is not None and _norm_mac(s.mac) == want:
                return s.signal_dbm
        return None

    def to_json(self) -> dict[str, Any]:
        """The `probe ap` line: the documented keys first (README, Commands), then the extras."""
        return {
            "signal_dbm": self.signal_dbm,
            "rssi": self.rssi,
            "noise_dbm": self.noise_dbm,
            "ccq_pct": self.ccq_pct,
            "tx_mbps": self.tx_mbps,
            "rx_mbps": self.rx_mbps,
            "stations": [s.to_json() for s in self.stations],
            "mode": self.mode,
            "essid": self.essid,
            "frequency_mhz": self.frequency_mhz,
            "hostname": self.hostname,
        }


def _norm_mac(mac: str) -> str:
    return mac.strip().lower().replace("-", ":")


def _number(value: object, bounds: tuple[float, float] | None = None) -> float | None:
    """int/float, or a string starting with a number ("243", "5700 MHz"); else None."""
    if isinstance(value, bool):  # JSON true is not 1 dBm
        return None
    if isinstance(value, int | float):
        try:
            out = float(value)
        except OverflowError:  # a 400-digit JSON integer
            return None
    elif isinstance(value, str):
        m = _NUMBER_PREFIX.match(value[:64])
        if m is None:
            return None
        try:
            out = float(m.group(1))
        except (ValueError, OverflowError):
            return None
    else:
        return None
    if not math.isfinite(out):
        return None
    if bounds is not None and not bounds[0] <= out <= bounds[1]:
        return None
    return out


def _text(value: object, limit: int = 256) -> str | None:
    if not isinstance(value, str):
        return None
    value = value.strip()
    return value[:limit] if value else None


def _mode(value: object) -> str | None:
    # airOS 6: "ap"/"sta"; airOS 8: "ap-ptp", "sta-ptmp", ...
    text = _text(value)
    if text is None:
        return None
    text = text.lower()
    if text.startswith("ap"):
        return "ap"
    if text.startswith("sta"):
        return "sta"
    return None


def _signal_pair(signal: object, rssi: object) -> tuple[float | None, float | None]:
    """(signal_dbm, rssi) with the one derived from the other when only one is usable."""
    signal_dbm = _number(signal, _DBM_RANGE)
    rssi_v = _number(rssi, _RSSI_RANGE)
    if signal_dbm is None and rssi_v is not None:
        derived = rssi_v - RSSI_OFFSET_DB
        # An rssi the radio could report (0..127) can still mean an impossible signal.
        signal_dbm = derived if _DBM_RANGE[0] <= derived <= _DBM_RANGE[1] else None
    elif rssi_v is None and signal_dbm is not None:
        candidate = signal_dbm + RSSI_OFFSET_DB
        rssi_v = candidate if _RSSI_RANGE[0] <= candidate <= _RSSI_RANGE[1] else None
    return signal_dbm, rssi_v


def _ccq_from_permille(value: object) -> float | None:
    permille = _number(value, (0.0, 1000.0))
    return None if permille is None else permille / 10.0


def parse_station(obj: Mapping[str, Any]) -> Station:
    """One sta.cgi entry (ccq in percent, tx/rx floats in Mbit/s)."""
    signal_dbm, _ = _signal_pair(obj.get("signal"), obj.get("rssi"))
    return Station(
        mac=_text(obj.get("mac"), 64),
        signal_dbm=signal_dbm,
        ccq_pct=_number(obj.get("ccq"), _PCT_RANGE),
        tx_mbps=_number(obj.get("tx"), _MBPS_RANGE),
        rx_mbps=_number(obj.get("rx"), _MBPS_RANGE),
        noise_dbm=_number(obj.get("noisefloor"), _DBM_RANGE),
        name=_text(obj.get("name")),
    )


def parse_stations(doc: object) -> tuple[Station, ...]:
    """A decoded sta.cgi array; entries that are not objects are skipped."""
    if not isinstance(doc, list):
        raise AirOsDataError(f"sta.cgi: expected a JSON array, got {type(doc).__name__}")
    return tuple(parse_station(e) for e in doc if isinstance(e, Mapping))


def parse_status(
    doc: object, *, t: float, stations: tuple[Station, ...] | None = None
) -> LinkQuality:
    """A decoded status.cgi object -> LinkQuality.

    On a station the only peer is the AP, described by status.cgi's own fields; on an AP
    pass the parsed sta.cgi list as `stations` (status.cgi has no per-station data there).
    """
    if not isinstance(doc, Mapping):
        raise AirOsDataError(f"status.cgi: expected a JSON object, got {type(doc).__name__}")
    wireless = doc.get("wireless")
    if not isinstance(wireless, Mapping):
        raise AirOsDataError("status.cgi: no 'wireless' object")
    host = doc.get("host")
    host = host if isinstance(host, Mapping) else {}

    signal_dbm, rssi = _signal_pair(wireless.get("signal"), wireless.get("rssi"))
    ccq_pct = _ccq_from_permille(wireless.get("ccq"))
    tx_mbps = _number(wireless.get("txrate"), _MBPS_RANGE)
    rx_mbps = _number(wireless.get("rxrate"), _MBPS_RANGE)
    noise_dbm = _number(wireless.get("noisef"), _DBM_RANGE)
    mode = _mode(wireless.get("mode"))
    v8_stations = wireless.get("sta")
    if stations is None and isinstance(v8_stations, list):
        # airOS 8 embeds the station list in status.cgi (ccq already in percent there).
        stations = parse_stations(v8_stations)
    if stations is None:
        stations = ()
        if mode == "sta" and signal_dbm is not None:
            stations = (
                Station(
                    mac=_text(wireless.get("apmac"), 64),
                    signal_dbm=signal_dbm,
                    ccq_pct=ccq_pct,
                    tx_mbps=tx_mbps,
                    rx_mbps=rx_mbps,
                    noise_dbm=noise_dbm,
                    name=_text(wireless.get("essid")),
                ),
            )
    return LinkQuality(
        t=float(t),
        signal_dbm=signal_dbm,
        rssi=rssi,
        noise_dbm=noise_dbm,
        ccq_pct=ccq_pct,
        tx_mbps=tx_mbps,
        rx_mbps=rx_mbps,
        stations=tuple(stations),
        mode=mode,
        essid=_text(wireless.get("essid")),
        frequency_mhz=_number(wireless.get("frequency"), (1.0, 100_000.0)),
        hostname=_text(host.get("hostname")),
    )


def decode_json(raw: str | bytes, what: str = "answer") -> Any:
    """json.loads that only ever raises AirOsDataError (bad UTF-8, syntax, absurd nesting)."""
    try:
        return json.loads(raw)
    except (
        ValueError,
        RecursionError,
        TypeError,
    ) as exc:  # JSONDecodeError/UnicodeError are ValueError
        raise AirOsDataError(f"{what}: malformed JSON ({type(exc).__name__})") from None


def decode_status(
    raw: str | bytes, *, t: float, stations: tuple[Station, ...] | None = None
) -> LinkQuality:
    return parse_status(decode_json(raw, "status.cgi"), t=t, stations=stations)


def decode_stations(raw: str | bytes) -> tuple[Station, ...]:
    return parse_stations(decode_json(raw, "sta.cgi"))
