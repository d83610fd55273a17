"""`relayd run -c FILE` as a real subprocess against a FakeRig served by the test process.

The daemon reaches the fake devices only through the config the rig writes (pty
paths, loopback URLs, secrets in 0600 files), exactly as on a robot. On SIGTERM the
fake robot must see the wheels zeroed, ENABLE 0 and CLOSE, in that order, quickly,
and the process must exit 0; a bad config must exit 2 naming the key before any
device is touched.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import json
import os
import re
import signal
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import pytest

from drivers.arcos.codec import CLOSE, Command
from relayd.config.tomlwriter import dump_toml
from relayd.fakes.rig import AP_PASSWORD_ENV, FakeRig
from tests.support import until

pytestmark = pytest.mark.slow

SCAN = {"samples": 9, "width_deg": 120, "settle_s": 0.02}
PANTILT = {"speed_deg_s": 1000}
#: relayd allows itself 0.5 s from the signal to CLOSE; the machine is shared, so fail only when clearly slow.
CLOSE_LIMIT_S = 1.5
_PRIORITY = re.compile(r"^<\d>")


class Relayd:
    """A `relayd` subprocess whose output is drained into lists as it arrives."""

    def __init__(self, proc: asyncio.subprocess.Process) -> None:
        self.proc = proc
        self.stdout: list[str] = []
        self.stderr: list[str] = []
        assert proc.stdout is not None and proc.stderr is not None
        self._readers = [
            asyncio.create_task(self._drain(proc.stdout, self.stdout)),
            asyncio.create_task(self._drain(proc.stderr, self.stderr)),
        ]

    @classmethod
    async def start(cls, *args: str, env: dict[str, str] | None = None) -> Relayd:
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "relayd",
            *args,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
            env=env if env is not None else clean_env(),
        )
        return cls(proc)

    @staticmethod
    async def _drain(stream: asyncio.StreamReader, into: list[str]) -> None:
        async for line in stream:
            into.append(line.decode(errors="replace").rstrip("\n"))

    def events(self) -> list[dict[str, object]]:
        """The JSON log events printed so far (systemd priority prefix stripped)."""
        out = []
        for line in self.stdout + self.stderr:
            text = _PRIORITY.sub("", line)
            with contextlib.suppress(ValueError):
                doc = json.loads(text)
                if isinstance(doc, dict):
                    out.append(doc)
        return out

    async def wait(self, timeout_s: float) -> int:
        async with asyncio.timeout(timeout_s):
            code = await self.proc.wait()
            await asyncio.gather(*self._readers)
        return code

    async def kill(self) -> None:
        if self.proc.returncode is None:
            self.proc.kill()
            await self.proc.wait()
        for task in self._readers:
            task.cancel()

    def output(self) -> str:
        return "\n".join(["--- stdout", *self.stdout, "--- stderr", *self.stderr])


def clean_env() -> dict[str, str]:
    """This environment without the rig's secrets: the config's secret files must suffice."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("RELAYD_")}
    env["PYTHONUNBUFFERED"] = "1"
    return env


def find_stop_sequence(commands: Sequence[tuple[int, object]]) -> tuple[int, int, int] | None:
    """Indices of the safe stop: VEL 0 (with RVEL 0 or VEL2 0), then ENABLE 0, then CLOSE."""
    close = next((i for i, (c, a) in enumerate(commands) if c == CLOSE and a == 1), None)
    if close is None:
        return None
    enable0 = max(
        (i for i, (c, a) in enumerate(commands[:close]) if c == Command.ENABLE and a == 0),
        default=None,
    )
    if enable0 is None:
        return None
    vel0 = max(
        (
            i
            for i, (c, a) in enumerate(commands[:enable0])
            if c in (Command.VEL, Command.VEL2) and a == 0
        ),
        default=None,
    )
    if vel0 is None:
        return None
    return vel0, enable0, close


async def test_run_drives_and_sigterm_zeroes_wheels_disables_and_closes(tmp_path: Path) -> None:
    async with FakeRig(tmp_path) as rig:
        config = rig.write_config(
            secrets_in_files=True, scan=SCAN, pantilt=PANTILT, log={"format": "json"}
        )
        relayd = await Relayd.start("run", "-c", str(config))
        try:
            await until(
                lambda: rig.robot.target_vel_mm_s > 0 and rig.robot.motors_enabled,
                "the fake robot driven forward",
            )
            await until(
                lambda: any(
                    e.get("event") == "drive_state" and e.get("state") == "driving"
                    for e in relayd.events()
                ),
                "a drive_state=driving log line",
            )
            mark = len(rig.robot.commands)
            t_signal = time.monotonic()
            relayd.proc.send_signal(signal.SIGTERM)
            t_close: float | None = None
            try:
                seq = await until(
                    lambda: find_stop_sequence(rig.robot.commands[mark:]),
                    "VEL 0, ENABLE 0, CLOSE after SIGTERM",
                    10.0,
                    poll_s=0.002,
                )
                t_close = time.monotonic()
            except AssertionError:
                pytest.fail(
                    f"no VEL 0, ENABLE 0, CLOSE after SIGTERM: {rig.robot.commands[mark:]}\n"
                    + relayd.output()
                )
            code = await relayd.wait(10)
            t_exit = time.monotonic()
        finally:
            await relayd.kill()
        close_s, exit_s = t_close - t_signal, t_exit - t_signal
        print(
            f"SIGTERM -> CLOSE at the fake robot {close_s * 1000:.0f} ms, -> process exit {exit_s * 1000:.0f} ms"
        )
        assert code == 0, relayd.output()
        after = rig.robot.commands[mark:]
        vel0, _enable0, close = seq
        # Nothing moves the wheels once the stop has started, and CLOSE is the last word.
        moving = [
            (c, a)
            for c, a in after[vel0:]
            if c in (Command.VEL, Command.RVEL, Command.VEL2) and a != 0
        ]
        assert moving == [], after
        assert all(
            c in (Command.VEL, Command.RVEL, Command.ENABLE, Command.SYNC0) or i == close
            for i, (c, _a) in enumerate(after)
            if i > vel0
        ), after
        assert not rig.robot.opened and not rig.robot.motors_enabled
        assert close_s <= CLOSE_LIMIT_S, f"CLOSE {close_s:.3f} s after SIGTERM"
        assert exit_s <= 10.0
        # A clean shutdown is not reported as a failure.
        events = relayd.events()
        names = [e.get("event") for e in events]
        assert "robot_safe_stop" in names and names[-1] == "stopped", names[-10:]
        shutdown = names.index("shutting_down")
        complaints = [
            e for e in events[shutdown:] if e.get("level") in ("warning", "error", "critical")
        ]
        assert complaints == [], complaints


class OpenWatch:
    """Notes every open(2) of the given device files from now on (inotify IN_OPEN).

    "Not touched" is proven by "never opened" at once, with no wait: a byte written to a
    pty reaches the other end a moment later (the kernel pushes it from a work queue), so
    an empty command list right after the process exits proves nothing by itself.
    """

    IN_OPEN = 0x20
    IN_NONBLOCK = os.O_NONBLOCK

    def __init__(self, *paths: str) -> None:
        self._libc = ctypes.CDLL(None, use_errno=True)
        self._fd = self._libc.inotify_init1(self.IN_NONBLOCK)
        if self._fd < 0:
            raise OSError(ctypes.get_errno(), "inotify_init1")
        for path in paths:
            if (
                self._libc.inotify_add_watch(
                    self._fd, os.path.realpath(path).encode(), self.IN_OPEN
                )
                < 0
            ):
                raise OSError(ctypes.get_errno(), f"inotify_add_watch {path}")

    def opened(self) -> bool:
        try:
            return bool(os.read(self._fd, 4096))
        except BlockingIOError:
            return False

    def close(self) -> None:
        os.close(self._fd)


async def refused(rig: FakeRig, config: Path, env: dict[str, str] | None = None) -> str:
    """Run `relayd run -c config`; assert it exits 2 without touching a device; its output."""
    assert rig.robot_port is not None and rig.servo_port is not None
    watch = OpenWatch(rig.robot_port, rig.servo_port)
    try:
        relayd = await Relayd.start("run", "-c", str(config), env=env)
        try:
            code = await relayd.wait(30)
        finally:
            await relayd.kill()
        assert code == 2, relayd.output()
        assert not watch.opened(), "a device port was opened"
    finally:
        watch.close()
    assert rig.robot.commands == [], "the robot was touched"
    assert not rig.maestro.received, "the servo controller was touched"
    return relayd.output()


async def test_run_with_a_bad_config_exits_2_naming_the_key_before_touching_devices(
    tmp_path: Path,
) -> None:
    async with FakeRig(tmp_path) as rig:
        doc = rig.config_doc(scan=SCAN, control={"kpp": 2.0, "threshold_b_dbm": 50.0})
        config = tmp_path / "bad.toml"
        config.write_text(dump_toml(doc), encoding="utf-8")
        err = await refused(rig, config, {**clean_env(), **rig.env})
        assert "control.kpp" in err and "control.threshold_b_dbm" in err, err


async def test_run_with_a_missing_secret_exits_2_naming_the_key_before_touching_devices(
    tmp_path: Path,
) -> None:
    async with FakeRig(tmp_path) as rig:
        config = rig.write_config(scan=SCAN)  # AP passwords come from the environment...
        env = clean_env()
        env.pop(AP_PASSWORD_ENV, None)  # ...which does not have them
        err = await refused(rig, config, env)
        assert "ap.rear.password_env" in err and AP_PASSWORD_ENV in err, err
        assert rig.ap_password not in err


async def test_run_with_an_unreadable_secret_file_names_that_key(tmp_path: Path) -> None:
    async with FakeRig(tmp_path) as rig:
        config = rig.write_config(secrets_in_files=True, scan=SCAN)
        missing = tmp_path / f"{rig.name}-ap-password"
        missing.unlink()
        err = await refused(rig, config)
        assert "ap.rear.password_file" in err and str(missing) in err, err
