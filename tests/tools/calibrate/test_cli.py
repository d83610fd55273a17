"""`relayd calibrate path-loss` end to end: on a synthetic recording, and live against a relayd API."""

from __future__ import annotations

import argparse
import json
import math
import tomllib
from pathlib import Path
from typing import Any

import pytest
from aiohttp import web

from relayd.calibrate import cli as calibrate_cli
from relayd.calibrate.sources import LiveOptions, readings_from_messages, sample_live
from relayd.calibrate.synthetic import drive_messages, write_recording
from relayd.cli import main


def test_cli_on_a_synthetic_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "drive.mcap"
    # Far enough (60 m) that the rate falls below the target: the measured threshold appears.
    write_recording(
        rec, drive_messages(l0_dbm=-20.0, n=3.0, sigma_db=3.0, seed=4, far_m=60.0, penalty_db=6.0)
    )
    out = tmp_path / "out"
    code = main(
        [
            "calibrate",
            "path-loss",
            "--from",
            str(rec),
            "--hop-m",
            "12",
            "--target-mbps",
            "10",
            "--out",
            str(out),
        ]
    )
    text = capsys.readouterr().out
    assert code == 0, text
    doc = json.loads((out / "path-loss.json").read_text())
    assert doc["fit"]["n"] == pytest.approx(3.0, abs=0.2)
    assert doc["fit"]["l0_dbm"] == pytest.approx(-20.0, abs=2.0)
    thr = doc["thresholds"]
    # 6 dB of multipath: the rates say ~6 dB more than the 802.11g table would.
    assert (
        thr["by_measured_rate"] is not None and thr["by_measured_rate"] > thr["by_throughput"] + 2.0
    )
    assert (out / "path-loss.toml").read_text().endswith("\n")
    snippet = tomllib.loads((out / "path-loss.toml").read_text())
    assert snippet["control"]["threshold_b_dbm"] == round(thr["chosen"])
    assert snippet["control"]["target_hop_mbps"] == 10
    assert (out / "path-loss.png").stat().st_size > 10_000
    assert "L0" in text and "threshold_b_dbm" in text


def test_cli_errors_are_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["calibrate", "path-loss", "--from", str(tmp_path / "missing.mcap")]) == 2
    assert "missing.mcap" in capsys.readouterr().err
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    assert main(["calibrate", "path-loss", "--from", str(junk)]) == 2
    assert "not a readable MCAP" in capsys.readouterr().err
    short = tmp_path / "short.mcap"
    write_recording(short, drive_messages(l0_dbm=-20.0, n=2.5, sigma_db=3.0, seed=1, far_m=1.5))
    assert main(["calibrate", "path-loss", "--from", str(short)]) == 2
    assert "usable readings" in capsys.readouterr().err


def test_readings_take_the_distance_of_the_last_sip() -> None:
    sip = {"sip": {"x_mm": 0.0, "y_mm": 0.0}}
    msgs: list[tuple[str, dict[str, Any]]] = [
        (
            "/link",
            {"t": 0.0, "side": "rear", "quality": {"signal_dbm": -30.0}},
        ),  # before odometry: dropped
        ("/robot/sip", sip),
        ("/robot/sip", {"sip": {"x_mm": 3000.0, "y_mm": 4000.0}}),
        ("/link", {"t": 1.0, "side": "front", "quality": {"signal_dbm": -50.0}}),
        (
            "/link",
            {
                "t": 1.0,
                "side": "rear",
                "quality": {"signal_dbm": -40.0, "tx_mbps": 54.0, "stations": []},
            },
        ),
        ("/wifi/rssi", {"t": 1.1, "sample": {"rssi_dbm": -45.0, "fresh": True}}),
    ]
    rear = readings_from_messages(msgs, start_distance_m=2.0)
    assert [(r.distance_m, r.rssi_dbm, r.tx_mbps) for r in rear] == [(7.0, -40.0, 54.0)]
    leader = readings_from_messages(msgs, link="leader")
    assert [(r.distance_m, r.rssi_dbm) for r in leader] == [(6.0, -45.0)]


class FakeRelayd:
    """A relayd API as `calibrate --drive` sees it: /status, /api/mode, /api/drive with a token.
    Each /status read moves a driven robot 0.25 s worth along x (no wall clock), the rear
    link following L0 = -20 dBm, n = 3 exactly; past `wall_m` it reports an obstacle stop."""

    def __init__(self, token: str, wall_m: float = 1e9) -> None:
        self.token, self.wall_m = token, wall_m
        self.mode, self.speed, self.x_mm = "hold", 0.0, 0.0
        self.modes: list[str] = []
        self.drives = 0

    def app(self) -> web.Application:
        app = web.Application()
        app.router.add_get("/status", self.status)
        app.router.add_post("/api/mode", self.set_mode)
        app.router.add_post("/api/drive", self.drive)
        return app

    def _authorized(self, request: web.Request) -> bool:
        return request.headers.get("Authorization") == f"Bearer {self.token}"

    async def status(self, request: web.Request) -> web.Response:
        reason = "manual" if self.mode == "manual" else self.mode
        if self.mode == "manual" and self.speed > 0:
            if self.x_mm / 1000.0 >= self.wall_m:
                reason = "obstacle"
            else:
                self.x_mm += self.speed * 0.25
        d = 1.0 + self.x_mm / 1000.0
        signal = -20.0 - 30.0 * math.log10(d)
        return web.json_response(
            {
                "pose": {"x_mm": self.x_mm, "y_mm": 0.0, "theta_deg": 0.0},
                "uptime_s": 1.0,
                "reason": reason,
                "rssi_behind_dbm": signal,
                "links": {
                    "rear": {
                        "signal_dbm": signal,
                        "tx_mbps": 54.0,
                        "rx_mbps": 54.0,
                        "ccq_pct": 90.0,
                    }
                },
            }
        )

    async def set_mode(self, request: web.Request) -> web.Response:
        if not self._authorized(request):
            return web.json_response({"error": "token"}, status=401)
        self.mode = (await request.json())["mode"]
        self.modes.append(self.mode)
        self.speed = 0.0
        return web.json_response({"ok": True})

    async def drive(self, request: web.Request) -> web.Response:
        if not self._authorized(request):
            return web.json_response({"error": "token"}, status=401)
        if self.mode != "manual":
            return web.json_response({"error": "mode"}, status=409)
        body = await request.json()
        self.speed = (body["left_mm_s"] + body["right_mm_s"]) / 2.0
        self.drives += 1
        return web.json_response({"ok": True})


async def _serve(fake: FakeRelayd) -> tuple[web.AppRunner, str]:
    runner = web.AppRunner(fake.app())
    await runner.setup()
    site = web.TCPSite(runner, "127.0.0.1", 0)
    await site.start()
    port = runner.addresses[0][1]
    return runner, f"http://127.0.0.1:{port}"


async def test_drive_goes_through_manual_mode_and_ends_in_hold() -> None:
    fake = FakeRelayd("s3cret")
    runner, url = await _serve(fake)
    try:
        readings, why = await sample_live(
            LiveOptions(
                url=url,
                drive=True,
                token="s3cret",
                speed_mm_s=200.0,
                distance_m=5.0,
                hz=50.0,
                seconds=60.0,
            )
        )
    finally:
        await runner.cleanup()
    assert why == "distance"
    assert fake.modes == ["manual", "hold"] and fake.drives > 0
    assert readings[-1].distance_m >= 6.0
    assert readings[-1].tx_mbps == 54.0


async def test_drive_stops_on_a_fail_safe_and_read_only_never_posts() -> None:
    fake = FakeRelayd("s3cret", wall_m=2.0)
    runner, url = await _serve(fake)
    try:
        _, why = await sample_live(
            LiveOptions(url=url, drive=True, token="s3cret", distance_m=10.0, hz=50.0)
        )
        assert "obstacle" in why and fake.modes[-1] == "hold"
        quiet = FakeRelayd("s3cret")
        runner2, url2 = await _serve(quiet)
        try:
            readings, why2 = await sample_live(LiveOptions(url=url2, seconds=0.3, hz=20.0))
        finally:
            await runner2.cleanup()
        assert quiet.modes == [] and quiet.drives == 0 and why2 == "time" and readings
    finally:
        await runner.cleanup()


async def test_drive_needs_a_token(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv("RELAYD_API_TOKEN", raising=False)
    parser = argparse.ArgumentParser()
    calibrate_cli.configure(parser)
    args = parser.parse_args(["--url", "http://127.0.0.1:9", "--drive"])
    assert await calibrate_cli.run(args) == 2
    assert "token" in capsys.readouterr().err


def test_synthetic_guided_drive_is_slow_through_the_first_metres() -> None:
    """As --drive: a third of the speed inside near_m, so three times the readings per metre there."""
    msgs = drive_messages(
        l0_dbm=-20.0, n=3.0, sigma_db=0.0, seed=1, far_m=12.0, near_m=4.0, poll_s=0.5
    )
    readings = readings_from_messages(msgs)
    near = sum(1 for r in readings if 1.5 <= r.distance_m < 3.5)
    far = sum(1 for r in readings if 6.0 <= r.distance_m < 8.0)
    assert near == pytest.approx(3 * far, rel=0.1)
    assert readings[-1].distance_m == pytest.approx(12.0, abs=0.1)


def test_the_leader_link_prints_the_median_gap_and_the_bound_on_it() -> None:
    """threshold_l for a gap: the median level there (the snippet's choice) and, beside it, the
    level that keeps the robot within the gap but with the outage probability."""
    from relayd.calibrate.fit import PathLossFit
    from relayd.calibrate.report import Wanted, config_snippet, text_report, thresholds

    fit = PathLossFit.known(-20.0, 2.5, 4.0)
    wanted = Wanted(link="leader", hop_m=5.0, outage=0.01)
    thr = thresholds(fit, [], wanted)
    assert thr.key == "threshold_l_dbm"
    assert thr.by_length == pytest.approx(fit.rssi_at(5.0))
    assert thr.bound == pytest.approx(fit.rssi_at(5.0) + 2.3263 * 4.0, abs=0.01)
    assert thr.chosen == thr.by_length  # the snippet keeps the median gap, as before
    text = text_report(fit, thr, wanted, "test")
    assert "following gap 5 m:  threshold_l_dbm = -37.5 dBm" in text
    assert (
        "gap at most 5 m (outage 0.01):  threshold_l_dbm = -28.2 dBm  (a median gap of 2.1 m)"
        in text
    )
    # The snippet's comment says what its value is: the median gap, not an outage level.
    assert "threshold_l_dbm = -37   # hop 5 m, the median gap" in config_snippet(
        fit, thr, wanted, "test"
    )
    rear = Wanted(link="rear", hop_m=5.0, outage=0.001)
    assert "# hop 5 m, at 0.1 % outage" in config_snippet(
        fit, thresholds(fit, [], rear), rear, "test"
    )
    # The rear link has no bound: its hop-length threshold already carries the margin.
    assert thresholds(fit, [], Wanted(link="rear", hop_m=5.0)).bound is None


def test_flat_rssi_is_refused_with_the_reason_and_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A drive whose RSSI does not fall (the node's radio off, a rig): no n of -0.00, no
    threshold of -55 written without a word, and never a ZeroDivisionError."""
    rec = tmp_path / "flat.mcap"
    write_recording(rec, drive_messages(l0_dbm=-55.0, n=0.0, sigma_db=0.0, seed=1, far_m=20.0))
    out = tmp_path / "out"
    args = ["calibrate", "path-loss", "--from", str(rec), "--out", str(out)]
    assert main([*args, "--target-mbps", "10", "--hop-m", "10"]) == 2
    err = capsys.readouterr().err
    assert "the RSSI does not fall with distance (n = " in err and "No threshold written" in err
    assert "Traceback" not in err and not out.exists()


@pytest.mark.parametrize(
    ("topic", "doc"),
    [
        ("/robot/sip", {"t": 1.0, "sip": [1, 2]}),
        ("/link", {"t": 1.0, "side": "rear", "quality": [1, 2]}),
        ("/link", {"t": 1.0, "side": "rear", "quality": {"stations": 5, "signal_dbm": -50}}),
        ("/link", {"t": 1.0, "side": "rear", "quality": {"stations": "x"}}),
        ("/wifi/rssi", {"t": 1.0, "sample": [3]}),
    ],
)
def test_a_message_of_the_wrong_shape_loses_one_reading_not_the_calibration(
    topic: str, doc: dict[str, Any]
) -> None:
    good = drive_messages(l0_dbm=-20.0, n=2.5, sigma_db=1.0, seed=1, far_m=10.0)
    messages = [good[0], (topic, doc), *good[1:]]
    for link in ("rear", "leader"):
        readings_from_messages(messages, link=link)  # no AttributeError or TypeError
    assert len(readings_from_messages(messages)) >= len(readings_from_messages(good)) - 1


def test_the_distance_axis_is_labelled_in_plain_metres() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from relayd.calibrate.report import plain_log_axis

    fig, ax = plt.subplots()
    try:
        ax.plot([1.0, 2.0, 3.0, 8.1], [-20, -26, -30, -38])
        plain_log_axis(ax)
        fig.canvas.draw()
        labels = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
        minor = [t.get_text() for t in ax.get_xticklabels(minor=True) if t.get_text()]
    finally:
        plt.close(fig)
    assert labels and all(text.replace(".", "").isdigit() for text in labels), labels
    assert {"1", "2", "5"} <= set(labels) and not minor, (labels, minor)
