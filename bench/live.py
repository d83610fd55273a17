"""A live relay for the benchmarks: `relayd run` as a subprocess driving a FakeRig here.

The daemon runs in its own process, as on a robot, so its event loop is not shared
with the fakes or with the measuring code; the fakes run in the benchmark's event loop.
`LoadProcess` runs bench/load.py (an aiohttp client loop) as a third process.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

import aiohttp

from bench.common import free_port
from relayd.fakes.rig import FakeRig

REPO = Path(__file__).resolve().parent.parent


def _child_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + (
        os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else ""
    )
    env.pop("NOTIFY_SOCKET", None)  # never talk to a real systemd from a benchmark
    return env


class RelaydProcess:
    """`python -m relayd run -c <rig config>`; `async with` starts it and waits for /status."""

    def __init__(
        self,
        rig: FakeRig,
        *,
        start_timeout_s: float = 30.0,
        command_prefix: Sequence[str] = (),
        **config: Any,
    ) -> None:
        self.rig = rig
        #: e.g. ("chrt", "-f", "10"): how the daemon is started (scheduling comparisons).
        self.command_prefix = tuple(command_prefix)
        self.port = free_port()
        self.config_kw = config
        self.start_timeout_s = start_timeout_s
        self.proc: subprocess.Popen[bytes] | None = None
        self.log_path = rig.work / f"{rig.name}-relayd.log"
        self._log: Any = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    async def status(self, session: aiohttp.ClientSession) -> dict[str, Any]:
        async with session.get(self.url + "/status") as resp:
            resp.raise_for_status()
            doc: dict[str, Any] = await resp.json()
            return doc

    async def wait_for(self, predicate: Any, timeout_s: float, what: str) -> dict[str, Any]:
        """Poll /status until `predicate(doc)` holds; the last document is returned."""
        last: dict[str, Any] | None = None
        try:
            async with aiohttp.ClientSession() as session, asyncio.timeout(timeout_s):
                while True:
                    self._check_alive()
                    with contextlib.suppress(aiohttp.ClientError, OSError):
                        last = await self.status(session)
                        if predicate(last):
                            return last
                    await asyncio.sleep(0.1)
        except TimeoutError:
            raise RuntimeError(
                f"relayd never reached '{what}' within {timeout_s:g} s; last /status "
                f"{json.dumps(last)[:400] if last else None}; log {self.log_path}"
            ) from None

    def _check_alive(self) -> None:
        if self.proc is not None and self.proc.poll() is not None:
            tail = (
                self.log_path.read_text(errors="replace")[-2000:] if self.log_path.exists() else ""
            )
            raise RuntimeError(f"relayd exited with {self.proc.returncode}:\n{tail}")

    async def __aenter__(self) -> RelaydProcess:
        cfg = self.rig.write_config(
            self.rig.work / f"{self.rig.name}-bench.toml",
            secrets_in_files=True,
            api_port=self.port,
            **self.config_kw,
        )
        self._log = self.log_path.open("wb")
        self.proc = subprocess.Popen(
            [*self.command_prefix, sys.executable, "-m", "relayd", "run", "-c", str(cfg)],
            stdout=self._log,
            stderr=subprocess.STDOUT,
            env=_child_env(),
            cwd=str(REPO),
        )
        await self.wait_for(lambda doc: True, self.start_timeout_s, "answering /status")
        return self

    async def __aexit__(
        self, et: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.stop()

    async def stop(self) -> None:
        proc, self.proc = self.proc, None
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                await asyncio.to_thread(proc.wait, 5.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                await asyncio.to_thread(proc.wait)
        if self._log is not None:
            self._log.close()
            self._log = None


class LoadProcess:
    """bench/load.py hammering one URL from its own process; `stop()` returns its figures."""

    def __init__(
        self, url: str, *, rps: float, seconds: float = 3600.0, concurrency: int = 8
    ) -> None:
        self.args = [
            sys.executable,
            "-m",
            "bench.load",
            url,
            "--rps",
            str(rps),
            "--seconds",
            str(seconds),
            "--concurrency",
            str(concurrency),
        ]
        self.proc: asyncio.subprocess.Process | None = None

    async def start(self) -> LoadProcess:
        self.proc = await asyncio.create_subprocess_exec(
            *self.args,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
            env=_child_env(),
            cwd=str(REPO),
        )
        assert self.proc.stdout is not None
        # The load process says "ready" once its session is up and the first request answered.
        async with asyncio.timeout(30.0):
            line = await self.proc.stdout.readline()
        if line.strip() != b"ready":
            err = await self.proc.stderr.read() if self.proc.stderr else b""
            raise RuntimeError(
                f"load process failed to start: {line!r} {err.decode(errors='replace')[-800:]}"
            )
        return self

    async def stop(self) -> Mapping[str, Any]:
        """Ask it to finish (SIGINT) and return its JSON report."""
        proc = self.proc
        assert proc is not None and proc.stdout is not None
        if proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGINT)
        async with asyncio.timeout(30.0):
            out, err = await proc.communicate()
        try:
            report: dict[str, Any] = json.loads(out.decode().strip().splitlines()[-1])
        except (IndexError, ValueError):
            raise RuntimeError(
                f"load process gave no report: {out!r} {err.decode(errors='replace')[-800:]}"
            ) from None
        return report

    async def wait(self) -> Mapping[str, Any]:
        """Let it run its --seconds out and return its report."""
        proc = self.proc
        assert proc is not None
        async with asyncio.timeout(3600.0):
            out, _err = await proc.communicate()
        return dict(json.loads(out.decode().strip().splitlines()[-1]))
