"""Pure parsers for the Linux Wi-Fi RSSI text formats, and the plausibility rules.

Formats (docs/PROTOCOLS.md section 3): `/proc/net/wireless` (WEXT,
`net/wireless/wext-proc.c`), `iw dev IF link`, and `iw dev IF station dump` /
`station get MAC` (iw's `station.c`). Real `iw` output indents with TABs; copies pasted
into issues use spaces, so every parser accepts both. No parser raises on bad input:
unparseable lines are skipped, and a missing field is `None`.

No asyncio and no I/O here: the sources in `drivers.wifi.sources` feed text in.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

#: A received frame below this is not believable: thermal noise in 20 MHz is -101 dBm
#: and no 802.11 receiver decodes a frame below about -98 dBm, so driver bugs such as
#: mt76's -101/-102 dBm (openwrt/mt76 #20) are rejected along with the -110 dBm floor.
RSSI_MIN_DBM = -100.0
#: Sentinels drivers use for "no value": 0 (rtw88), -128 (s8 min, monitor mode), -256
#: (WEXT "invalid" noise/level).
_SENTINELS_DBM = frozenset({0.0, -128.0, -256.0})


def wrap_u8_dbm(value: float) -> float:
    """Undo an unsigned print of a signed dBm byte (wireless-tools' `iwlib.c` rule).

    WEXT carries the level in a u8; wireless-tools treats raw values >= 64 as
    `value - 256` dBm, and old `iw` printed `beacon signal avg` unsigned (218 -> -38).
    Values 64..127 become < -128 and are then rejected as impossible.
    """
    return value - 256 if value > 63 else value


def plausible_rssi_dbm(value: float, *, min_dbm: float = RSSI_MIN_DBM) -> bool:
    """True when `value` (already wrapped) can be a real received signal level."""
    if value != value:  # NaN
        return False
    if value in _SENTINELS_DBM:
        return False
    return min_dbm <= value < 0


# --------------------------------------------------------------------------------------
# /proc/net/wireless

PROC_HEADER_1 = "Inter-| sta-|   Quality        |   Discarded packets               | Missed | WE"
PROC_HEADER_2 = " face | tus | link level noise |  nwid  crypt   frag  retry   misc | beacon | 22"

_NUM = r"(-?\d+)(\.?)"
_PROC_ROW = re.compile(
    r"^\s*(?P<iface>[^\s:]+):\s+(?P<status>[0-9a-fA-F]+)\s+"
    + rf"{_NUM}\s+{_NUM}\s+{_NUM}"
    + r"\s+(-?\d+)\s+(-?\d+)\s+(-?\d+)\s+(-?\d+)\s+(-?\d+)\s+(-?\d+)\s*$"
)


@dataclass(frozen=True, slots=True)
class ProcWirelessRow:
    """One interface row of /proc/net/wireless, numbers as printed (level not wrapped).

    The `*_updated` flags are the '.' printed after a value: the WEXT UPDATED bit.
    """

    interface: str
    status: int
    link: int
    link_updated: bool
    level: int
    level_updated: bool
    noise: int
    noise_updated: bool
    discard_nwid: int
    discard_crypt: int
    discard_frag: int
    discard_retry: int
    discard_misc: int
    missed_beacon: int
    line: str

    @property
    def level_dbm(self) -> float:
        """The level as dBm, with the u8 convention of out-of-tree drivers undone."""
        return wrap_u8_dbm(float(self.level))


def parse_proc_wireless_line(line: str) -> ProcWirelessRow | None:
    """Parse one interface row; None for headers, blanks and garbage."""
    m = _PROC_ROW.match(line)
    if m is None:
        return None
    g = m.groups()
    try:
        status = int(g[1], 16)
    except ValueError:
        return None
    return ProcWirelessRow(
        interface=g[0],
        status=status,
        link=int(g[2]),
        link_updated=g[3] == ".",
        level=int(g[4]),
        level_updated=g[5] == ".",
        noise=int(g[6]),
        noise_updated=g[7] == ".",
        discard_nwid=int(g[8]),
        discard_crypt=int(g[9]),
        discard_frag=int(g[10]),
        discard_retry=int(g[11]),
        discard_misc=int(g[12]),
        missed_beacon=int(g[13]),
        line=line.strip(),
    )


def parse_proc_net_wireless(text: str) -> dict[str, ProcWirelessRow]:
    """All interface rows of a /proc/net/wireless text, keyed by interface name."""
    rows: dict[str, ProcWirelessRow] = {}
    for line in text.splitlines():
        row = parse_proc_wireless_line(line)
        if row is not None:
            rows[row.interface] = row
    return rows


# --------------------------------------------------------------------------------------
# iw text

_MAC = r"[0-9A-Fa-f]{2}(?::[0-9A-Fa-f]{2}){5}|<[^>\s]*>"
_CONNECTED = re.compile(rf"^\s*Connected to ({_MAC})(?: \(on (\S+)\))?\s*$")
_STATION = re.compile(rf"^\s*Station ({_MAC})(?: \(on (\S+)\))?\s*$")
# "signal:  \t-60 [-60, -60] dBm"; the chain list is optional.
_DBM = re.compile(r"^(-?\d+)\s*(?:\[([-\d,\s]*)\])?\s*dBm\s*$")
_RX_TX = re.compile(r"^(\d+) bytes \((\d+) packets\)\s*$")
_INT_UNIT = re.compile(r"^(-?\d+)(?:\s*\S+)?\s*$")


def _key_value(line: str) -> tuple[str, str] | None:
    """Split an indented `key: value` line (tabs or spaces after the colon)."""
    if not line[:1].isspace():
        return None
    key, sep, value = line.strip().partition(":")
    if not sep or not key:
        return None
    return key.strip().lower(), value.strip()


def parse_dbm(value: str) -> tuple[int, tuple[int, ...]] | None:
    """Parse `-57 [-62, -59] dBm` into (-57, (-62, -59)); None if malformed."""
    m = _DBM.match(value.strip())
    if m is None:
        return None
    chains: tuple[int, ...] = ()
    if m.group(2) is not None:
        parts = [p.strip() for p in m.group(2).split(",")]
        try:
            chains = tuple(int(p) for p in parts if p)
        except ValueError:
            return None
    try:
        return int(m.group(1)), chains
    except ValueError:
        return None


def _leading_int(value: str) -> int | None:
    m = _INT_UNIT.match(value)
    if m is None:
        return None
    try:
        return int(m.group(1))
    except ValueError:
        return None


@dataclass(frozen=True, slots=True)
class IwLink:
    """`iw dev IF link`: the association and the station signal of the BSSID."""

    connected: bool
    bssid: str | None = None
    interface: str | None = None
    ssid: str | None = None
    freq_mhz: int | None = None
    rx_bytes: int | None = None
    rx_packets: int | None = None
    tx_bytes: int | None = None
    tx_packets: int | None = None
    signal_dbm: int | None = None
    beacon_interval_tu: int | None = None


def parse_iw_link(text: str) -> IwLink | None:
    """Parse `iw dev IF link`; `IwLink(connected=False)` for `Not connected.`, None if neither."""
    fields: dict[str, int | str | None] = {}
    connected: bool | None = None
    bssid: str | None = None
    interface: str | None = None
    for line in text.splitlines():
        if connected is None:
            if line.strip() == "Not connected.":
                return IwLink(connected=False)
            m = _CONNECTED.match(line)
            if m is not None:
                connected, bssid, interface = True, m.group(1), m.group(2)
            continue
        kv = _key_value(line)
        if kv is None:
            continue
        key, value = kv
        if key == "ssid":
            fields["ssid"] = value
        elif key == "freq":
            fields["freq_mhz"] = _leading_int(value)
        elif key in ("rx", "tx"):
            m2 = _RX_TX.match(value)
            if m2 is not None:
                fields[f"{key}_bytes"] = int(m2.group(1))
                fields[f"{key}_packets"] = int(m2.group(2))
        elif key == "signal":
            parsed = parse_dbm(value)
            fields["signal_dbm"] = parsed[0] if parsed else None
        elif key == "beacon int":
            fields["beacon_interval_tu"] = _leading_int(value)
    if connected is None:
        return None
    return IwLink(connected=True, bssid=bssid, interface=interface, **fields)  # type: ignore[arg-type]


@dataclass(frozen=True, slots=True)
class IwStation:
    """One `Station ...` block of `iw ... station dump` or `station get`.

    dBm values are as printed (`wrap_u8_dbm` is applied by the sources, because old
    `iw` printed `beacon signal avg` unsigned). Chain tuples are empty when absent.
    """

    mac: str
    interface: str | None = None
    inactive_time_ms: int | None = None
    rx_bytes: int | None = None
    rx_packets: int | None = None
    tx_packets: int | None = None
    beacon_rx: int | None = None
    beacon_loss: int | None = None
    signal_dbm: int | None = None
    signal_chains_dbm: tuple[int, ...] = ()
    signal_avg_dbm: int | None = None
    signal_avg_chains_dbm: tuple[int, ...] = ()
    beacon_signal_avg_dbm: int | None = None
    connected_time_s: int | None = None


_STA_INTS = {
    "inactive time": "inactive_time_ms",
    "rx bytes": "rx_bytes",
    "rx packets": "rx_packets",
    "tx packets": "tx_packets",
    "beacon rx": "beacon_rx",
    "beacon loss": "beacon_loss",
    "connected time": "connected_time_s",
}


def parse_iw_stations(text: str) -> list[IwStation]:
    """Every station block in `iw ... station dump` / `station get` output, in order."""
    stations: list[IwStation] = []
    current: dict[str, object] | None = None

    def flush() -> None:
        if current is not None:
            stations.append(IwStation(**current))  # type: ignore[arg-type]

    for line in text.splitlines():
        m = _STATION.match(line)
        if m is not None and not line[:1].isspace():
            flush()
            current = {"mac": m.group(1), "interface": m.group(2)}
            continue
        if current is None:
            continue
        kv = _key_value(line)
        if kv is None:
            continue
        key, value = kv
        if key in _STA_INTS:
            current[_STA_INTS[key]] = _leading_int(value)
        elif key in ("signal", "signal avg"):
            parsed = parse_dbm(value)
            name = "signal_dbm" if key == "signal" else "signal_avg_dbm"
            current[name] = parsed[0] if parsed else None
            current[name.replace("_dbm", "_chains_dbm")] = parsed[1] if parsed else ()
        elif key == "beacon signal avg":
            parsed = parse_dbm(value)
            current["beacon_signal_avg_dbm"] = parsed[0] if parsed else None
    flush()
    return stations
