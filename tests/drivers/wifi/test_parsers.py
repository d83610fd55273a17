"""Wi-Fi text parsers against every captured fixture, tabs vs spaces, and fuzzing."""

from __future__ import annotations

import random
import re
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from drivers.wifi.fake import format_proc_row
from drivers.wifi.parsers import (
    PROC_HEADER_1,
    PROC_HEADER_2,
    IwLink,
    IwStation,
    parse_dbm,
    parse_iw_link,
    parse_iw_stations,
    parse_proc_net_wireless,
    parse_proc_wireless_line,
    plausible_rssi_dbm,
    wrap_u8_dbm,
)

FIXTURES = Path(__file__).parents[2] / "fixtures" / "wifi"
FILES = sorted(p.name for p in FIXTURES.glob("*.txt"))

# What each capture says, read off the file by hand. A new fixture without an entry
# here fails test_every_fixture_has_expectations.
EXPECTED: dict[str, dict[str, Any]] = {
    "iw_link_jantman_issue1_5260MHz.txt": {
        "link": IwLink(
            connected=True,
            bssid="34:fc:b9:74:cf:d0",
            interface="wlan0",
            ssid="Guardia Forest Treasure Secure",
            freq_mhz=5260,
            rx_bytes=149879,
            rx_packets=882,
            tx_bytes=4747,
            tx_packets=33,
            signal_dbm=-39,
            beacon_interval_tu=100,
        )
    },
    "iw_link_lede_tp1043_2462MHz.txt": {
        "link": IwLink(
            connected=True,
            bssid="f4:f2:6d:22:7c:f0",
            interface="wlan0",
            ssid="LEDE-tp1043",
            freq_mhz=2462,
            rx_bytes=7007190,
            rx_packets=72847,
            tx_bytes=20015,
            tx_packets=226,
            signal_dbm=-39,
            beacon_interval_tu=None,
        )
    },
    "iw_link_opensolo_2447MHz.txt": {
        "link": IwLink(
            connected=True,
            bssid="d4:d7:48:81:68:a0",
            interface="wlan0",
            ssid="3DRobotics",
            freq_mhz=2447,
            rx_bytes=5779050,
            rx_packets=38689,
            tx_bytes=13885,
            tx_packets=73,
            signal_dbm=-37,
            beacon_interval_tu=85,
        )
    },
    "proc_net_wireless_glances_wlp2s0.txt": {
        "proc": {
            "wlp2s0": dict(
                status=0,
                link=51,
                link_updated=True,
                level=-59,
                level_updated=True,
                noise=-256,
                noise_updated=False,
                discard_nwid=0,
                discard_crypt=0,
                discard_frag=0,
                discard_retry=0,
                discard_misc=5881,
                missed_beacon=0,
            )
        }
    },
    "proc_net_wireless_telegraf_two_ifaces.txt": {
        "proc": {
            "wlan0": dict(
                status=0,
                link=60,
                link_updated=True,
                level=-50,
                level_updated=True,
                noise=-256,
                noise_updated=False,
                discard_nwid=0,
                discard_crypt=0,
                discard_frag=0,
                discard_retry=1525,
                discard_misc=0,
                missed_beacon=0,
            ),
            "wlan1": dict(
                status=0,
                link=70,
                link_updated=True,
                level=-39,
                level_updated=True,
                noise=-256,
                noise_updated=False,
                discard_nwid=0,
                discard_crypt=0,
                discard_frag=0,
                discard_retry=12096,
                discard_misc=191188,
                missed_beacon=0,
            ),
        }
    },
    "station_dump_openwrt_packages_issue16471_chain_signals.txt": {
        "stations": [
            IwStation(
                mac="8c:be:be:f5:8f:59",
                interface="wlan0",
                inactive_time_ms=120,
                rx_bytes=14835,
                rx_packets=296,
                tx_packets=90,
                signal_dbm=-57,
                signal_chains_dbm=(-62, -59),
                signal_avg_dbm=-66,
                signal_avg_chains_dbm=(-71, -69),
            )
        ]
    },
    "station_get_mt76_issue20_bogus_signal.txt": {
        "stations": [
            IwStation(
                mac="00:13:10:14:c4:fe",
                interface="wlan1",
                inactive_time_ms=110,
                rx_bytes=122899664,
                rx_packets=778197,
                tx_packets=4,
                signal_dbm=-101,
                signal_avg_dbm=-102,
                connected_time_s=39194,
            )
        ],
        "rejected": True,
    },
    "station_get_rtl8723bs_mdlayher_wifi_issue27.txt": {
        "stations": [
            IwStation(
                mac="<BSSID>",
                interface="wlan0",
                rx_packets=1428888,
                tx_packets=6618022,
                signal_dbm=-45,
            )
        ]
    },
}


_TEXTS: dict[str, str] = {}


def _read(name: str) -> str:
    if name not in _TEXTS:
        _TEXTS[name] = (FIXTURES / name).read_text()
    return _TEXTS[name]


def test_fixture_directory_is_there() -> None:
    assert len(FILES) >= 8


def test_every_fixture_has_expectations() -> None:
    assert set(FILES) == set(EXPECTED)


def _check(text: str, exp: dict[str, Any]) -> None:
    if "link" in exp:
        assert parse_iw_link(text) == exp["link"]
        assert parse_iw_stations(text) == []
        assert parse_proc_net_wireless(text) == {}
        level = exp["link"].signal_dbm
    elif "stations" in exp:
        assert parse_iw_stations(text) == exp["stations"]
        assert parse_iw_link(text) is None
        assert parse_proc_net_wireless(text) == {}
        level = exp["stations"][0].signal_dbm
    else:
        rows = parse_proc_net_wireless(text)
        assert set(rows) == set(exp["proc"])
        for iface, fields in exp["proc"].items():
            row = rows[iface]
            assert {k: getattr(row, k) for k in fields} == fields
            assert row.interface == iface
            # The capture is consistent with cfg80211: quality = level + 110, max 70.
            assert row.link == min(70, row.level + 110)
        assert parse_iw_link(text) is None
        assert parse_iw_stations(text) == []
        level = next(iter(rows.values())).level_dbm
    assert plausible_rssi_dbm(wrap_u8_dbm(level)) is not exp.get("rejected", False)


@pytest.mark.parametrize("name", FILES)
def test_fixture_values(name: str) -> None:
    _check(_read(name), EXPECTED[name])


def _to_spaces(text: str) -> str:
    return text.replace("\t", "        ")


def _to_tabs(text: str) -> str:
    text = re.sub(r"^ +", "\t", text, flags=re.M)
    return re.sub(r":( {2,})", ":\t", text)


@pytest.mark.parametrize("name", FILES)
@pytest.mark.parametrize("convert", [_to_spaces, _to_tabs], ids=["spaces", "tabs"])
def test_fixture_values_with_tabs_or_spaces(name: str, convert: Any) -> None:
    text = _read(name)
    if name.startswith("proc_"):
        # /proc rows are space separated by the kernel; a tab between columns must also do.
        converted = text.replace("  ", "\t")
        assert "\t" in converted
        rows = parse_proc_net_wireless(converted)
        assert {k: r.level for k, r in rows.items()} == {
            k: v["level"] for k, v in EXPECTED[name]["proc"].items()
        }
        return
    converted = convert(text)
    _check(converted, EXPECTED[name])


def test_fixtures_really_differ_in_indentation() -> None:
    assert "\tsignal:" in _read("iw_link_lede_tp1043_2462MHz.txt")
    assert "        signal:" in _read("iw_link_opensolo_2447MHz.txt")


def test_iw_link_not_connected() -> None:
    assert parse_iw_link("Not connected.\n") == IwLink(connected=False)
    assert parse_iw_link("") is None
    assert parse_iw_link("command failed: No such device (-19)\n") is None


def test_station_dump_from_the_protocol_doc_with_beacon_fields() -> None:
    text = (
        "Station 04:f0:21:32:3f:d2 (on wlo1)\n"
        "\tinactive time:\t70 ms\n\trx packets:\t12577\n\tbeacon loss:\t0\n"
        "\tbeacon rx:\t2325\n\tsignal:  \t-60 [-60, -60] dBm\n\tsignal avg:\t-59 dBm\n"
        "\tbeacon signal avg:\t-58 dBm\n"
        "\ttx bitrate:\t650.0 MBit/s VHT-MCS 7 80MHz short GI VHT-NSS 2\n"
        "\tbeacon interval:100\n\tconnected time:\t233 seconds\n"
        "\tcurrent time:\t1731975697273 ms\n"
        "Station 11:22:33:44:55:66 (on wlo1)\n\tinactive time:\t900 ms\n\tsignal:\t-70 dBm\n"
    )
    a, b = parse_iw_stations(text)
    assert a == IwStation(
        mac="04:f0:21:32:3f:d2",
        interface="wlo1",
        inactive_time_ms=70,
        rx_packets=12577,
        beacon_rx=2325,
        beacon_loss=0,
        signal_dbm=-60,
        signal_chains_dbm=(-60, -60),
        signal_avg_dbm=-59,
        beacon_signal_avg_dbm=-58,
        connected_time_s=233,
    )
    assert (b.mac, b.signal_dbm, b.inactive_time_ms) == ("11:22:33:44:55:66", -70, 900)


def test_old_iw_unsigned_beacon_signal_avg() -> None:
    st_ = parse_iw_stations("Station 00:11:22:33:44:55 (on wlan0)\n\tbeacon signal avg:\t218 dBm\n")
    assert st_[0].beacon_signal_avg_dbm == 218
    assert wrap_u8_dbm(218) == -38


@pytest.mark.parametrize(
    ("raw", "dbm", "ok"),
    [
        (-60, -60, True),
        (-1, -1, True),
        (-100, -100, True),
        (196, -60, True),
        (0, 0, False),
        (-128, -128, False),
        (-256, -256, False),
        (5, 5, False),
        (63, 63, False),
        (64, -192, False),
        (70, -186, False),
        (-101, -101, False),
        (-111, -111, False),
        (128, -128, False),
        (255, -1, True),
    ],
)
def test_plausibility_rules(raw: int, dbm: int, ok: bool) -> None:
    assert wrap_u8_dbm(raw) == dbm
    assert plausible_rssi_dbm(wrap_u8_dbm(raw)) is ok


def test_plausibility_nan_and_custom_floor() -> None:
    assert not plausible_rssi_dbm(float("nan"))
    assert plausible_rssi_dbm(-105, min_dbm=-110)
    assert not plausible_rssi_dbm(-111, min_dbm=-110)


def test_parse_dbm_variants() -> None:
    assert parse_dbm("-57 [-62, -59] dBm") == (-57, (-62, -59))
    assert parse_dbm("-39 dBm") == (-39, ())
    assert parse_dbm("-60 [-60, -60, -95, -95] dBm") == (-60, (-60, -60, -95, -95))
    assert parse_dbm("-39") is None
    assert parse_dbm("garbage dBm") is None
    assert parse_dbm("-5 [x] dBm") is None


def test_proc_row_round_trip_through_kernel_format() -> None:
    line = format_proc_row(
        "wlan1",
        link=50,
        link_updated=True,
        level=-60,
        level_updated=True,
        noise=-95,
        noise_updated=True,
        misc=7,
        missed_beacon=3,
    )
    row = parse_proc_wireless_line(line)
    assert row is not None
    assert (row.interface, row.link, row.level, row.noise, row.discard_misc, row.missed_beacon) == (
        "wlan1",
        50,
        -60,
        -95,
        7,
        3,
    )
    assert row.level_updated and row.noise_updated
    assert parse_proc_wireless_line(PROC_HEADER_1) is None
    assert parse_proc_wireless_line(PROC_HEADER_2) is None


def test_proc_unmarked_and_biased_levels() -> None:
    row = parse_proc_wireless_line(format_proc_row("wlan0"))
    assert row is not None and not row.level_updated and row.level == 0
    row = parse_proc_wireless_line(format_proc_row("wlan0", level=196, level_updated=True))
    assert row is not None and row.level_dbm == -60


# ---------------------------------------------------------------------------- fuzzing

_LINE_BREAKS = "\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029"
_garbage_line = st.text(
    alphabet=st.characters(exclude_categories=["Cs"], exclude_characters=_LINE_BREAKS), max_size=80
)
_format_chars = st.sampled_from(list("\t :.-[],()<>0123456789abcdefdBmStation\n"))
_format_text = st.lists(_format_chars, max_size=300).map("".join)
_any_text = st.one_of(st.text(max_size=400), _format_text)
_FUZZ = settings(max_examples=1200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@_FUZZ
@given(_any_text)
def test_fuzz_no_parser_raises(text: str) -> None:
    parse_proc_net_wireless(text)
    parse_iw_link(text)
    parse_iw_stations(text)
    parse_dbm(text)
    for line in text.splitlines():
        parse_proc_wireless_line(line)


def _garble(rng: random.Random, text: str) -> str:
    chars = list(text)
    for _ in range(rng.randint(1, 12)):
        i = rng.randint(0, len(chars))
        c = rng.choice(
            [
                "\t",
                " ",
                "\n",
                ":",
                ".",
                "-",
                "[",
                "]",
                "\x00",
                "\u2028",
                "é",
                chr(rng.randint(32, 0x2FFF)),
                str(rng.randint(0, 9)),
            ]
        )
        op = rng.choice(["del", "sub", "ins"])
        if op == "ins" or i == len(chars):
            chars.insert(i, c)
        elif op == "del":
            del chars[i]
        else:
            chars[i] = c
    return "".join(chars)


@settings(max_examples=400, deadline=None)
@given(st.sampled_from(FILES), st.integers(0, 2**32 - 1))
def test_fuzz_garbled_fixtures(name: str, seed: int) -> None:
    """20 mutated copies of a real capture per example (8000 in all); nothing raises."""
    rng = random.Random(seed)
    for _ in range(20):
        mutated = _garble(rng, _read(name))
        rows = parse_proc_net_wireless(mutated)
        link = parse_iw_link(mutated)
        stations = parse_iw_stations(mutated)
        for row in rows.values():
            assert isinstance(row.level, int)
        assert link is None or isinstance(link.connected, bool)
        for sta in stations:
            assert sta.signal_dbm is None or isinstance(sta.signal_dbm, int)


@settings(max_examples=600, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_garbage_line, max_size=6), st.sampled_from(FILES))
def test_fuzz_valid_text_after_garbage_still_parses(garbage: list[str], name: str) -> None:
    for g in garbage:
        assume(g.strip() != "Not connected.")
        assume(parse_iw_link(g) is None and not parse_iw_stations(g))
        assume(parse_proc_wireless_line(g) is None)
    text = "\n".join([*garbage, _read(name)])
    _check(text, EXPECTED[name])
