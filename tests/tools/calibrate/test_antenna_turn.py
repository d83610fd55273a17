"""`relayd calibrate antenna --turn-steps`: the relay turns itself in place between sweeps.

Against a fake daemon on localhost: its heading turns with the wheel commands it is
sent (and stops without them, as the dead-man time does), its scans hear a node through
the "yagi" pattern at the heading of the moment.
"""

from __future__ import annotations

import asyncio
import itertools
import math
from pathlib import Path
from typing import Any

import pytest
from aiohttp import web

from relayd.calibrate.antenna import measure_pattern
from relayd.calibrate.antenna_turn import TurnOptions, sample_turning
from relayd.calibrate.sources import SourceError
from relayd.cli import main
from relayd.sim.antennas import FAMILY

ANGLES = [-90.0 + 7.5 * i for i in range(25)]


class FakeDaemon:
    """Heading from the wheels, a scan per two polls. The heading advances per /status poll
    (200 mm/s between the wheels: 3 deg a poll), not with the wall clock, so how fast a
    loaded machine polls does not change what the test sees."""

    def __init__(self, stop_reason: str | None = None) -> None:
        self.mode = "hold"
        self.theta = 0.0
        self.wheels = (0.0, 0.0, 0.0)  # left, right, when
        self.polls = 0
        self.scan_t = 0.0
        self.log: list[tuple[str, Any]] = []
        self.stop_reason = stop_reason

    def _advance(self, now: float) -> None:
        left, right, sent = self.wheels
        if self.mode == "manual" and now - sent <= 0.5:  # the dead-man time
            self.theta = math.remainder(self.theta + (right - left) * 0.015, 360.0)

    async def status(self, request: web.Request) -> web.Response:
        now = asyncio.get_running_loop().time()
        self._advance(now)
        self.polls += 1
        if self.polls % 2 == 0:
            self.scan_t += 1.0
        gain = FAMILY["yagi"]
        rssi = [round(-45.0 + gain(math.remainder(-self.theta - a, 360.0))) for a in ANGLES]
        reason = (
            self.stop_reason if self.wheels[:2] != (0.0, 0.0) and self.stop_reason else "manual"
        )
        return web.json_response(
            {
                "mode": self.mode,
                "reason": reason,
                "pose": {"x_mm": 0.0, "y_mm": 0.0, "theta_deg": self.theta},
                "last_scan": {"t": self.scan_t, "angles": ANGLES, "rssi": rssi},
            }
        )

    async def mode_(self, request: web.Request) -> web.Response:
        assert request.headers["Authorization"] == "Bearer secret"
        self.mode = (await request.json())["mode"]
        self.log.append(("mode", self.mode))
        return web.json_response({"ok": True, "mode": self.mode})

    async def drive(self, request: web.Request) -> web.Response:
        assert request.headers["Authorization"] == "Bearer secret"
        if self.mode != "manual":
            return web.json_response({"error": "drive commands need manual mode"}, status=409)
        body = await request.json()
        now = asyncio.get_running_loop().time()
        self.wheels = (body["left_mm_s"], body["right_mm_s"], now)
        self.log.append(("drive", (body["left_mm_s"], body["right_mm_s"])))
        return web.json_response({"ok": True})


async def _serve(fake: FakeDaemon) -> tuple[web.AppRunner, str]:
    app = web.Application()
    app.router.add_get("/status", fake.status)
    app.router.add_post("/api/mode", fake.mode_)
    app.router.add_post("/api/drive", fake.drive)
    runner = web.AppRunner(app)
    await runner.setup()
    site = web.TCPSite(runner, "127.0.0.1", 0)
    await site.start()
    return runner, f"http://127.0.0.1:{runner.addresses[0][1]}"


async def test_four_headings_measure_the_back_lobe_and_leave_the_relay_in_hold() -> None:
    fake = FakeDaemon()
    runner, url = await _serve(fake)
    opts = TurnOptions(url, "secret", steps=4, sweeps_per_step=4, speed_mm_s=100.0, hz=200.0)
    try:
        samples = await sample_turning(opts)
    finally:
        await runner.cleanup()
    headings = list(dict.fromkeys(round(s.heading_deg) for s in samples))  # in turn order
    assert len(headings) == 4 and len({s.sweep for s in samples}) == 16
    # 90 deg apart, to within the stop's tolerance and one poll's 3 deg.
    turned = [math.remainder(b - a, 360.0) for a, b in itertools.pairwise(headings)]
    assert all(abs(d - 90.0) <= 4.0 for d in turned), headings
    # Turned in place only (one wheel back, one forward), slowly, stopped after each step,
    # in manual mode; hold at the end.
    drives = [v for k, v in fake.log if k == "drive"]
    assert all(left == -right and abs(right) <= 100.0 for left, right in drives)
    assert drives.count((0.0, 0.0)) == 3 and drives[-1] == (0.0, 0.0)
    assert fake.log[0] == ("mode", "manual") and fake.log[-1] == ("mode", "hold")
    # The back half is measured: the yagi's -15 dB back lobe, which a servo sweep never sees.
    cal = measure_pattern(samples)
    assert cal.pattern.full_circle
    assert cal.front_to_back_db == pytest.approx(15.0, abs=2.0)


async def test_a_daemon_that_stops_the_robot_ends_it_in_hold() -> None:
    fake = FakeDaemon(stop_reason="obstacle")
    runner, url = await _serve(fake)
    opts = TurnOptions(url, "secret", steps=2, sweeps_per_step=4, speed_mm_s=100.0, hz=200.0)
    try:
        with pytest.raises(SourceError, match="obstacle"):
            await sample_turning(opts)
    finally:
        await runner.cleanup()
    assert fake.log[-2:] == [("drive", (0.0, 0.0)), ("mode", "hold")]


def test_turning_needs_a_live_relay_and_a_token(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv("RELAYD_API_TOKEN", raising=False)
    base = ["calibrate", "antenna", "--out", str(tmp_path)]
    assert main([*base, "--from", str(tmp_path / "x.mcap"), "--turn-steps", "4"]) == 2
    assert "needs --url" in capsys.readouterr().err
    assert main([*base, "--url", "http://127.0.0.1:9", "--turn-steps", "4"]) == 2
    assert "RELAYD_API_TOKEN" in capsys.readouterr().err
    assert main([*base, "--url", "http://127.0.0.1:9", "--turn-steps", "1"]) == 2
    assert not list(tmp_path.iterdir())
