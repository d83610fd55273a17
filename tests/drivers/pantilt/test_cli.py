"""`relayd probe pantilt` through relayd.cli.main against `relayd fake pantilt` in a subprocess."""

from __future__ import annotations

import json
import select
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from relayd.cli import main
from tests.support import piped_into_head


@pytest.fixture(params=["maestro", "ssc32"])
def served(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[tuple[str, str]]:
    link = tmp_path / "servo"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "relayd",
            "fake",
            "pantilt",
            "--protocol",
            request.param,
            "--link",
            str(link),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], 20)
        assert ready, "the fake did not print its path"
        path = proc.stdout.readline().strip()
        assert path == str(link) and link.exists()
        yield request.param, path
    finally:
        proc.terminate()
        proc.wait(10)
    assert not link.exists()  # the fake removed its link on the way out


def probe(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(["probe", "pantilt", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_probe_moves_waits_and_reads_back(
    served: tuple[str, str], capsys: pytest.CaptureFixture[str]
) -> None:
    protocol, path = served
    base = ["--port", path, "--protocol", protocol, "--channel", "1", "--json"]
    code, out, err = probe(capsys, *base, "--angle", "0")
    assert code == 0, err
    assert json.loads(out) == {"channel": 1, "angle_deg": 0.0, "pulse_us": 1500.0, "moving": False}
    # 36 deg at 180 deg/s: the probe waits ~0.2 s for the move, then reads it back.
    code, out, _ = probe(capsys, *base, "--angle", "36", "--speed", "180")
    assert code == 0
    reply = json.loads(out)
    assert reply["moving"] is False
    assert reply["angle_deg"] == pytest.approx(36, abs=1.0)
    assert reply["pulse_us"] == pytest.approx(1500 + 36 * 500 / 90, abs=12)
    # Outside the limits: refused with exit 2, and nothing moved.
    code, out, err = probe(capsys, *base, "--angle", "150")
    assert code == 2 and out == ""
    assert "outside the limits -90..90" in err
    code, out, err = probe(capsys, *base, "--angle=-45", "--limits=-30,30")
    assert code == 2 and "outside the limits -30..30" in err
    # Read only, human output: still where the last accepted move left it, with its pulse.
    code, out, _ = probe(capsys, "--port", path, "--protocol", protocol, "--channel", "1")
    assert code == 0 and out.startswith("channel 1: 36.")
    assert "pulse 17" in out
    # A calibration with decreasing pulses (servo upside down): the pulse is the one sent.
    code, out, _ = probe(capsys, *base, "--angle", "90", "--pulse-us", "2000,1500,1000")
    assert code == 0 and json.loads(out)["pulse_us"] == pytest.approx(1000, abs=4)


def test_probe_into_a_reader_that_closed_exits_0(served: tuple[str, str]) -> None:
    """`relayd probe pantilt ... | true`: the reading is done, so no traceback and exit 0."""
    protocol, path = served
    code, _, err, _ = piped_into_head(
        [
            "probe",
            "pantilt",
            "--port",
            path,
            "--protocol",
            protocol,
            "--channel",
            "1",
            "--angle",
            "0",
        ],
        lines=0,
        timeout_s=30,
    )
    assert code == 0, err
    for noise in ("BrokenPipe", "Traceback", "Exception ignored"):
        assert noise not in err, err[:2000]


def test_probe_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = probe(
        capsys, "--port", str(tmp_path / "nothing"), "--protocol", "maestro", "--channel", "0"
    )
    assert code == 1 and out == "" and "cannot open" in err
    code, _, err = probe(capsys, "--port", "/dev/null", "--protocol", "ssc32", "--channel", "40")
    assert code == 2 and "channel out of range" in err
    code, _, err = probe(
        capsys,
        "--port",
        "/dev/null",
        "--protocol",
        "ssc32",
        "--channel",
        "0",
        "--pulse-us",
        "1000,900,2000",
    )
    assert code == 2 and "monotonic" in err


def test_fake_pantilt_defaults_to_the_maestro() -> None:
    from relayd.cli import build_parser

    assert build_parser().parse_args(["fake", "pantilt"]).protocol == "maestro"
