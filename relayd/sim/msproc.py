"""Starting and stopping one MobileSim process that holds every robot of a run.

MobileSim (the P3-AT maker's ARCOS simulator) is not shipped with relayd: its program
comes from `--mobilesim PATH` or the environment variable RELAYD_MOBILESIM. It finds
its robot models (PioneerRobotModels.world.inc) through its own variable MOBILESIM,
which is set to the program's folder unless already set. Even with `--no-gui` it opens
a GTK display, so a private Xvfb is started when the machine has one (the display is
the only X client it serves). Robots listen on consecutive loopback ports from a free
base; a port is ready once it is LISTEN in /proc/net/tcp (connecting to test it would
use up the session).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import random
import shutil
import socket
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

ENV_PROGRAM = "RELAYD_MOBILESIM"
#: How long MobileSim may take to load a map and open its ports.
START_TIMEOUT_S = 30.0


class MobileSimError(RuntimeError):
    """MobileSim cannot be found or started; the message says why."""


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
    _procs: list[asyncio.subprocess.Process] = field(default_factory=list)
    _tmp: tempfile.TemporaryDirectory[str] | None = None

    def port(self, name: str) -> int:
        return self.base_port + self.names.index(name)

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
        """Start Xvfb and MobileSim; return once every robot's port is listening."""
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
            await self.stop()
            raise MobileSimError(f"MobileSim opened no port in {START_TIMEOUT_S:.0f} s") from None

    async def stop(self) -> None:
        """Stop MobileSim, then Xvfb (terminate, kill after 3 s). Idempotent."""
        for proc in reversed(self._procs):
            if proc.returncode is None:
                with contextlib.suppress(ProcessLookupError):
                    proc.terminate()
                try:
                    async with asyncio.timeout(3.0):
                        await proc.wait()
                except TimeoutError:
                    with contextlib.suppress(ProcessLookupError):
                        proc.kill()
                    await proc.wait()
        self._procs.clear()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
