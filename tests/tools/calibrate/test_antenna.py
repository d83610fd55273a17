"""`relayd calibrate antenna`: simulated calibrations recover every pattern; untrustworthy ones are refused."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from aiohttp import web

from relayd.calibrate.antenna import CalibrationRefused, measure_pattern
from relayd.calibrate.antenna_sources import (
    sample_live,
    samples_from_messages,
    sweep_messages,
    write_recording,
)
from relayd.cli import main
from relayd.config.model import load_pattern_file
from relayd.sim.antennas import FAMILY, family_pattern

TURNS = (0.0, 90.0, 180.0, 270.0)


@pytest.mark.parametrize("name", list(FAMILY))
def test_a_simulated_calibration_recovers_the_pattern(name: str) -> None:
    # 20 full sweeps at each of four headings (the robot turned in place between them),
    # LOS fading, whole-dB readings with +-1 dB of jitter.
    msgs = sweep_messages(FAMILY[name], seed=3, headings_deg=TURNS, sweeps_per_heading=20)
    cal = measure_pattern(samples_from_messages(msgs), distance_m=8.0)
    truth = FAMILY[name]
    lo, hi = family_pattern(name).main_lobe_deg()
    assert cal.pattern.full_circle
    for a, g in zip(cal.pattern.angles_deg, cal.pattern.gain_db_table, strict=True):
        main = lo <= a <= hi and truth(a) >= -10.0
        assert abs(g - truth(a)) <= (1.0 if main else 3.0), (a, g, truth(a))
    assert cal.beamwidth_deg == pytest.approx(family_pattern(name).beamwidth_deg(), abs=6.0)


@pytest.mark.parametrize(
    ("kw", "reason"),
    [
        ({"gain": lambda a: 0.0}, "flat pattern"),
        ({"level_dbm": -18.0}, "node too close"),
        ({"distance_m": 1.0}, "node too close"),
        ({"multipath": (35.0, -3.0)}, "unstable shape"),
        ({"sweeps_per_heading": 2}, "too few samples"),
        ({"node_bearing_deg": 95.0}, "edge of what was measured"),
    ],
)
def test_untrustworthy_measurements_are_refused(kw: dict[str, Any], reason: str) -> None:
    gain = kw.pop("gain", FAMILY["yagi"])
    distance = kw.pop("distance_m", None)
    msgs = sweep_messages(gain, seed=5, sweeps_per_heading=kw.pop("sweeps_per_heading", 12), **kw)
    with pytest.raises(CalibrationRefused) as ei:
        measure_pattern(samples_from_messages(msgs), distance_m=distance)
    assert any(reason in r for r in ei.value.reasons), ei.value.reasons


def test_cli_from_a_recording_writes_a_pattern_the_config_takes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec = tmp_path / "sweeps.mcap"
    write_recording(str(rec), sweep_messages(FAMILY["yagi"], seed=2, sweeps_per_heading=16))
    out = tmp_path / "out"
    code = main(
        ["calibrate", "antenna", "--from", str(rec), "--distance-m", "8", "--out", str(out)]
    )
    text = capsys.readouterr().out
    assert code == 0, text
    assert "3 dB beamwidth" in text and "worst side lobe" in text
    pattern = load_pattern_file(str(out / "antenna-pattern.toml"))
    assert pattern.beamwidth_deg() == pytest.approx(40.0, abs=5.0)
    assert dict(pattern.conditions)["distance_m"] == "8.0"
    doc = json.loads((out / "antenna-pattern.json").read_text())
    assert doc["side_lobe_db"] == pytest.approx(-10.0, abs=1.5)


def test_cli_refuses_and_writes_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "sweeps.mcap"
    write_recording(str(rec), sweep_messages(lambda a: 0.0, seed=2, sweeps_per_heading=8))
    out = tmp_path / "out"
    assert main(["calibrate", "antenna", "--from", str(rec), "--out", str(out)]) == 1
    assert "flat pattern" in capsys.readouterr().err
    assert not (out / "antenna-pattern.toml").exists()


async def test_live_sweeps_come_from_status() -> None:
    scans = iter(range(1000))
    gain = FAMILY["patch"]
    angles = [-90.0 + 7.5 * i for i in range(25)]

    async def status(request: web.Request) -> web.Response:
        k = next(scans)
        rssi = [round(-50.0 + gain(-a) + (k % 3 - 1)) for a in angles]
        return web.json_response(
            {
                "pose": {"x_mm": 0.0, "y_mm": 0.0, "theta_deg": 0.0},
                "last_scan": {"t": float(k), "angles": angles, "rssi": rssi},
            }
        )

    app = web.Application()
    app.router.add_get("/status", status)
    runner = web.AppRunner(app)
    await runner.setup()
    site = web.TCPSite(runner, "127.0.0.1", 0)
    await site.start()
    url = f"http://127.0.0.1:{runner.addresses[0][1]}"
    try:
        samples, why = await sample_live(url, sweeps=6, seconds=30.0, hz=100.0)
    finally:
        await runner.cleanup()
    assert why == "sweeps" and len({s.sweep for s in samples}) == 6 and len(samples) == 150
    cal = measure_pattern(samples)
    assert cal.beamwidth_deg == pytest.approx(70.0, abs=6.0)
