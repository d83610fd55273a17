"""A device another process holds is an error at start, naming the device and the holder.

A second `relayd run` on the same devices used to log "Could not exclusively lock port",
retry, and take the robot over (driving it in follow) about 5 s after the first was
stopped. Now it exits 2 at once, naming the key, the port and the holder's PID, and
never opens a device.
"""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
from pathlib import Path

import pytest

from drivers.transport.link import held_ports, holder_text, lock_holder
from relayd.fakes.rig import FakeRig
from tests.support import until
from tests.tools.test_run_cli import PANTILT, SCAN, OpenWatch, Relayd


def test_an_unlocked_file_has_no_holder(tmp_path: Path) -> None:
    port = tmp_path / "tty"
    port.write_bytes(b"")
    assert lock_holder(str(port)) is None
    assert held_ports([("robot.port", str(port))]) == []


def test_a_flock_held_by_another_process_names_its_pid(tmp_path: Path) -> None:
    port = tmp_path / "tty"
    port.write_bytes(b"")
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import fcntl, sys; f = open(sys.argv[1]); fcntl.flock(f, fcntl.LOCK_EX);"
            " print('locked', flush=True); sys.stdin.read()",
            str(port),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "locked"
        link = tmp_path / "relay1-base"  # a udev-style symlink to the port
        link.symlink_to(port)
        assert lock_holder(str(port)) == holder.pid
        assert lock_holder(str(link)) == holder.pid
        [line] = held_ports([("robot.port", str(link))])
        assert line.startswith(f"robot.port: {link} is in use by PID {holder.pid} (")
        assert "fcntl" in line  # the holder's command line, as /proc has it
    finally:
        assert holder.stdin is not None
        holder.stdin.close()
        holder.wait(10)
    assert lock_holder(str(port)) is None  # released with the process


def test_own_lock_and_unreadable_table(tmp_path: Path) -> None:
    port = tmp_path / "tty"
    port.write_bytes(b"")
    with open(port) as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        assert lock_holder(str(port)) == os.getpid()
        # No /proc/locks (not Linux): no answer, and the open itself refuses the port.
        assert lock_holder(str(port), proc_locks=str(tmp_path / "missing")) is None
    assert lock_holder("socket://127.0.0.1:8101") is None
    assert lock_holder(str(tmp_path / "unplugged")) is None
    assert holder_text(0) == "a process whose PID is not visible here"


@pytest.mark.slow
async def test_a_second_relayd_on_the_same_devices_exits_2_naming_the_holder(
    tmp_path: Path,
) -> None:
    async with FakeRig(tmp_path) as rig:
        config = rig.write_config(
            secrets_in_files=True, scan=SCAN, pantilt=PANTILT, log={"format": "json"}
        )
        first = await Relayd.start("run", "-c", str(config))
        try:
            await until(
                lambda: rig.robot.target_vel_mm_s > 0 and rig.robot.motors_enabled,
                "the first relayd driving:\n" + first.output(),
            )
            assert rig.robot_port is not None and rig.servo_port is not None
            # The second must never open the ports (an open would be one more lock holder).
            watch = OpenWatch(rig.robot_port, rig.servo_port)
            try:
                second = await Relayd.start("run", "-c", str(config))
                try:
                    code = await second.wait(30)
                finally:
                    await second.kill()
                assert not watch.opened(), "the second relayd opened a port"
            finally:
                watch.close()
            assert code == 2, second.output()
            err = "\n".join(second.stderr)
            assert f"robot.port: {rig.robot_port} is in use by PID {first.proc.pid}" in err, err
            assert f"pantilt.port: {rig.servo_port} is in use by PID {first.proc.pid}" in err, err
            # The first relayd drives on, undisturbed: no stop, no second handshake.
            assert first.proc.returncode is None
            assert rig.robot.motors_enabled and rig.robot.opened
        finally:
            await first.kill()
