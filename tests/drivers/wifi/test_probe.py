"""`relayd probe wifi` end to end through relayd.cli.main, on a ProcfsWriter file."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest

from drivers.wifi import ProcfsWriter
from relayd.cli import main
from tests.support import piped_into_head


def _lines(out: str) -> list[dict[str, object]]:
    return [json.loads(line) for line in out.splitlines() if line.strip()]


def test_probe_wifi_procfs_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "wireless"
    w = ProcfsWriter(path, "wlan1")
    w.write(-60)
    stop = threading.Event()

    def updates() -> None:
        level = -60
        while not stop.wait(0.03):
            level = -61 if level == -60 else -60
            w.write(level)

    th = threading.Thread(target=updates)
    th.start()
    try:
        code = main(
            [
                "probe",
                "wifi",
                "--source",
                "procfs",
                "--interface",
                "wlan1",
                "--path",
                str(path),
                "--seconds",
                "0.3",
                "--hz",
                "20",
                "--json",
            ]
        )
    finally:
        stop.set()
        th.join()
    out = capsys.readouterr().out
    samples = _lines(out)  # every stdout line is JSON: logs stay off stdout
    assert code == 0
    assert 4 <= len(samples) <= 8
    assert all(set(s) == {"t", "rssi_dbm", "fresh"} for s in samples)
    # t counts from the probe's start; a loaded machine may deliver the first read late,
    # after the writer's first flip (every 30 ms from the start).
    assert samples[0]["rssi_dbm"] in (-60.0, -61.0) and samples[0]["fresh"] is True
    assert 0.0 <= float(samples[0]["t"]) <= 0.3  # type: ignore[arg-type]
    assert all(s["rssi_dbm"] in (-60.0, -61.0) for s in samples)
    assert sum(bool(s["fresh"]) for s in samples) >= 2
    ts = [float(s["t"]) for s in samples]  # type: ignore[arg-type]
    assert ts == sorted(ts) and ts[-1] <= 0.3


def test_probe_wifi_missing_interface_exits_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "wireless"
    ProcfsWriter(path, "wlan0").write(-50)
    t0 = time.monotonic()
    code = main(
        [
            "probe",
            "wifi",
            "--source",
            "procfs",
            "--interface",
            "wlan1",
            "--path",
            str(path),
            "--seconds",
            "30",
            "--json",
        ]
    )
    captured = capsys.readouterr()
    # At the first read, not after --seconds of "stale" lines.
    assert code == 1 and time.monotonic() - t0 < 5
    assert captured.out == ""
    assert "relayd probe wifi: interface missing: wlan1 not listed" in captured.err


def test_probe_wifi_missing_file_exits_1_at_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t0 = time.monotonic()
    code = main(
        [
            "probe",
            "wifi",
            "--source",
            "procfs",
            "--path",
            str(tmp_path / "nothing"),
            "--seconds",
            "30",
        ]
    )
    captured = capsys.readouterr()
    assert code == 1 and time.monotonic() - t0 < 5
    assert "stale" not in captured.out
    assert "does not exist" in captured.err


def test_probe_wifi_missing_iw_binary_exits_1_at_once(capsys: pytest.CaptureFixture[str]) -> None:
    t0 = time.monotonic()
    code = main(["probe", "wifi", "--source", "iw", "--iw", "/nonexistent", "--seconds", "30"])
    captured = capsys.readouterr()
    assert code == 1 and time.monotonic() - t0 < 5
    assert captured.out == ""  # no "-- dBm stale" lines
    assert "no iw binary at '/nonexistent'" in captured.err


def test_probe_wifi_a_hung_source_is_bounded_by_seconds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    iw = tmp_path / "iw"
    iw.write_text("#!/bin/sh\nexec sleep 30\n")
    iw.chmod(0o755)
    t0 = time.monotonic()
    code = main(["probe", "wifi", "--source", "iw", "--iw", str(iw), "--seconds", "0.5"])
    assert code == 1 and time.monotonic() - t0 < 10
    assert capsys.readouterr().err


def test_probe_wifi_human_output(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "wireless"
    ProcfsWriter(path, "wlan1").write(-47)
    code = main(
        [
            "probe",
            "wifi",
            "--source",
            "procfs",
            "--interface",
            "wlan1",
            "--path",
            str(path),
            "--seconds",
            "0",
        ]
    )
    captured = capsys.readouterr()
    assert code == 0
    assert captured.out.splitlines() == ["   0.000 s    -47 dBm  fresh"]
    assert "samples=1" in captured.err


def test_probe_wifi_rejects_bad_rate(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["probe", "wifi", "--source", "procfs", "--hz", "0"]) == 2
    assert "--hz" in capsys.readouterr().err


def test_probe_wifi_iw_source_with_a_fake_binary(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    iw = tmp_path / "iw"
    iw.write_text(
        "#!/bin/sh\nprintf 'Connected to f4:f2:6d:22:7c:f0 (on wlan1)\\n\\tsignal: -52 dBm\\n'\n"
    )
    iw.chmod(0o755)
    code = main(["probe", "wifi", "--source", "iw", "--iw", str(iw), "--seconds", "0", "--json"])
    assert code == 0
    assert _lines(capsys.readouterr().out) == [{"t": 0.0, "rssi_dbm": -52.0, "fresh": True}]


def test_probe_wifi_after_the_daemons_logging_was_set_up(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A probe's warning must print even when the caller had configured the daemon's pipeline.

    The daemon's processors are stdlib-bound (logger names); the probe's own logger is a
    PrintLogger, so keeping the caller's processors raised AttributeError mid-probe.
    """
    import structlog

    from relayd.runtime.logsetup import StdStream, setup_logging

    setup_logging("info", "json", StdStream("stderr"))
    try:
        path = tmp_path / "wireless"
        ProcfsWriter(path, "wlan0").write(-50)
        code = main(
            [
                "probe",
                "wifi",
                "--source",
                "procfs",
                "--interface",
                "wlan1",
                "--path",
                str(path),
                "--seconds",
                "5",
                "--json",
            ]
        )
    finally:
        structlog.reset_defaults()
    captured = capsys.readouterr()
    assert code == 1
    assert "wifi_read_failed" in captured.err
    assert "relayd probe wifi: interface missing: wlan1 not listed" in captured.err


@pytest.mark.parametrize("fmt", [[], ["--json"]])
def test_probe_wifi_piped_into_head_stops_quietly(tmp_path: Path, fmt: list[str]) -> None:
    """`relayd probe wifi | head -1`: exit 0 at the next sample, no traceback.

    It used to die with a BrokenPipeError traceback and exit 1.
    """
    path = tmp_path / "wireless"
    ProcfsWriter(path, "wlan1").write(-47)
    code, got, err, _ = piped_into_head(
        [
            "probe",
            "wifi",
            "--source",
            "procfs",
            "--interface",
            "wlan1",
            "--path",
            str(path),
            "--seconds",
            "60",
            *fmt,
        ],
        lines=1,
        timeout_s=30,
    )
    assert "-47" in got[0]
    assert code == 0, err
    for noise in ("BrokenPipe", "Traceback", "Exception ignored"):
        assert noise not in err, err[:2000]
