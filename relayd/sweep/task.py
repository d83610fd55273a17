"""What a Dask worker executes for one run: the child process, bounded in wall time.

`run_task` returns the run's files as data (summary, series, optional trace, sim.log
tail) rather than leaving them on the worker's disk, so workers on other machines
need no shared filesystem: the sweep's client writes every run folder itself.
A run that exits non-zero or outlives its limit raises `RunFailed` with the reason;
the driver decides about retrying.
"""

from __future__ import annotations

import atexit
import json
import multiprocessing.util
import os
import shutil
import subprocess
import sys
import tempfile
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

    With PYTHONDONTWRITEBYTECODE set, every run would compile relayd and its libraries
    afresh (about 0.6 s of CPU per run, a tenth of a generated world's run); instead the
    worker's runs share a bytecode cache in a private temporary directory of the worker
    (PYTHONPYCACHEPREFIX; removed when the worker exits), so nothing is written beside
    the sources all the same. Python checks each cached file against its source.
    """
    env = dict(base)
    env.setdefault("PYTHONHASHSEED", "0")
    if env.get("PYTHONDONTWRITEBYTECODE") and not env.get("PYTHONPYCACHEPREFIX"):
        del env["PYTHONDONTWRITEBYTECODE"]
        env["PYTHONPYCACHEPREFIX"] = _pycache_dir()
    return env


_pycache: list[str] = []  # this worker's bytecode cache, once made


def _pycache_dir() -> str:
    if not _pycache:
        path = tempfile.mkdtemp(prefix="relayd-sweep-pycache-")
        # About 15 MB: removed at the worker's exit, whether it is a plain process (atexit)
        # or a multiprocessing child, as Dask's local workers are (which skip atexit).
        atexit.register(shutil.rmtree, path, ignore_errors=True)
        multiprocessing.util.Finalize(
            None, shutil.rmtree, args=(path,), kwargs={"ignore_errors": True}, exitpriority=0
        )
        _pycache.append(path)
    return _pycache[0]


def run_task(payload: dict[str, Any], timeout_s: float) -> dict[str, Any]:
    """Run one simulation in a child process; its results, or RunFailed."""
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="relayd-sweep-") as tmp:
        spec_path = Path(tmp) / "spec.json"
        spec_path.write_text(json.dumps(payload), encoding="utf-8")
        out = Path(tmp) / "out"
        env = child_env(os.environ)
        env["RELAYD_SWEEP_PARENT_PID"] = str(os.getpid())
        try:
            proc = subprocess.run(
                [sys.executable, "-m", "relayd.sweep.child", str(spec_path), str(out)],
                capture_output=True,
                text=True,
                timeout=timeout_s,
                env=env,
                check=False,
            )
        except subprocess.TimeoutExpired:
            raise RunFailed(f"timed out after {timeout_s:g} s wall time (--run-timeout)") from None
        if proc.returncode != 0:
            tail = (proc.stderr or "").strip()[-ERROR_TAIL_CHARS:]
            how = (
                f"killed by signal {-proc.returncode}"
                if proc.returncode < 0
                else f"exit status {proc.returncode}"
            )
            raise RunFailed(f"{how}: {tail}" if tail else how)
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
