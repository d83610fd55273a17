"""`relayd calibrate path-loss` against a real relayd on fake devices, and on that relayd's own recording.

tests/tools/calibrate/test_cli.py checks the command's parsing, the fit's inputs and the
--drive protocol against a stand-in API. This file runs the whole path: an in-process
`Daemon` drives a `FakeRig` (the fake P3-AT on its ARCOS memory link, the fake airOS
radios on loopback) with recording on; `sample_live` drives it with `--drive`
through the daemon's manual mode, and the rear radio's signal follows the robot's
distance from a node behind it by the log-distance model. Then the daemon's
recording (relayd/record/, written by the daemon itself) goes through
`relayd calibrate path-loss --from`, which must find the model's L0 and n again.

Virtual time (`relayd.runtime.vtime`): a minute of driving costs no wall time.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import subprocess
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from relayd.calibrate.sources import NEAR_SPEED_SHARE, LiveOptions, sample_live
from relayd.config.load import parse_settings
from relayd.daemon import Daemon
from relayd.fakes.rig import FakeRig
from relayd.runtime.vtime import LoopClock
from tests.support import running as run_daemon
from tests.support import until

pytestmark = [pytest.mark.asyncio, pytest.mark.virtual_time]

#: The node behind: RSSI^b = L0 - 10 n log10(d), d = 1 m + the distance driven.
L0_DBM, N = -30.0, 2.5
SPEED_MM_S = 150.0
NEAR_M = 2.5


def rear_dbm(x_mm: float) -> float:
    return round(L0_DBM - 10.0 * N * math.log10(1.0 + x_mm / 1000.0))


@contextlib.asynccontextmanager
async def relay(tmp: Path) -> AsyncIterator[tuple[FakeRig, Daemon, str]]:
    clock = LoopClock()
    async with FakeRig(tmp / "rig", clock=clock, links="memory") as rig:
        doc = rig.config_doc(
            api_port=0,
            control={"mode": "hold"},
            record={"enabled": True, "path": str(tmp / "drive.mcap")},
        )
        daemon = Daemon(parse_settings(doc), env=rig.env, clock=clock)

        async def world() -> None:
            while True:  # the rear radio hears the node behind at the robot's distance
                rig.set_rear_signal(rear_dbm(rig.robot.x_mm))
                await asyncio.sleep(0.1)

        w = asyncio.create_task(world())
        try:
            async with run_daemon(daemon) as task:

                def serving() -> bool:
                    if task.done():
                        task.result()  # a start-up failure, with its own error
                    return daemon.api_port is not None

                await until(serving, "the API to bind", poll_s=0.05)
                await until(
                    lambda: daemon.state.reason == "hold", "the daemon in hold", poll_s=0.05
                )
                yield rig, daemon, f"http://127.0.0.1:{daemon.api_port}"
        finally:
            w.cancel()


async def drive(rig: FakeRig, url: str, **kw: float) -> tuple[list[tuple[float, float]], str]:
    """One --drive run; the robot's (distance from the node m, speed mm/s) seen meanwhile."""
    seen: list[tuple[float, float]] = []

    async def watch() -> None:
        while True:
            seen.append((1.0 + rig.robot.x_mm / 1000.0, rig.robot.vel_mm_s))
            await asyncio.sleep(0.1)

    w = asyncio.create_task(watch())
    try:
        opts = LiveOptions(
            url=url,
            drive=True,
            speed_mm_s=SPEED_MM_S,
            near_m=NEAR_M,
            token=rig.api_token,
            start_distance_m=1.0 + rig.robot.x_mm / 1000.0,
            **kw,
        )  # type: ignore[arg-type]
        _readings, why = await sample_live(opts)
    finally:
        w.cancel()
    return seen, why


async def settled(rig: FakeRig, daemon: Daemon) -> None:
    """Wheels at zero and the daemon in hold mode (where every --drive run must leave it)."""
    await until(
        lambda: rig.robot.vel_mm_s == 0.0 and str(daemon.state.mode) == "hold",
        "wheels at zero in hold mode",
        10.0,
        poll_s=0.1,
    )


async def test_drive_a_real_relayd_then_calibrate_from_its_own_recording(tmp_path: Path) -> None:
    async with relay(tmp_path) as (rig, daemon, url):
        # 1. To the distance: slow through the first metres, then the set speed, never faster.
        seen, why = await drive(rig, url, distance_m=3.0, seconds=120.0)
        assert why == "distance"
        await settled(rig, daemon)
        assert rig.robot.x_mm >= 2900.0
        assert max(v for _d, v in seen) <= SPEED_MM_S + 1.0
        near = [v for d, v in seen if 1.3 < d < NEAR_M - 0.2]
        far = [v for d, v in seen if d > NEAR_M + 0.5]
        assert near and max(near) <= SPEED_MM_S * NEAR_SPEED_SHARE + 1.0
        assert far and max(far) >= SPEED_MM_S - 10.0

        # 2. A wall 0.6 m ahead: the daemon's obstacle guard stops the robot and ends the run.
        wall_mm = rig.robot.x_mm + 600.0
        rig.robot.sonar_fn = lambda x, _y, _th: [max(0.0, wall_mm - x)] * 16
        _seen, why = await drive(rig, url, distance_m=5.0, seconds=60.0)
        assert why == "the daemon stopped the robot: obstacle"
        await settled(rig, daemon)
        assert rig.robot.x_mm < wall_mm - 150.0
        rig.robot.sonar_fn = None
        await until(
            lambda: not any(r is not None and r < 4000 for r in daemon.state.sonar_mm),
            "the whole sonar ring fired again: the way is clear",
            10.0,
            poll_s=0.1,
        )

        # 3. The base goes silent mid-drive: no SIP, wheels at zero, the run ends in hold.
        async def go_silent() -> None:
            await asyncio.sleep(3.0)  # virtual: the fault comes 3 s into the drive
            rig.robot.silent = True

        silent = asyncio.create_task(go_silent())
        _seen, why = await drive(rig, url, distance_m=5.0, seconds=60.0)
        await silent
        assert why == "the daemon stopped the robot: no_sip"
        await until(
            lambda: str(daemon.state.mode) == "hold",
            "hold mode after the silent base",
            10.0,
            poll_s=0.1,
        )
        assert daemon.state.wheels_left_mm_s == 0.0 and daemon.state.wheels_right_mm_s == 0.0
    # The daemon has stopped: its recording is complete.

    recording = tmp_path / "drive.mcap"
    assert recording.stat().st_size > 0
    out = tmp_path / "out"
    # The command as a shell runs it (in its own process: it owns its loop and signals).
    proc = await asyncio.to_thread(
        subprocess.run,
        [
            sys.executable,
            "-m",
            "relayd",
            "calibrate",
            "path-loss",
            "--from",
            str(recording),
            "--start-distance-m",
            "1",
            "--target-mbps",
            "10",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert "path loss of the rear link" in proc.stdout
    fit = json.loads((out / "path-loss.json").read_text())["fit"]
    assert fit["n"] == pytest.approx(N, abs=0.2)
    assert fit["l0_dbm"] == pytest.approx(L0_DBM, abs=1.5)
    assert fit["points"] >= 30
    assert (out / "path-loss.toml").exists()
