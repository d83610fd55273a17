"""Starting and stopping one MobileSim process that holds every robot of a run.

MobileSim (the P3-AT maker's ARCOS simulator) is not shipped with relayd: its program
comes from `--mobilesim PATH` or the environment variable RELAYD_MOBILESIM. It finds
its robot models (PioneerRobotModels.world.inc) through its own variable MOBILESIM,
which is set to the program's folder unless already set. Even with `--no-gui` it opens
a GTK display, so a private Xvfb is started when the machine has one (the display is
the only X client it serves). Robots listen on consecutive loopback ports from a free
base; a port is ready once it is LISTEN in /proc/net/tcp (connecting to test it would
use up the session).

Neither process may outlive the run, however it ends. `stop()` (every runner's `finally`)
sends SIGTERM to each one's process group, then SIGKILL after `stop_timeout_s`; a stop
that is itself cancelled kills what is left outright. Each runs in a session of its own:
its group takes whatever it forks along, and a Ctrl-C at the terminal reaches relayd
alone, which then stops them in order (bridges first) instead of MobileSim dying under
its clients. For an end with no `finally` at all (relayd killed with SIGKILL, a crash)
each is started with Linux's parent-death signal (prctl PR_SET_PDEATHSIG): the kernel
kills it when the thread that started it (the event loop's) is gone.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import os
import random
import shutil
import signal
import socket
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

ENV_PROGRAM = "RELAYD_MOBILESIM"
#: How long MobileSim may take to load a map and open its ports.
START_TIMEOUT_S = 30.0


#: How long MobileSim and Xvfb get to exit on SIGTERM before SIGKILL (each exits in
#: tens of milliseconds).
STOP_TIMEOUT_S = 2.0
#: prctl(2)'s option: the signal a process gets when its parent thread exits.
PR_SET_PDEATHSIG = 1


class MobileSimError(RuntimeError):
    """MobileSim cannot be found or started; the message says why."""


def die_with_parent() -> Callable[[], None] | None:
    """A `preexec_fn` that makes the child get SIGKILL when this thread ends (Linux); None
    where there is no prctl. The child also kills itself if this process is gone already
    (it died between the fork and the prctl)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl  # looked up before the fork
    except (OSError, AttributeError):
        return None
    parent = os.getpid()

    def preexec() -> None:
        prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        if os.getppid() != parent:
            os.kill(os.getpid(), signal.SIGKILL)

    return preexec


def _signal_group(proc: asyncio.subprocess.Process, sig: signal.Signals) -> None:
    """`sig` to the process group `proc` leads (its own session), unless it has been reaped."""
    if proc.returncode is None:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, sig)


def find_program(explicit: str | None = None) -> Path:
    """The MobileSim program: `explicit`, else $RELAYD_MOBILESIM (MobileSimError if neither)."""
    where = explicit or os.environ.get(ENV_PROGRAM)
    if not where:
        raise MobileSimError(f"no MobileSim: give --mobilesim PATH or set {ENV_PROGRAM}")
    p = Path(where)
    if p.is_dir():
        p = p / "MobileSim"
    if not (p.is_file() and os.access(p, os.X_OK)):
        raise MobileSimError(f"{p}: not an executable MobileSim program")
    return p


def _listening(port: int) -> bool:
    """Whether 127.0.0.1:port is LISTEN (state 0A) in /proc/net/tcp."""
    want = f"0100007F:{port:04X}"
    try:
        with open("/proc/net/tcp", encoding="ascii") as f:
            return any(
                (parts := line.split())[1] == want and parts[3] == "0A"
                for line in f.readlines()[1:]
            )
    except OSError:
        return False


def _free_run(n: int) -> int:
    """A base port with `n` consecutive free loopback ports."""
    rng = random.SystemRandom()
    for _ in range(200):
        base = rng.randrange(20000, 60000 - n)
        socks = []
        try:
            for k in range(n):
                s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                socks.append(s)
                s.bind(("127.0.0.1", base + k))
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise MobileSimError(f"no {n} consecutive free loopback ports")


@dataclass(slots=True)
class MobileSim:
    """One MobileSim process with robots `names` (p3at each) in `map_path`."""

    program: Path
    map_path: Path | None
    names: list[str]
    model: str = "p3at"
    #: Robot models other than `model`, by robot name (a person's stand-in: "amigo-nosonar").
    models: dict[str, str] = field(default_factory=dict)
    base_port: int = 0
    log_path: Path | None = None
    stop_timeout_s: float = STOP_TIMEOUT_S
    _procs: list[asyncio.subprocess.Process] = field(default_factory=list)
    _tmp: tempfile.TemporaryDirectory[str] | None = None

    def port(self, name: str) -> int:
        return self.base_port + self.names.index(name)

    @property
    def pids(self) -> list[int]:
        """The processes started and not yet stopped: Xvfb's (when started), MobileSim's."""
        return [p.pid for p in self._procs if p.returncode is None]

    async def _xvfb(self) -> str | None:
        """A private X display (its number) when Xvfb is installed; None: use $DISPLAY."""
        xvfb = shutil.which("Xvfb")
        if xvfb is None:
            if not os.environ.get("DISPLAY"):
                raise MobileSimError(
                    "MobileSim needs an X display: install Xvfb (Debian: xvfb) or set DISPLAY"
                )
            return None
        assert self._tmp is not None
        disp = Path(self._tmp.name) / "display"
        fd = os.open(disp, os.O_WRONLY | os.O_CREAT, 0o600)
        try:
            proc = await asyncio.create_subprocess_exec(
                xvfb, "-displayfd", str(fd), "-nolisten", "tcp",
                pass_fds=(fd,), stdout=asyncio.subprocess.DEVNULL,
                stderr=asyncio.subprocess.DEVNULL,
                start_new_session=True, preexec_fn=die_with_parent(),
            )  # fmt: skip
        finally:
            os.close(fd)
        self._procs.append(proc)
        async with asyncio.timeout(10.0):
            while not disp.read_text(encoding="ascii").strip():
                if proc.returncode is not None:
                    raise MobileSimError(f"Xvfb exited with {proc.returncode}")
                await asyncio.sleep(0.05)
        return disp.read_text(encoding="ascii").strip()

    async def start(self) -> None:
        """Start Xvfb and MobileSim; return once every robot's port is listening. On any
        failure or cancellation on the way, whatever was started is stopped again."""
        try:
            await self._start()
        except BaseException:
            await self.stop()
            raise

    async def _start(self) -> None:
        self._tmp = tempfile.TemporaryDirectory(prefix="relayd-mobilesim-")
        env = dict(os.environ)
        env.setdefault("MOBILESIM", str(self.program.parent))
        display = await self._xvfb()
        if display is not None:
            env["DISPLAY"] = f":{display}"
        self.base_port = _free_run(len(self.names))
        args = [str(self.program), "--no-gui", "--bind-to-address", "127.0.0.1"]
        args += ["-p", str(self.base_port), "--no-network-discovery"]
        args += ["--no-crash-debug", "--no-crash-restart"]
        args += ["-m", str(self.map_path)] if self.map_path is not None else ["--nomap"]
        for n in self.names:
            args += ["-r", f"{self.models.get(n, self.model)}:{n}"]
        log = self.log_path or Path(self._tmp.name) / "mobilesim.log"
        with log.open("wb") as out:
            proc = await asyncio.create_subprocess_exec(
                *args, env=env, cwd=self._tmp.name, stdout=out, stderr=asyncio.subprocess.STDOUT,
                stdin=asyncio.subprocess.DEVNULL,
                start_new_session=True, preexec_fn=die_with_parent(),
            )  # fmt: skip
        self._procs.append(proc)
        try:
            async with asyncio.timeout(START_TIMEOUT_S):
                while not all(_listening(self.port(n)) for n in self.names):
                    if proc.returncode is not None:
                        tail = log.read_text(encoding="utf-8", errors="replace")[-600:]
                        raise MobileSimError(f"MobileSim exited with {proc.returncode}: {tail}")
                    await asyncio.sleep(0.1)
        except TimeoutError:
            raise MobileSimError(f"MobileSim opened no port in {START_TIMEOUT_S:.0f} s") from None

    async def stop(self) -> None:
        """Stop MobileSim, then Xvfb: SIGTERM to each one's group, SIGKILL after
        `stop_timeout_s`. Idempotent. Cancelled while it waits: SIGKILL to what is left."""
        try:
            for proc in reversed(self._procs):
                _signal_group(proc, signal.SIGTERM)
                try:
                    async with asyncio.timeout(self.stop_timeout_s):
                        await proc.wait()
                except TimeoutError:
                    _signal_group(proc, signal.SIGKILL)
                    await proc.wait()
        finally:
            for proc in self._procs:
                _signal_group(proc, signal.SIGKILL)
            self._procs.clear()
            if self._tmp is not None:
                self._tmp.cleanup()
                self._tmp = None
