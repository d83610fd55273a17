"""What a Dask worker executes for one run: the child process, bounded in wall time.

`run_task` returns the run's files as data (summary, series, optional trace, sim.log
tail) rather than leaving them on the worker's disk, so workers on other machines
need no shared filesystem: the sweep's client writes every run folder itself.
A run that exits non-zero or outlives its limit raises `RunFailed` with the reason;
the driver decides about retrying.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

#: How much of a failed child's stderr goes into the error (the end is where the reason is).
ERROR_TAIL_CHARS = 2000


class RunFailed(RuntimeError):
    """A run that did not produce results: exit status or time limit, and its stderr's end."""


def run_task(payload: dict[str, Any], timeout_s: float) -> dict[str, Any]:
    """Run one simulation in a child process; its results, or RunFailed."""
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="relayd-sweep-") as tmp:
        spec_path = Path(tmp) / "spec.json"
        spec_path.write_text(json.dumps(payload), encoding="utf-8")
        out = Path(tmp) / "out"
        env = dict(os.environ)
        env.setdefault("PYTHONHASHSEED", "0")
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
