"""What the fake airOS radio serves: its login page, a status.cgi capture, sta.cgi entries.

The documents are in the firmware's own shapes and units (rates as strings, the RSSI
offset of the chains), so a client that parses them parses a real radio's.
"""

from __future__ import annotations

import copy
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from drivers.airos.model import RSSI_OFFSET_DB, Station

#: The login page lighttpd serves on airOS 5/6 (trimmed; the fields are the real ones).
LOGIN_PAGE = """<!DOCTYPE html>
<html><head><title>Login</title></head><body>
<form enctype="multipart/form-data" id="loginform" method="post" action="/login.cgi">
<input type="hidden" name="uri" value="{uri}" />
<input type="text" name="username" id="username" />
<input type="password" name="password" id="password" />
<input type="submit" value="Login" />
</form>{error}
</body></html>
"""

#: NanoStation loco M5 XM v6.3.16 station, /status.cgi (tests/fixtures/airos), used when no
#: fixture is given.
DEFAULT_STATUS: dict[str, Any] = json.loads("""
{
  "host": {
    "uptime": 1974859,
    "time": "2025-10-20 15:33:05",
    "fwversion": "v6.3.16",
    "fwprefix": "XM",
    "hostname": "NanoStation loco M5 Client",
    "devmodel": "NanoStation loco M5 ",
    "netrole": "bridge",
    "totalram": 30220288,
    "freeram": 8753152,
    "cpuload": 100.0,
    "cputotal": 197455604,
    "cpubusy": 11150046
  },
  "wireless": {
    "mode": "sta",
    "essid": "SOMETHING",
    "hide_essid": 0,
    "apmac": "XX:XX:XX:XX:XX:XX",
    "countrycode": 616,
    "channel": 140,
    "frequency": "5700 MHz",
    "dfs": "0",
    "opmode": "11naht40minus",
    "antenna": "Built in - 13 dBi",
    "chains": "2X2",
    "signal": -46,
    "rssi": 50,
    "noisef": -89,
    "txpower": 2,
    "ack": 28,
    "distance": 600,
    "ccq": 738,
    "txrate": "243",
    "rxrate": "180",
    "security": "WPA2",
    "qos": "No QoS",
    "rstatus": 5,
    "count": 1,
    "cac_nol": 0,
    "nol_chans": 0,
    "polling": {
      "enabled": 1,
      "quality": 84,
      "capacity": 55,
      "priority": 0,
      "noack": 0,
      "airsync_mode": 0,
      "airsync_connections": 0,
      "airsync_down_util": 0,
      "airsync_up_util": 0,
      "airselect": 0,
      "airselect_interval": 1000,
      "ff_mode": 0,
      "ff_duration": 0,
      "ff_dlulratio": 0,
      "atpc_status": 0
    },
    "stats": {
      "rx_nwids": 0,
      "rx_crypts": 0,
      "rx_frags": 0,
      "tx_retries": 0,
      "missed_beacons": 0,
      "err_other": 0
    },
    "wds": 1,
    "aprepeater": 0,
    "chwidth": 20,
    "chanbw": 40,
    "cwmmode": 0,
    "rx_chainmask": 3,
    "tx_chainmask": 3,
    "chainrssi": [50, 47, 0],
    "chainrssimgmt": [50, 47, 0],
    "chainrssiext": [50, 47, 0]
  },
  "airview": { "enabled": 0 },
  "services": { "dhcpc": 0, "dhcpd": 0, "pppoe": 0 },
  "firewall": { "iptables": 0, "ebtables": 1, "ip6tables": 0, "eb6tables": 0 },
  "genuine": "/images/genuine.png",
  "unms": { "status": 0, "timestamp": "", "link": "" },
  "interfaces": [
    {
      "ifname": "lo",
      "hwaddr": "00:00:00:00:00:00",
      "enabled": true,
      "status": { "plugged": 1, "speed": 0, "duplex": 255 },
      "services": { "dhcpc": false, "dhcpd": false, "pppoe": false }
    },
    {
      "ifname": "eth0",
      "hwaddr": "YY:YY:YY:YY:YY:YY",
      "enabled": true,
      "status": { "plugged": 0, "speed": 0, "duplex": 0 },
      "services": { "dhcpc": false, "dhcpd": false, "pppoe": false }
    },
    {
      "ifname": "wifi0",
      "hwaddr": "YY:YY:YY:YY:YY:YY",
      "enabled": true,
      "status": { "plugged": 1, "speed": 0, "duplex": 255 },
      "services": { "dhcpc": false, "dhcpd": false, "pppoe": false }
    },
    {
      "ifname": "ath0",
      "hwaddr": "YY:YY:YY:YY:YY:YY",
      "enabled": true,
      "status": { "plugged": 1, "speed": 300, "duplex": 255 },
      "services": { "dhcpc": false, "dhcpd": false, "pppoe": false }
    },
    {
      "ifname": "br0",
      "hwaddr": "YY:YY:YY:YY:YY:YY",
      "enabled": true,
      "status": { "plugged": 1, "speed": 0, "duplex": 255 },
      "services": { "dhcpc": false, "dhcpd": false, "pppoe": false }
    }
  ]
}
""")


def load_fixture(fixture: str | Path | Mapping[str, Any] | None) -> dict[str, Any]:
    """A deep copy of a status.cgi document: a path, a dict, or the built-in capture."""
    if fixture is None:
        return copy.deepcopy(DEFAULT_STATUS)
    if isinstance(fixture, Mapping):
        return copy.deepcopy(dict(fixture))
    doc = json.loads(Path(fixture).read_text(encoding="utf-8"))
    if not isinstance(doc, dict) or not isinstance(doc.get("wireless"), dict):
        raise ValueError(f"{fixture}: not an airOS status.cgi document (no 'wireless' object)")
    return doc


def rate_text(mbps: float) -> str:
    # status.cgi writes rates as strings: "243", "144.4".
    return f"{mbps:g}"


def station_entry(station: Station, index: int = 0) -> dict[str, Any]:
    """One /sta.cgi (wstalist) object in the firmware's shape and units."""
    signal = None if station.signal_dbm is None else round(station.signal_dbm)
    rssi = None if signal is None else signal + RSSI_OFFSET_DB
    return {
        "mac": station.mac or f"00:27:22:00:00:{index + 1:02X}",
        "name": station.name or f"station-{index + 1}",
        "lastip": f"192.168.1.{30 + index}",
        "associd": index + 1,
        "aprepeater": 0,
        "tx": station.tx_mbps,
        "rx": station.rx_mbps,
        "signal": signal,
        "rssi": rssi,
        "chainrssi": [rssi, rssi, 0] if rssi is not None else [0, 0, 0],
        "rx_chainmask": 3,
        "ccq": None if station.ccq_pct is None else round(station.ccq_pct),
        "idle": 0,
        "tx_latency": 1,
        "uptime": 3600,
        "ack": 28,
        "distance": 600,
        "txpower": 20,
        "noisefloor": None if station.noise_dbm is None else round(station.noise_dbm),
        "airmax": {"priority": 0, "quality": 85, "beam": 0, "signal": 0, "capacity": 60},
        "stats": {
            "rx_data": 0,
            "rx_bytes": 0,
            "rx_pps": 0,
            "tx_data": 0,
            "tx_bytes": 0,
            "tx_pps": 0,
        },
        "rates": ["MCS0", "MCS15"],
        "signals": [signal, signal],
    }
