"""SIGTERM stops `relayd run` and every `relayd fake ...` quickly and cleanly.

Measured from the signal to the process's exit, with real subprocesses. The target is
0.5 s; the limit below leaves room for a loaded shared machine but still fails at the
~2 s a shutdown timeout or a joined executor thread would cost. A fake must also leave
no pty symlink behind (a stale link would hand a later `relayd run` some other pty).
"""

from __future__ import annotations

import asyncio
import os
import signal
import sys
import time
from pathlib import Path

import pytest

from tests.support import until

pytestmark = pytest.mark.slow

#: 1.0 s failed once at 1.2 s with the machine's load average at 19 on its 2 cores; a
#: shutdown timeout or a joined thread costs 2 s or more on top of the exit itself.
EXIT_LIMIT_S = 1.6


async def _start(*args: str) -> tuple[asyncio.subprocess.Process, list[str]]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RELAYD_")}
    env["PYTHONUNBUFFERED"] = "1"
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "relayd",
        *args,
        env=env,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT,
    )
    lines: list[str] = []

    async def drain() -> None:
        assert proc.stdout is not None
        async for raw in proc.stdout:
            lines.append(raw.decode(errors="replace").rstrip("\n"))

    asyncio.get_running_loop().create_task(drain())
    return proc, lines


async def _sigterm_exit_s(proc: asyncio.subprocess.Process, lines: list[str]) -> float:
    t0 = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    try:
        async with asyncio.timeout(15):
            code = await proc.wait()
    finally:
        if proc.returncode is None:
            proc.kill()
    exit_s = time.monotonic() - t0
    print(f"SIGTERM -> exit {exit_s * 1000:.0f} ms")
    assert code == 0, "\n".join(lines)
    return exit_s


@pytest.mark.parametrize(
    "args",
    [
        ("robot", "--pty", "--link", "{dir}/base"),
        ("robot", "--tcp", "0"),
        ("pantilt", "--protocol", "maestro", "--link", "{dir}/servo"),
        ("pantilt", "--protocol", "ssc32", "--link", "{dir}/servo"),
        ("ap",),
    ],
    ids=lambda a: " ".join(a[:2]),
)
async def test_fake_exits_quickly_and_removes_its_link(
    tmp_path: Path, args: tuple[str, ...]
) -> None:
    argv = [a.format(dir=tmp_path) for a in args]
    proc, lines = await _start("fake", *argv)
    await until(lambda: lines, "the fake's address on stdout")
    exit_s = await _sigterm_exit_s(proc, lines)
    assert list(tmp_path.iterdir()) == [], "a pty symlink was left behind"
    assert exit_s <= EXIT_LIMIT_S


async def test_fake_rig_exits_quickly_and_removes_its_links(tmp_path: Path) -> None:
    work = tmp_path / "rig"
    proc, lines = await _start("fake", "rig", "--dir", str(work), "--api-port", "0")
    await until(lambda: lines, "the rig's config path on stdout")
    assert (work / "relay1-base").is_symlink() and (work / "relay1-servo").is_symlink()
    exit_s = await _sigterm_exit_s(proc, lines)
    leftover = sorted(p.name for p in work.iterdir())
    assert not any(p.is_symlink() for p in work.iterdir()), leftover
    # A --dir the user named keeps the written config for the next run.
    assert "relay1.toml" in leftover
    assert exit_s <= EXIT_LIMIT_S


async def test_fake_rig_in_a_temp_dir_leaves_nothing(tmp_path: Path) -> None:
    proc, lines = await _start("fake", "rig", "--api-port", "0")
    await until(lambda: lines, "the rig's config path on stdout")
    work = Path(lines[0]).parent
    assert work.is_dir()
    await _sigterm_exit_s(proc, lines)
    assert not work.exists()


async def test_run_exits_quickly_after_sigterm(tmp_path: Path) -> None:
    rig, rig_lines = await _start("fake", "rig", "--dir", str(tmp_path), "--api-port", "0")
    try:
        await until(lambda: rig_lines, "the rig's config path")
        proc, lines = await _start("run", "-c", rig_lines[0], "--log-format", "console")
        try:
            await until(
                lambda: any("robot_connected" in ln for ln in lines),
                "relayd connected to the robot",
            )
            await until(lambda: any("api_listening" in ln for ln in lines), "the API listening")
            exit_s = await _sigterm_exit_s(proc, lines)
        finally:
            if proc.returncode is None:
                proc.kill()
        assert any("stopped" in ln for ln in lines), lines[-5:]
        assert exit_s <= EXIT_LIMIT_S
    finally:
        rig.send_signal(signal.SIGTERM)
        await rig.wait()


async def test_sim_stops_in_order_after_sigterm(tmp_path: Path) -> None:
    """`relayd sim` cancels the run (the relays' daemons stopped in its `finally`), says so
    and exits 0, instead of dying without cleaning up (the MobileSim engine's processes:
    tests/sim/test_mobilesim.py)."""
    out = tmp_path / "out"
    proc, lines = await _start(
        "sim", "--relays", "1", "--speed", "1", "--no-plots", "--out", str(out)
    )
    try:
        await until(lambda: any("API and live page" in ln for ln in lines), "the relay up")
        exit_s = await _sigterm_exit_s(proc, lines)
    finally:
        if proc.returncode is None:
            proc.kill()
    assert "relayd sim: stopped before the end of the run" in lines, lines
    assert not (out / "summary.json").exists()  # the run did not end: no summary
    assert exit_s <= EXIT_LIMIT_S
