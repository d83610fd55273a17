"""What a Dask worker executes for one run: the child process, bounded in wall time.

`run_task` returns the run's files as data (summary, series, optional trace, sim.log
tail) rather than leaving them on the worker's disk, so workers on other machines
need no shared filesystem: the sweep's client writes every run folder itself.
A run that exits non-zero or outlives its limit raises `RunFailed` with the reason;
the driver decides about retrying.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import os
import select
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

#: How much of a failed child's stderr goes into the error (the end is where the reason is).
ERROR_TAIL_CHARS = 2000


class RunFailed(RuntimeError):
    """A run that did not produce results: exit status or time limit, and its stderr's end."""


def child_env(base: Mapping[str, str]) -> dict[str, str]:
    """The run's environment: the worker's, with a fixed hash seed, and compiled modules
    kept when the environment forbids writing them beside their sources.

    With PYTHONDONTWRITEBYTECODE set, every start of the fork server (or, without it,
    every run) would compile relayd and its libraries afresh (about 0.6 s of CPU);
    instead they go to the user's cache directory (PYTHONPYCACHEPREFIX:
    $XDG_CACHE_HOME/relayd/pycache, else ~/.cache/relayd/pycache), so nothing is
    written beside the sources all the same. Python checks each cached file against
    its source; the directory is the user's own (mode 0700) and about 15 MB.
    """
    env = dict(base)
    env.setdefault("PYTHONHASHSEED", "0")
    if env.get("PYTHONDONTWRITEBYTECODE") and not env.get("PYTHONPYCACHEPREFIX"):
        cache = _pycache_dir(env)
        if cache is not None:
            del env["PYTHONDONTWRITEBYTECODE"]
            env["PYTHONPYCACHEPREFIX"] = cache
    return env


def _pycache_dir(env: Mapping[str, str]) -> str | None:
    """The user's bytecode cache for sweep runs, made if need be; None if it cannot be."""
    try:
        root = Path(env.get("XDG_CACHE_HOME") or Path.home() / ".cache")
        path = root / "relayd" / "pycache"
        path.mkdir(parents=True, exist_ok=True, mode=0o700)
    except (OSError, RuntimeError):  # no home, or a read-only one
        return None
    return str(path)


class ForkServer:
    """This worker thread's relayd/sweep/forkserver.py: one run at a time through it."""

    def __init__(self, env: dict[str, str]) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "relayd.sweep.forkserver"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            env=env,
        )
        self._buf = b""

    def alive(self) -> bool:
        return self.proc.poll() is None

    def _answer(self, deadline: float | None) -> dict[str, Any] | None:
        """The server's next answer line; None at the deadline; EOFError if it is gone."""
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        while b"\n" not in self._buf:
            wait = None if deadline is None else max(0.0, deadline - time.monotonic())
            ready, _, _ = select.select([fd], [], [], wait)
            if not ready:
                return None
            chunk = os.read(fd, 4096)
            if not chunk:
                raise EOFError("the fork server ended")
            self._buf += chunk
        line, _, self._buf = self._buf.partition(b"\n")
        answer: dict[str, Any] = json.loads(line)
        return answer

    def run(self, spec: Path, out: Path, log: Path, timeout_s: float) -> int:
        """The run's exit status (negative: killed by that signal); TimeoutError past
        timeout_s (the run killed); EOFError or OSError if the server is gone."""
        assert self.proc.stdin is not None
        req = {"spec": str(spec), "out": str(out), "log": str(log)}
        self.proc.stdin.write(json.dumps(req).encode() + b"\n")
        self.proc.stdin.flush()
        deadline = time.monotonic() + timeout_s
        forked = self._answer(deadline)
        if forked is None:
            # Still starting (or stuck): it would fork this run later, out of turn, so
            # it goes; the next run starts another.
            self.proc.kill()
            self.proc.wait()
            raise TimeoutError
        done = self._answer(deadline)
        if done is None:
            os.kill(int(forked["pid"]), signal.SIGKILL)
            self._answer(None)  # its exit
            raise TimeoutError
        return int(done["exit"])

    def close(self) -> None:
        with contextlib.suppress(OSError):
            if self.proc.stdin is not None:
                self.proc.stdin.close()
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


_servers = threading.local()


def _fork_server(env: dict[str, str]) -> ForkServer:
    """This thread's fork server, started (again) when it has none or it has died."""
    server: ForkServer | None = getattr(_servers, "server", None)
    if server is None or not server.alive():
        server = _servers.server = ForkServer(env)
        atexit.register(server.close)
    return server


def _failure(code: int, stderr: str) -> RunFailed:
    tail = stderr.strip()[-ERROR_TAIL_CHARS:]
    how = f"killed by signal {-code}" if code < 0 else f"exit status {code}"
    return RunFailed(f"{how}: {tail}" if tail else how)


def _run_forked(spec: Path, out: Path, env: dict[str, str], timeout_s: float) -> None:
    log = spec.with_name("child.log")
    server = _fork_server(env)
    try:
        code = server.run(spec, out, log, timeout_s)
    except TimeoutError:
        raise RunFailed(f"timed out after {timeout_s:g} s wall time (--run-timeout)") from None
    except (EOFError, OSError) as exc:
        server.close()
        _servers.server = None
        raise RunFailed(f"the worker's fork server failed: {exc}") from None
    if code != 0:
        text = log.read_text(encoding="utf-8", errors="replace") if log.exists() else ""
        raise _failure(code, text)


def _run_process(spec: Path, out: Path, env: dict[str, str], timeout_s: float) -> None:
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "relayd.sweep.child", str(spec), str(out)],
            capture_output=True,
            text=True,
            timeout=timeout_s,
            env=env,
            check=False,
        )
    except subprocess.TimeoutExpired:
        raise RunFailed(f"timed out after {timeout_s:g} s wall time (--run-timeout)") from None
    if proc.returncode != 0:
        raise _failure(proc.returncode, proc.stderr or "")


def run_task(payload: dict[str, Any], timeout_s: float) -> dict[str, Any]:
    """Run one simulation in a child process; its results, or RunFailed.

    On Linux the child is forked by this worker thread's fork server
    (relayd/sweep/forkserver.py: the simulator imported once, not once per run);
    elsewhere, or with RELAYD_SWEEP_FORK=0, it is a fresh `python -m relayd.sweep.child`.
    """
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="relayd-sweep-") as tmp:
        spec_path = Path(tmp) / "spec.json"
        spec_path.write_text(json.dumps(payload), encoding="utf-8")
        out = Path(tmp) / "out"
        env = child_env(os.environ)
        env["RELAYD_SWEEP_PARENT_PID"] = str(os.getpid())
        if sys.platform == "linux" and os.environ.get("RELAYD_SWEEP_FORK", "1") != "0":
            _run_forked(spec_path, out, env, timeout_s)
        else:
            _run_process(spec_path, out, env, timeout_s)
        result: dict[str, Any] = {
            "summary": json.loads((out / "summary.json").read_text(encoding="utf-8")),
            "series": json.loads((out / "series.json").read_text(encoding="utf-8")),
            "sim_log": (out / "sim.log").read_text(encoding="utf-8")[-200_000:],
        }
        trace = out / "trace.jsonl"
        if trace.exists():
            result["trace"] = trace.read_text(encoding="utf-8")
    result["wall_s"] = round(time.monotonic() - t0, 3)
    return result
