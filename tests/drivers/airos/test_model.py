"""airOS status.cgi / sta.cgi parsing: the real captures, the unit traps, and fuzzing."""

from __future__ import annotations

import json
import math
import random
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.airos.model import (
    AirOsDataError,
    LinkQuality,
    Station,
    _signal_pair,
    decode_stations,
    decode_status,
    parse_stations,
    parse_status,
)

FIXTURES = Path(__file__).parents[2] / "fixtures" / "airos"
LOCO_STA = FIXTURES / "status_cgi_NanoStation_loco_M5_XM_v6.3.16_sta.json"
LOCO_AP = FIXTURES / "status_cgi_NanoStation_loco_M5_XM_v6.3.16_ap.json"
XW_STA = FIXTURES / "status_cgi_NanoStation_M5_XW_v6.3.16_sta.json"

#: A wstalist/sta.cgi answer in the firmware's shape (docs/PROTOCOLS.md 4.4), with the
#: signal/rssi pairs of real wstalist dumps (-48/48, -51/45, -44/52).
STA_CGI = [
    {
        "mac": "00:27:22:AA:BB:01",
        "name": "relay-1",
        "lastip": "192.168.1.31",
        "associd": 1,
        "tx": 150.0,
        "rx": 130.0,
        "signal": -48,
        "rssi": 48,
        "chainrssi": [48, 45, 0],
        "ccq": 91,
        "noisefloor": -95,
        "uptime": 812,
        "distance": 600,
        "airmax": {"priority": 0, "quality": 88, "beam": 0, "signal": 0, "capacity": 70},
    },
    {
        "mac": "00:27:22:AA:BB:02",
        "name": "relay-2",
        "tx": 65,
        "rx": "58.5",
        "signal": -51,
        "rssi": 45,
        "ccq": 77,
        "noisefloor": -94,
    },
    {"mac": "00:27:22:aa:bb:03", "tx": 300.0, "rx": 270.0, "signal": -44, "rssi": 52, "ccq": 99},
]


@pytest.mark.parametrize(
    ("path", "signal", "rssi", "noise", "ccq_pct", "tx", "rx", "mode", "essid", "freq"),
    [
        (LOCO_STA, -46, 50, -89, 73.8, 243, 180, "sta", "SOMETHING", 5700),
        (LOCO_AP, -45, 51, -91, 87.0, 270, 300, "ap", "SOMETHING", 5700),
        (XW_STA, -64, 32, -99, 99.1, 270, 216, "sta", "Nano", 5180),
    ],
)
def test_real_captures(path, signal, rssi, noise, ccq_pct, tx, rx, mode, essid, freq) -> None:
    q = decode_status(path.read_bytes(), t=12.5)
    assert q.t == 12.5
    assert q.signal_dbm == signal
    assert q.rssi == rssi
    assert q.rssi == q.signal_dbm + 96  # the cross-check that holds on every capture
    assert q.noise_dbm == noise
    assert q.ccq_pct == pytest.approx(ccq_pct)  # status.cgi ccq is per-mille
    assert q.tx_mbps == tx and isinstance(q.tx_mbps, float)  # "243" (a string) -> 243.0
    assert q.rx_mbps == rx
    assert q.mode == mode
    assert q.essid == essid
    assert q.frequency_mhz == freq  # "5700 MHz"
    if mode == "sta":
        # A station's only peer is its AP, described by status.cgi's own fields.
        assert len(q.stations) == 1
        ap = q.stations[0]
        assert (ap.signal_dbm, ap.ccq_pct, ap.tx_mbps, ap.rx_mbps) == (signal, q.ccq_pct, tx, rx)
        assert q.best_station_signal_dbm == signal
    else:
        assert q.stations == ()  # status.cgi on an AP has no per-station data: sta.cgi does
        assert q.best_station_signal_dbm is None


def test_sta_cgi_units() -> None:
    stations = decode_stations(json.dumps(STA_CGI))
    assert [s.mac for s in stations] == [
        "00:27:22:AA:BB:01",
        "00:27:22:AA:BB:02",
        "00:27:22:aa:bb:03",
    ]
    first = stations[0]
    assert first == Station(
        mac="00:27:22:AA:BB:01",
        signal_dbm=-48,
        ccq_pct=91,
        tx_mbps=150.0,
        rx_mbps=130.0,
        noise_dbm=-95,
        name="relay-1",
    )
    assert first.rssi == 48
    assert stations[1].ccq_pct == 77  # percent here, NOT per-mille
    assert stations[1].rx_mbps == 58.5  # a string rate is still Mbit/s
    q = parse_status(json.loads(LOCO_AP.read_text()), t=0.0, stations=stations)
    assert q.best_station_signal_dbm == -44
    assert q.best_station is stations[2]
    assert q.station_signal_dbm("00-27-22-AA-BB-03") == -44  # case and separator don't matter
    assert q.station_signal_dbm("00:27:22:aa:bb:02") == -51
    assert q.station_signal_dbm("00:00:00:00:00:00") is None


def test_probe_json_keys() -> None:
    q = decode_status(LOCO_STA.read_bytes(), t=0.0)
    out = q.to_json()
    assert list(out)[:7] == [
        "signal_dbm",
        "rssi",
        "noise_dbm",
        "ccq_pct",
        "tx_mbps",
        "rx_mbps",
        "stations",
    ]
    assert out["stations"][0]["signal_dbm"] == -46
    json.dumps(out)


def test_odd_fields_become_none() -> None:
    doc = {
        "wireless": {
            "signal": "n/a",
            "rssi": True,
            "noisef": None,
            "ccq": 1500,
            "txrate": "-",
            "rxrate": float("nan"),
            "mode": 3,
            "essid": ["x"],
            "frequency": {"a": 1},
        }
    }
    q = parse_status(doc, t=1.0)
    assert (q.signal_dbm, q.rssi, q.noise_dbm, q.ccq_pct, q.tx_mbps, q.rx_mbps) == (None,) * 6
    assert (q.mode, q.essid, q.frequency_mhz, q.stations) == (None, None, None, ())


def test_one_of_signal_and_rssi_gives_the_other() -> None:
    assert parse_status({"wireless": {"rssi": 40}}, t=0).signal_dbm == -56
    assert parse_status({"wireless": {"signal": -70}}, t=0).rssi == 26
    # A positive "signal" is not dBm: implausible values are dropped, not trusted.
    assert parse_status({"wireless": {"signal": 500, "rssi": 500}}, t=0).signal_dbm is None


def test_airos8_embedded_station_list() -> None:
    doc = {"wireless": {"mode": "ap-ptmp", "noisef": -96, "sta": STA_CGI[:2]}}
    q = parse_status(doc, t=0)
    assert q.mode == "ap"
    assert [s.signal_dbm for s in q.stations] == [-48, -51]
    assert q.best_station_signal_dbm == -48


@pytest.mark.parametrize(
    "raw",
    [
        b"",
        b"{",
        b"<html>login</html>",
        b"\xff\xfe\x00",
        b"[" * 100_000,
        b"null",
        b"[]",
        b'{"host": {}}',
        b'{"wireless": []}',
        b"42",
    ],
)
def test_not_a_status_document(raw: bytes) -> None:
    with pytest.raises(AirOsDataError):
        decode_status(raw, t=0)


@pytest.mark.parametrize("raw", [b"{}", b'{"mac": 1}', b"nope", b"[" * 100_000])
def test_not_a_station_list(raw: bytes) -> None:
    with pytest.raises(AirOsDataError):
        decode_stations(raw)


def test_station_list_skips_non_objects() -> None:
    assert len(parse_stations([1, "x", None, [], {"mac": "m"}])) == 1


# -- fuzzing ---------------------------------------------------------------------------------

FIELDS = [
    "signal",
    "rssi",
    "noisef",
    "noisefloor",
    "ccq",
    "txrate",
    "rxrate",
    "tx",
    "rx",
    "mode",
    "essid",
    "frequency",
    "apmac",
    "mac",
    "name",
    "sta",
    "chainrssi",
    "count",
    "hostname",
]
scalars = (
    st.none()
    | st.booleans()
    | st.integers()
    | st.integers(min_value=-(10**400), max_value=10**400)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=12)
    | st.sampled_from(["5700 MHz", "243", "-46", "1e999", "-inf", "NaN", " 12.5 Mbps", "ap-ptp"])
)
json_ish = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=4)
        | st.dictionaries(st.sampled_from(FIELDS) | st.text(max_size=6), inner, max_size=6)
    ),
    max_leaves=8,
)
field_values = (
    scalars
    | st.lists(scalars, max_size=3)
    | st.lists(st.dictionaries(st.sampled_from(FIELDS), scalars, max_size=5), max_size=3)
)
wireless = st.dictionaries(st.sampled_from(FIELDS), field_values, max_size=10)


def _check(q: LinkQuality) -> None:
    for v in (q.signal_dbm, q.noise_dbm):
        assert v is None or (math.isfinite(v) and -130 <= v <= 10)
    assert q.ccq_pct is None or 0 <= q.ccq_pct <= 100
    for v in (q.tx_mbps, q.rx_mbps, q.rssi):
        assert v is None or (math.isfinite(v) and v >= 0)
    for s in q.stations:
        assert isinstance(s, Station)
        assert s.signal_dbm is None or -130 <= s.signal_dbm <= 10
        assert s.ccq_pct is None or 0 <= s.ccq_pct <= 100
    q.best_station_signal_dbm  # noqa: B018 - must not raise either
    json.dumps(q.to_json())


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    w=wireless,
    host=scalars | st.dictionaries(st.sampled_from(FIELDS), scalars, max_size=3),
    mode=st.sampled_from(["ap", "sta", "ap-ptmp", "x", None]),
)
def test_fuzz_status_never_raises(w, host, mode) -> None:
    if mode is not None:
        w = {**w, "mode": mode}
    _check(parse_status({"wireless": w, "host": host}, t=0.0))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(doc=json_ish)
def test_fuzz_any_document(doc) -> None:
    try:
        _check(parse_status(doc, t=0.0))
    except AirOsDataError:
        pass
    try:
        for s in parse_stations(doc):
            assert isinstance(s, Station)
    except AirOsDataError:
        pass


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    raw=st.binary(max_size=200)
    | st.text(max_size=200).map(str.encode)
    | json_ish.map(lambda d: json.dumps(d)[:150].encode())
)
def test_fuzz_raw_bytes(raw: bytes) -> None:
    for decode in (lambda r: decode_status(r, t=0.0), decode_stations):
        try:
            decode(raw)
        except AirOsDataError:
            pass


ODD_VALUES = [
    None,
    True,
    False,
    0,
    -1,
    1,
    10**400,
    -(10**400),
    1e308,
    -1e308,
    float("nan"),
    float("inf"),
    "",
    " ",
    "n/a",
    "243",
    "-46",
    "5700 MHz",
    "1e999",
    "NaN",
    "-inf",
    "\x00",
    "٣",
    [],
    {},
    [1, 2],
    {"a": None},
    -46,
    738,
    1001,
    -200,
    500,
    2.5,
]


def _random_doc(rng: random.Random, depth: int = 0) -> object:
    if depth > 2 or rng.random() < 0.5:
        return rng.choice(ODD_VALUES)
    if rng.random() < 0.3:
        return [_random_doc(rng, depth + 1) for _ in range(rng.randrange(4))]
    return {rng.choice(FIELDS): _random_doc(rng, depth + 1) for _ in range(rng.randrange(8))}


def test_bulk_random_documents() -> None:
    """Tens of thousands of seeded-random documents, cheaper per case than hypothesis's."""
    rng = random.Random(20261123)
    parsed = 0
    for _ in range(20_000):
        w = {rng.choice(FIELDS): _random_doc(rng, 1) for _ in range(rng.randrange(12))}
        _check(parse_status({"wireless": w, "host": _random_doc(rng)}, t=0.0))
        doc = _random_doc(rng)
        raw = json.dumps(doc).encode()
        cut = raw[: rng.randrange(len(raw) + 1)]
        for decode in (lambda r: decode_status(r, t=0.0), decode_stations):
            for blob in (raw, cut):
                try:
                    decode(blob)
                    parsed += 1
                except AirOsDataError:
                    pass
    assert parsed > 0  # some of them were real documents, not only errors


def test_rssi_that_means_an_impossible_signal_gives_no_signal() -> None:
    # Found by the fuzzer: rssi 107 would be +11 dBm.
    assert _signal_pair(None, 107) == (None, 107.0)
    assert _signal_pair(None, 50) == (-46.0, 50.0)
