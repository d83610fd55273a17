"""`relayd probe ap` and `relayd fake ap` end to end, through relayd.cli.main."""

from __future__ import annotations

import asyncio
import itertools
import json
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from drivers.airos import Station
from drivers.airos.fake import FakeAirOs
from relayd.cli import main
from tests.support import piped_into_head

FIXTURES = Path(__file__).parents[2] / "fixtures" / "airos"
LOCO_AP = FIXTURES / "status_cgi_NanoStation_loco_M5_XM_v6.3.16_ap.json"
SECRET = "Pa55-w0rd-XYZZY"
REPO = Path(__file__).resolve().parents[3]


@contextmanager
def fake_in_thread(*args, **kwargs) -> Iterator[FakeAirOs]:
    """FakeAirOs on its own loop in a thread: cli.main() runs asyncio.run() in this one."""
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    fake = FakeAirOs(*args, **kwargs)
    try:
        asyncio.run_coroutine_threadsafe(fake.start(), loop).result(5)
        yield fake
    finally:
        asyncio.run_coroutine_threadsafe(fake.stop(), loop).result(5)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(5)
        loop.close()


def test_probe_json_v6(monkeypatch, capsys) -> None:
    monkeypatch.setenv("RELAYD_AP_PASSWORD", SECRET)
    with fake_in_thread("admin", SECRET) as fake:
        code = main(["probe", "ap", "--url", fake.base_url or "", "--username", "admin", "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    lines = out.splitlines()
    assert len(lines) == 1
    doc = json.loads(lines[0])
    assert list(doc)[:7] == [
        "signal_dbm",
        "rssi",
        "noise_dbm",
        "ccq_pct",
        "tx_mbps",
        "rx_mbps",
        "stations",
    ]
    assert (
        doc["signal_dbm"],
        doc["rssi"],
        doc["noise_dbm"],
        doc["ccq_pct"],
        doc["tx_mbps"],
        doc["rx_mbps"],
    ) == (-46, 50, -89, 73.8, 243, 180)
    assert doc["stations"][0]["signal_dbm"] == -46 and doc["mode"] == "sta"


def test_probe_ap_station_list_v8(monkeypatch, capsys) -> None:
    monkeypatch.setenv("RELAYD_AP_PASSWORD", SECRET)
    with fake_in_thread("ubnt", SECRET, fixture=LOCO_AP, version=8) as fake:
        fake.set_stations(
            [Station(mac="00:27:22:AA:BB:07", signal_dbm=-62, ccq_pct=88, tx_mbps=104, rx_mbps=78)]
        )
        code = main(
            [
                "probe",
                "ap",
                "--url",
                fake.base_url or "",
                "--username",
                "ubnt",
                "--json",
                "--firmware",
                "8",
            ]
        )
    out, err = capsys.readouterr()
    assert code == 0, err
    doc = json.loads(out)
    assert doc["mode"] == "ap" and doc["signal_dbm"] == -45 and doc["ccq_pct"] == 87.0
    assert doc["stations"] == [
        {
            "mac": "00:27:22:AA:BB:07",
            "name": "station-1",
            "signal_dbm": -62,
            "noise_dbm": None,
            "ccq_pct": 88,
            "tx_mbps": 104,
            "rx_mbps": 78,
        }
    ]


def test_probe_human_output(monkeypatch, capsys) -> None:
    monkeypatch.setenv("RELAYD_AP_PASSWORD", SECRET)
    with fake_in_thread("ubnt", SECRET) as fake:
        code = main(["probe", "ap", "--url", fake.base_url or "", "--username", "ubnt"])
    out, _ = capsys.readouterr()
    assert code == 0
    assert "signal   -46 dBm  (rssi 50)  noise -89 dBm" in out
    assert "ccq      73.8 %  tx 243 Mbit/s  rx 180 Mbit/s" in out


def test_probe_needs_the_password_env(monkeypatch, capsys) -> None:
    monkeypatch.delenv("RELAYD_AP_PASSWORD", raising=False)
    code = main(["probe", "ap", "--url", "http://127.0.0.1:9", "--username", "ubnt"])
    _, err = capsys.readouterr()
    assert code == 2
    assert "RELAYD_AP_PASSWORD" in err


def test_probe_wrong_password_and_unreachable(monkeypatch, capsys) -> None:
    monkeypatch.setenv("RELAYD_AP_PASSWORD", SECRET)
    with fake_in_thread("ubnt", "not-" + SECRET) as fake:
        url = fake.base_url or ""
        code = main(["probe", "ap", "--url", url, "--username", "ubnt", "--json"])
        out, err = capsys.readouterr()
        assert code == 1 and out == ""
        assert "wrong username or password" in err
        assert SECRET not in err
    # The fake is gone: its port now refuses connections.
    code = main(["probe", "ap", "--url", url, "--username", "ubnt", "--timeout", "1"])
    out, err = capsys.readouterr()
    assert code == 1 and out == ""
    assert url in err and SECRET not in err


def test_probe_rejects_a_bad_url(monkeypatch, capsys) -> None:
    monkeypatch.setenv("RELAYD_AP_PASSWORD", SECRET)
    assert main(["probe", "ap", "--url", "192.168.1.20", "--username", "ubnt"]) == 2
    assert "http://host" in capsys.readouterr().err


def test_fake_ap_command_serves_until_interrupted(monkeypatch, capsys) -> None:
    env = {**os.environ, "RELAYD_AP_PASSWORD": SECRET, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "relayd", "fake", "ap", "--fixture", str(LOCO_AP), "--version", "8"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=REPO,
    )
    try:
        assert proc.stdout is not None
        url = proc.stdout.readline().strip()
        assert url.startswith("http://127.0.0.1:"), proc.stderr.read() if proc.stderr else ""
        monkeypatch.setenv("RELAYD_AP_PASSWORD", SECRET)
        assert main(["probe", "ap", "--url", url, "--username", "ubnt", "--json"]) == 0
        doc = json.loads(capsys.readouterr().out)
        assert doc["mode"] == "ap" and [s["signal_dbm"] for s in doc["stations"]] == [-45]
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 130
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_fake_ap_bad_fixture(tmp_path, capsys) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("[]")
    assert main(["fake", "ap", "--fixture", str(bad)]) == 2
    assert "wireless" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["fake", "ap", "--version", "7"])


def test_probe_ap_series_for_seconds_at_an_interval(monkeypatch, capsys) -> None:
    monkeypatch.setenv("RELAYD_AP_PASSWORD", SECRET)
    with fake_in_thread("admin", SECRET) as fake:
        code = main(
            [
                "probe",
                "ap",
                "--url",
                fake.base_url or "",
                "--username",
                "admin",
                "--json",
                "--seconds",
                "1.0",
                "--interval",
                "0.25",
            ]
        )
    out, err = capsys.readouterr()
    assert code == 0, err
    docs = [json.loads(line) for line in out.splitlines()]
    # Readings at t = 0, 0.25, 0.5, 0.75, 1.0 (a slow machine may drop the last one).
    assert 4 <= len(docs) <= 5
    ts = [d["t"] for d in docs]
    assert ts[0] < 0.2 and all(b > a for a, b in itertools.pairwise(ts)) and ts[-1] <= 1.3
    assert all(d["signal_dbm"] == -46 for d in docs)
    assert f"# {len(docs)} reading(s) in 1 s, median signal -46 dBm" in err


def test_probe_ap_rejects_bad_series_options(monkeypatch, capsys) -> None:
    monkeypatch.setenv("RELAYD_AP_PASSWORD", SECRET)
    assert (
        main(["probe", "ap", "--url", "http://127.0.0.1:9", "--seconds", "5", "--interval", "0"])
        == 2
    )
    assert "--interval" in capsys.readouterr().err


def test_probe_ap_series_piped_into_head_stops_quietly(monkeypatch) -> None:
    """`relayd probe ap --seconds 60 | head -1`: exit 0 at the next reading, no traceback."""
    monkeypatch.setenv("RELAYD_AP_PASSWORD", SECRET)
    with fake_in_thread("admin", SECRET) as fake:
        code, got, err, _ = piped_into_head(
            [
                "probe",
                "ap",
                "--url",
                fake.base_url or "",
                "--username",
                "admin",
                "--json",
                "--seconds",
                "60",
                "--interval",
                "0.1",
            ],
            lines=1,
            timeout_s=30,
        )
    assert json.loads(got[0])["signal_dbm"] == -46
    assert code == 0, err
    for noise in ("BrokenPipe", "Traceback", "Exception ignored", "reading(s)"):
        assert noise not in err, err[:2000]
