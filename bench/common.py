"""Shared pieces of the benchmarks: result rows, statistics, the machine, /proc readings.

Every benchmark returns a list of `Result` rows; `bench/run.py` prints them as one
markdown table and writes bench/RESULTS.md. A row with no target (`passed is None`)
is a figure reported for context, not judged.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import platform
import socket
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path


@dataclass(slots=True)
class Result:
    """One row of the results table."""

    bench: str
    figure: str
    value: float | None
    unit: str = ""
    target: str = ""  # as a reader states it, e.g. "< 2 ms"; empty: reported, not judged
    passed: bool | None = None
    note: str = ""

    def value_text(self) -> str:
        v = self.value
        if v is None or (isinstance(v, float) and not math.isfinite(v)):
            return "n/a"
        if abs(v) >= 100 or float(v).is_integer():
            text = f"{v:.0f}"
        elif abs(v) >= 10:
            text = f"{v:.1f}"
        elif abs(v) >= 0.1:
            text = f"{v:.2f}"
        else:
            text = f"{v:.3g}"
        return f"{text} {self.unit}".strip()

    def verdict(self) -> str:
        if self.passed is None:
            return ""
        return "pass" if self.passed else "**FAIL**"


@dataclass(slots=True)
class BenchOutput:
    """What one benchmark hands back: its rows and free-text details for RESULTS.md."""

    name: str
    results: list[Result] = field(default_factory=list)
    details: list[str] = field(default_factory=list)
    wall_s: float = 0.0


def percentile(values: Sequence[float], q: float) -> float:
    """The q-th percentile (0..100) with linear interpolation; nan for no values."""
    if not values:
        return math.nan
    xs = sorted(values)
    if len(xs) == 1:
        return float(xs[0])
    pos = (len(xs) - 1) * q / 100.0
    lo = math.floor(pos)
    hi = min(lo + 1, len(xs) - 1)
    return float(xs[lo] + (xs[hi] - xs[lo]) * (pos - lo))


def rms(values: Sequence[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values)) if values else math.nan


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now (the usual small race is acceptable here)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_info() -> dict[str, str]:
    """What a reader needs to compare these figures with their own machine."""
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        usable = os.cpu_count() or 0
    try:
        load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        load = "n/a"
    mem = "n/a"
    try:
        for line in Path("/proc/meminfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("MemTotal:"):
                mem = f"{int(line.split()[1]) / 1024 / 1024:.1f} GiB"
    except OSError:
        pass
    return {
        "cpu": cpu_model(),
        "cores": f"{os.cpu_count()} logical, {usable} usable by this process",
        "memory": mem,
        "python": f"{platform.python_implementation()} {sys.version.split()[0]}",
        "os": f"{platform.system()} {platform.release()}",
        "date": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "load average at start": load,
    }


# -- /proc readings of another process ------------------------------------------------

CLK_TCK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def proc_cpu_s(pid: int) -> float:
    """User + system CPU seconds the process has used (/proc/<pid>/stat fields 14, 15)."""
    raw = Path(f"/proc/{pid}/stat").read_text(encoding="ascii")
    # The command name (field 2) may contain spaces; everything after its ')' is fixed.
    fields = raw[raw.rindex(")") + 2 :].split()
    utime, stime = int(fields[11]), int(fields[12])
    return (utime + stime) / CLK_TCK


def proc_status_kb(pid: int, key: str) -> int | None:
    """A `kB` field of /proc/<pid>/status (VmRSS, VmHWM, ...)."""
    for line in Path(f"/proc/{pid}/status").read_text(encoding="ascii").splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    return None


def proc_threads(pid: int) -> int | None:
    return proc_status_kb(pid, "Threads")


# -- a `relayd` command with another tree's code, timed ---------------------------------


def run_relayd_of(
    tree: Path, argv: Sequence[str], cwd: Path, env: dict[str, str], what: str
) -> tuple[float, float]:
    """Run `relayd ARGV` with the code of `tree` (its PYTHONPATH in `env`; checked, not
    assumed, in the child) in a child process; its (wall, CPU) seconds, the CPU of every
    process it started included. A non-zero exit raises, naming `what` and the tree."""
    import resource
    import subprocess
    import time

    code = (
        "import sys, relayd; from relayd.cli import main; "
        f"assert relayd.__file__.startswith({str(tree) + os.sep!r}), relayd.__file__; "
        "sys.exit(main(sys.argv[1:]))"
    )
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", code, *argv],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"{what} on {tree}: exit {proc.returncode}\n{proc.stderr[-2000:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
