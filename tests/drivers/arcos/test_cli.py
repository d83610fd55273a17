"""`relayd probe robot` and `relayd fake robot` end to end (fake served from another thread/process)."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from drivers.arcos import ArcosRobot
from drivers.arcos.codec import CLOSE, Command
from drivers.arcos.fake import FakeRobot
from relayd.cli import main
from tests.support import piped_into_head, until_sync

ROOT = Path(__file__).resolve().parents[3]


class ThreadedFake:
    """A FakeRobot on its own event loop, so the CLI can run asyncio.run() in this thread."""

    def __init__(self, **kw: object) -> None:
        self.loop = asyncio.new_event_loop()
        self.ready = threading.Event()
        self.path = ""
        self.fake: FakeRobot | None = None
        self.thread = threading.Thread(target=self._run, args=(kw,), daemon=True)
        self.thread.start()
        assert self.ready.wait(5)

    def _run(self, kw: dict[str, object]) -> None:
        asyncio.set_event_loop(self.loop)

        async def setup() -> None:
            self.fake = FakeRobot(**kw)  # type: ignore[arg-type]
            self.path = self.fake.serve_pty()
            self.ready.set()

        self.loop.run_until_complete(setup())
        self.loop.run_forever()

    def close(self) -> None:
        assert self.fake is not None
        asyncio.run_coroutine_threadsafe(self.fake.stop(), self.loop).result(5)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
        self.loop.close()


@pytest.fixture
def fake_robot() -> Iterator[ThreadedFake]:
    tf = ThreadedFake(
        name="probe-me", subclass="p3at-sh", sonar_fn=lambda x, y, th: [700 + i for i in range(16)]
    )
    yield tf
    tf.close()


def test_probe_json_lines(fake_robot: ThreadedFake, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["probe", "robot", "--port", fake_robot.path, "--seconds", "0.7", "--json"])
    out = capsys.readouterr().out.splitlines()
    assert code == 0
    assert json.loads(out[0]) == {"name": "probe-me", "class": "Pioneer", "subclass": "p3at-sh"}
    sips = [json.loads(line) for line in out[1:]]
    assert len(sips) >= 4
    keys = {
        "x_mm",
        "y_mm",
        "theta_deg",
        "left_mm_s",
        "right_mm_s",
        "battery_v",
        "motors_enabled",
        "stall_left",
        "stall_right",
        "sonar_mm",
    }
    for rec in sips:
        assert keys <= rec.keys()
        assert len(rec["sonar_mm"]) == 16
        assert rec["motors_enabled"] is False and rec["battery_v"] == 13.0
        # 8 sonars per SIP: a sonar not yet read is null, never a made-up or shifted range.
        # (Whether the first line shows any null depends on whether a SIP came in during
        # the handshake, before the probe listened: on a loaded machine one often does.)
        assert all(r is None or r == 700 + i for i, r in enumerate(rec["sonar_mm"])), rec
    assert sips[-1]["sonar_mm"] == [700 + i for i in range(16)]
    assert fake_robot.fake is not None
    assert (Command.ENABLE, 1) not in fake_robot.fake.commands  # read-only


def test_probe_text_mode(fake_robot: ThreadedFake, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["probe", "robot", "--port", fake_robot.path, "--seconds", "0.3"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("robot 'probe-me': class Pioneer, subclass p3at-sh")
    assert "motors=off" in out[-1] and "bat=13.0V" in out[-1]


def test_probe_piped_into_head_stops_quietly(fake_robot: ThreadedFake) -> None:
    """`relayd probe robot | head -1`: stop at the next SIP, exit 0, log nothing.

    It used to run on to --seconds, logging robot_listener_error with a BrokenPipeError
    traceback on every SIP (10 a second).
    """
    code, got, err, _ = piped_into_head(
        ["probe", "robot", "--port", fake_robot.path, "--seconds", "60"], lines=1, timeout_s=30
    )
    assert got[0].startswith("robot 'probe-me': class Pioneer")
    assert code == 0, err
    for noise in ("robot_listener_error", "BrokenPipe", "Traceback", "Exception ignored"):
        assert noise not in err, err[:2000]
    # It left through the usual safe stop.
    assert fake_robot.fake is not None
    fake = fake_robot.fake
    until_sync(lambda: fake.commands[-1][0] == CLOSE, "CLOSE as the last command", 10.0)
    assert (Command.ENABLE, 1) not in fake_robot.fake.commands


def test_probe_missing_port(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = str(tmp_path / "ttyUSB9")
    assert main(["probe", "robot", "--port", missing, "--json"]) == 1
    err = capsys.readouterr().err
    assert missing in err and "cannot open" in err


def test_probe_robot_that_never_answers(capsys: pytest.CaptureFixture[str]) -> None:
    tf = ThreadedFake()
    assert tf.fake is not None
    tf.fake.silent = True
    try:
        assert main(["probe", "robot", "--port", tf.path, "--retries", "1"]) == 1
    finally:
        tf.close()
    assert "never answered SYNC0" in capsys.readouterr().err


def test_fake_robot_command_serves_tcp() -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "relayd",
            "fake",
            "robot",
            "--tcp",
            "0",
            "--name",
            "cli-bot",
            "--subclass",
            "p3at-sh",
        ],
        stdout=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )
    try:
        assert proc.stdout is not None
        url = proc.stdout.readline().strip()
        assert url.startswith("socket://127.0.0.1:")

        async def talk() -> tuple[str, str]:
            robot = ArcosRobot(url)
            ident = await robot.connect()
            await robot.shutdown()
            return ident.name, ident.subclass

        assert asyncio.run(talk()) == ("cli-bot", "p3at-sh")
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(10) in (0, 130)


def test_fake_robot_link_needs_pty(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fake", "robot", "--tcp", "0", "--link", "/tmp/x"]) == 2
    assert "--link needs --pty" in capsys.readouterr().err
