"""Stopping MobileSim and its Xvfb, without MobileSim: a stand-in program in its place.

The stand-in takes MobileSim's arguments, listens on the robots' ports as MobileSim does
(or never does), may ignore SIGTERM and may start a process of its own, and writes its
pids where the test says. Xvfb is the real one where it is installed (else a DISPLAY
is set and none is started). Every check is by pid and start time (tests/sim/procs.py).
"""

from __future__ import annotations

import asyncio
import os
import signal
import sys
import time
from pathlib import Path

import pytest

from relayd.sim.msproc import MobileSim
from tests.sim.procs import Proc, children, running, started
from tests.support import ROOT, until

FAKE = """\
import os, signal, socket, sys
args = sys.argv[1:]
if os.environ.get("FAKE_MS_IGNORE_TERM"):
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
pids = [os.getpid()]
if os.environ.get("FAKE_MS_FORK"):
    child = os.fork()
    if child == 0:
        while True:
            signal.pause()
    pids.append(child)
# The pids first: start() returns once the ports listen, and the test reads them then.
with open(os.environ["FAKE_MS_PIDS"] + ".tmp", "w") as f:
    f.write(" ".join(map(str, pids)))
os.rename(os.environ["FAKE_MS_PIDS"] + ".tmp", os.environ["FAKE_MS_PIDS"])
socks = []
if not os.environ.get("FAKE_MS_NO_PORTS"):
    base = int(args[args.index("-p") + 1])
    for k in range(args.count("-r")):
        s = socket.socket()
        s.bind(("127.0.0.1", base + k))
        s.listen()
        socks.append(s)
while True:
    signal.pause()
"""

#: How long a stopped process may take to be gone (they take milliseconds).
GONE_S = 3.0


@pytest.fixture
def fake(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    prog = tmp_path / "MobileSim"
    prog.write_text(f"#!{sys.executable}\n{FAKE}", encoding="utf-8")
    prog.chmod(0o755)
    monkeypatch.setenv("FAKE_MS_PIDS", str(tmp_path / "pids"))
    monkeypatch.setenv("DISPLAY", os.environ.get("DISPLAY", ":0"))  # used only without Xvfb
    return prog


def _fake_pids(tmp_path: Path) -> list[Proc]:
    return [started(int(p)) for p in (tmp_path / "pids").read_text().split()]


async def _all_gone(procs: list[Proc]) -> None:
    await until(lambda: not any(running(p) for p in procs), f"{procs} gone", GONE_S)


async def test_stop_ends_mobilesim_xvfb_and_what_mobilesim_started(
    fake: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FAKE_MS_FORK", "1")
    ms = MobileSim(fake, None, ["leader", "relay1"])
    await ms.start()
    procs = [started(p) for p in ms.pids] + _fake_pids(tmp_path)[1:]
    assert len(procs) >= 2 and all(running(p) for p in procs)
    await ms.stop()
    assert ms.pids == []
    # MobileSim and Xvfb are reaped by the stop; the stand-in's own child got the signal too.
    await _all_gone(procs)
    await ms.stop()  # idempotent


async def test_stop_kills_a_mobilesim_that_ignores_sigterm(
    fake: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FAKE_MS_IGNORE_TERM", "1")
    monkeypatch.setenv("FAKE_MS_FORK", "1")  # its child ignores SIGTERM too
    ms = MobileSim(fake, None, ["relay1"], stop_timeout_s=0.2)
    await ms.start()
    procs = _fake_pids(tmp_path)
    t0 = time.monotonic()
    await ms.stop()
    assert time.monotonic() - t0 >= 0.2  # it waited for SIGTERM, in vain
    await _all_gone(procs)


async def test_a_cancelled_start_stops_what_it_started(
    fake: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FAKE_MS_NO_PORTS", "1")  # start() waits for ports that never open
    ms = MobileSim(fake, None, ["relay1"])
    task = asyncio.create_task(ms.start())
    await until(lambda: (tmp_path / "pids").exists(), "the stand-in running")
    procs = [started(p) for p in ms.pids]
    assert procs and all(running(p) for p in procs)
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert ms.pids == []
    await _all_gone(procs)


HOLDER = """\
import asyncio, sys
from pathlib import Path
from relayd.sim.msproc import MobileSim

async def main() -> None:
    ms = MobileSim(Path(sys.argv[1]), None, ["relay1"])
    await ms.start()
    print(flush=True)
    await asyncio.Event().wait()

asyncio.run(main())
"""


async def test_a_killed_parent_takes_mobilesim_and_xvfb_along(fake: Path) -> None:
    """SIGKILL runs no `finally`: the kernel's parent-death signal ends them."""
    if not sys.platform.startswith("linux"):
        pytest.skip("the parent-death signal is Linux's")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    holder = await asyncio.create_subprocess_exec(
        sys.executable, "-c", HOLDER, str(fake), env=env, stdout=asyncio.subprocess.PIPE
    )
    try:
        assert holder.stdout is not None
        async with asyncio.timeout(30):
            await holder.stdout.readline()  # MobileSim (the stand-in) is up
        procs = list(children(holder.pid).values())
        names = set(children(holder.pid))
        assert "MobileSim" in names, names
        holder.send_signal(signal.SIGKILL)
        assert await holder.wait() == -signal.SIGKILL
        await _all_gone(procs)
    finally:
        if holder.returncode is None:
            holder.kill()
            await holder.wait()
