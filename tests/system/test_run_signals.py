"""Every way `relayd run` can end while driving ends in the safe stop at the robot.

Real `relayd run` subprocesses against a FakeRig served by this process (the machinery
of tests/tools/test_run_cli.py). After each catchable fatal signal, and after an exception
that ends the daemon (in a supervised task beyond its keeper, or in the main
coroutine), the fake P3-AT must see VEL 0, ENABLE 0 and CLOSE, end disabled and
closed, and the process must exit with the code the shell expects: 0 for SIGTERM
(systemd's stop), 128 + the signal's number for the others (130 for Ctrl-C).
"""

from __future__ import annotations

import asyncio
import signal
import sys
import time
from pathlib import Path

import pytest

from drivers.arcos.codec import Command
from relayd.fakes.rig import FakeRig
from tests.support import until
from tests.tools.test_run_cli import PANTILT, SCAN, Relayd, clean_env, find_stop_sequence

pytestmark = pytest.mark.slow

STOP_LIMIT_S = 1.5


async def _driving(rig: FakeRig, relayd: Relayd) -> None:
    await until(
        lambda: rig.robot.target_vel_mm_s > 0 and rig.robot.motors_enabled,
        "the fake robot driven forward:\n" + relayd.output(),
    )


async def _assert_safe_stop(rig: FakeRig, relayd: Relayd, mark: int, t0: float) -> int:
    """The stop sequence reached the robot quickly, nothing moved after it; the exit code."""
    try:
        seq = await until(
            lambda: find_stop_sequence(rig.robot.commands[mark:]),
            "VEL 0, ENABLE 0, CLOSE",
            10.0,
            poll_s=0.002,
        )
    except AssertionError:
        pytest.fail(f"no safe stop: {rig.robot.commands[mark:]}\n" + relayd.output())
    stop_s = time.monotonic() - t0
    code = await relayd.wait(10)
    after = rig.robot.commands[mark:]
    moving = [
        (c, a)
        for c, a in after[seq[0] :]
        if c in (Command.VEL, Command.RVEL, Command.VEL2) and a != 0
    ]
    assert moving == [], after
    assert not rig.robot.opened and not rig.robot.motors_enabled
    assert stop_s <= STOP_LIMIT_S, f"CLOSE {stop_s:.3f} s after the cause"
    return code


def _config(rig: FakeRig) -> Path:
    return rig.write_config(
        secrets_in_files=True, scan=SCAN, pantilt=PANTILT, log={"format": "json"}
    )


@pytest.mark.parametrize(
    ("sig", "code"),
    [
        (signal.SIGHUP, 129),  # the SSH session running it in the foreground dropped
        (signal.SIGINT, 130),  # Ctrl-C: the shell's 130, as the README says
        (signal.SIGQUIT, 131),
        (signal.SIGUSR1, 138),
        (signal.SIGUSR2, 140),
    ],
    ids=lambda v: v.name if isinstance(v, signal.Signals) else str(v),
)
async def test_a_fatal_signal_while_driving_ends_in_the_safe_stop(
    tmp_path: Path, sig: signal.Signals, code: int
) -> None:
    async with FakeRig(tmp_path) as rig:
        relayd = await Relayd.start("run", "-c", str(_config(rig)))
        try:
            await _driving(rig, relayd)
            mark, t0 = len(rig.robot.commands), time.monotonic()
            relayd.proc.send_signal(sig)
            got = await _assert_safe_stop(rig, relayd, mark, t0)
        finally:
            await relayd.kill()
        assert got == code, relayd.output()
        names = [e.get("event") for e in relayd.events()]
        assert "robot_safe_stop" in names and names[-1] == "stopped", names[-10:]
        assert not any("Traceback" in line for line in relayd.stderr), relayd.output()


async def test_a_second_signal_does_not_cut_the_safe_stop_short(tmp_path: Path) -> None:
    async with FakeRig(tmp_path) as rig:
        relayd = await Relayd.start("run", "-c", str(_config(rig)))
        try:
            await _driving(rig, relayd)
            mark, t0 = len(rig.robot.commands), time.monotonic()
            relayd.proc.send_signal(signal.SIGHUP)
            # Pending signals are delivered in number order, not in the order sent: the
            # others go once relayd has taken SIGHUP, while its safe stop runs.
            await until(
                lambda: any(e.get("event") == "signal" for e in relayd.events()),
                "the SIGHUP taken",
                poll_s=0.001,
            )
            relayd.proc.send_signal(signal.SIGINT)  # the user pressing Ctrl-C as well
            relayd.proc.send_signal(signal.SIGTERM)
            got = await _assert_safe_stop(rig, relayd, mark, t0)
        finally:
            await relayd.kill()
        assert got == 129, relayd.output()  # the first signal decides


async def test_sigpipe_is_ignored_and_the_robot_keeps_its_control_loop(tmp_path: Path) -> None:
    # Python ignores SIGPIPE: a closed log pipe is an EPIPE on a write, not a dead
    # daemon, so neither kills relayd nor stops a driving robot. SIGTERM still stops it.
    async with FakeRig(tmp_path) as rig:
        relayd = await Relayd.start("run", "-c", str(_config(rig)))
        try:
            await _driving(rig, relayd)
            relayd.proc.send_signal(signal.SIGPIPE)
            before = len(rig.robot.commands)
            await until(lambda: len(rig.robot.commands) > before + 5, "commands still flowing")
            assert relayd.proc.returncode is None
            assert rig.robot.motors_enabled
            mark, t0 = len(rig.robot.commands), time.monotonic()
            relayd.proc.send_signal(signal.SIGTERM)
            got = await _assert_safe_stop(rig, relayd, mark, t0)
        finally:
            await relayd.kill()
        assert got == 0, relayd.output()


#: `relayd run` with one fault injected once the robot drives. argv: KIND CONFIG.
INJECT = """
import asyncio, sys
from relayd.runtime.control import ControlShell
from relayd.daemon import Daemon

kind, config = sys.argv[1], sys.argv[2]

class Injected(BaseException):
    pass

def driving(daemon_or_control):
    robot = daemon_or_control._robot if hasattr(daemon_or_control, "_robot") else daemon_or_control.robot
    return robot is not None and robot.wheels_wish != (0.0, 0.0)

if kind == "main":
    start = Daemon.start
    async def failing_start(self):
        await start(self)
        while not driving(self):
            await asyncio.sleep(0.01)
        await asyncio.sleep(1.0)  # driving for a while: the test must see it drive first
        raise RuntimeError("injected into the main coroutine")
    Daemon.start = failing_start
else:
    check = ControlShell.check_devices
    ticks = []
    def failing_check(self):
        check(self)
        if driving(self):
            ticks.append(1)
        # A second of driving first (ten 0.1 s ticks): the test must see the robot drive
        # before the fault, or it waits for a drive that a stop already cancelled.
        if len(ticks) >= 10:
            raise {"base": Injected("injected"), "exit": SystemExit(7),
                   "keyboard": KeyboardInterrupt()}[kind]
    ControlShell.check_devices = failing_check

from relayd.cli import main
sys.exit(main(["run", "-c", config]))
"""


@pytest.mark.parametrize(
    ("kind", "code"),
    [
        ("base", 1),  # a BaseException the supervisor's keeper does not catch: task dead
        ("exit", 7),  # sys.exit() inside a task: SystemExit leaves the event loop
        ("keyboard", 130),  # KeyboardInterrupt raised inside a task
        ("main", 1),  # an exception in the main coroutine
    ],
)
async def test_an_exception_that_ends_the_daemon_ends_in_the_safe_stop(
    tmp_path: Path, kind: str, code: int
) -> None:
    async with FakeRig(tmp_path) as rig:
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-c",
            INJECT,
            kind,
            str(_config(rig)),
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
            env=clean_env(),
        )
        relayd = Relayd(proc)
        try:
            await _driving(rig, relayd)
            # The fault fires about a second into the drive (INJECT): the stop is timed from then.
            got = await _assert_safe_stop(rig, relayd, 0, time.monotonic() + 1.0)
        finally:
            await relayd.kill()
        assert got == code, relayd.output()
        names = [e.get("event") for e in relayd.events()]
        assert "robot_safe_stop" in names, names[-10:]


@pytest.mark.parametrize("delay_s", [0.05, 0.1, 0.15, 0.2, 0.3, 0.5])
async def test_ctrl_c_while_starting_exits_130_without_a_traceback(
    tmp_path: Path, delay_s: float
) -> None:
    # Within the first 0.2 s the command line is still importing and loading the config:
    # Ctrl-C there used to print a KeyboardInterrupt traceback. The delay counts from the
    # moment Python has loaded relayd's package: before it the interpreter is starting
    # itself (site, the venv's .pth files), which no code of relayd's runs in; on a loaded
    # machine that alone took more than 0.05 s, and Python's own traceback came out.
    async with FakeRig(tmp_path) as rig:
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-X",
            "importtime",  # one stderr line per module loaded: says when relayd's began
            "-m",
            "relayd",
            "run",
            "-c",
            str(_config(rig)),
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
            env=clean_env(),
        )
        relayd = Relayd(proc)
        try:
            await until(
                lambda: any(line.endswith("| relayd") for line in relayd.stderr),
                "Python to load relayd's package",
                timeout_s=30.0,
            )
            await asyncio.sleep(delay_s)
            relayd.proc.send_signal(signal.SIGINT)
            code = await relayd.wait(10)
        finally:
            await relayd.kill()
        out = relayd.output()
        assert "Traceback" not in out and "KeyboardInterrupt" not in out, out
        # Before Python's own handler is in place the signal's default ends the process.
        assert code in (130, -signal.SIGINT), out
        if rig.robot.commands:  # it got as far as the robot: the robot was stopped
            assert find_stop_sequence(rig.robot.commands) is not None, rig.robot.commands
