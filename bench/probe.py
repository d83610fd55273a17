"""`relayd probe robot` CPU at 10 Hz SIPs: this tree side by side with a baseline tree.

A FakeRobot in this process serves a real pty and streams SIPs at ARCOS's 10 Hz. The
probe runs as a subprocess (`python -m relayd probe robot --json`, its stdout drained
through a pipe as a terminal would take it) and its CPU is the growth of utime+stime
in /proc/<pid>/stat over the window, after its handshake is done. The same
measurement runs, interleaved, for the code of a baseline git revision (exported with
`git archive` into a scratch directory), so both see the same machine load. ARIA's
own C++ client uses 0.6 % of a core for the same job on the project's reference
machine; that is the target.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench.common import BenchOutput, Result, proc_cpu_s
from drivers.arcos.fake import FakeRobot
from relayd.sim.runner import scratch_root

NAME = "probe"
TARGET_CPU_PCT = 0.6
#: The revision before the driver's SIP path was profiled and trimmed.
BASELINE_REV = "641a72f"
REPO = Path(__file__).resolve().parent.parent


async def measure_once(tree: Path, seconds: float, warmup_s: float = 1.0) -> float:
    """CPU percent of one core used by `relayd probe robot` from `tree` over `seconds`."""
    fake = FakeRobot(sonars_per_sip=8)
    path = fake.serve_pty()
    env = {**os.environ, "PYTHONPATH": str(tree)}
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-c",
        "import sys; from relayd.cli import main; sys.exit(main())",
        "probe",
        "robot",
        "--port",
        path,
        "--json",
        "--seconds",
        str(seconds + warmup_s + 30),
        cwd=str(tree),
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
    )
    lines = 0
    connected = asyncio.Event()

    async def drain() -> None:
        nonlocal lines
        assert proc.stdout is not None
        while await proc.stdout.readline():
            lines += 1
            connected.set()

    reader = asyncio.create_task(drain())
    try:
        async with asyncio.timeout(30):
            await connected.wait()
        await asyncio.sleep(warmup_s)
        cpu0, t0, n0 = proc_cpu_s(proc.pid), time.monotonic(), lines
        await asyncio.sleep(seconds)
        cpu1, t1, n1 = proc_cpu_s(proc.pid), time.monotonic(), lines
        if n1 - n0 < 0.8 * 10 * seconds:
            raise RuntimeError(
                f"the probe printed {n1 - n0} SIPs in {seconds:g} s, expected ~{10 * seconds:g}"
            )
        return 100.0 * (cpu1 - cpu0) / (t1 - t0)
    finally:
        with contextlib.suppress(ProcessLookupError):
            proc.terminate()
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(5):
                await proc.wait()
        reader.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reader
        await fake.stop()


def export_tree(rev: str, into: Path) -> Path:
    """The files of `rev` under `into` (no .git): an importable relayd/drivers of that time."""
    archive = subprocess.run(
        ["git", "-C", str(REPO), "archive", rev], check=True, capture_output=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into


async def measure(seconds: float, rounds: int, baseline: str | None) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="relayd-bench-probe-", dir=scratch_root()) as tmp:
        trees = {"this tree": REPO}
        if baseline:
            trees[f"baseline {baseline}"] = export_tree(baseline, Path(tmp))
        got: dict[str, list[float]] = {name: [] for name in trees}
        for _ in range(rounds):  # interleaved: both see the same load over the run
            for name, tree in trees.items():
                got[name].append(await measure_once(tree, seconds))
    return got


def run(
    quick: bool = False,
    *,
    seconds: float | None = None,
    rounds: int | None = None,
    baseline: str | None = BASELINE_REV,
) -> BenchOutput:
    secs = seconds if seconds is not None else (10.0 if quick else 30.0)
    n = rounds if rounds is not None else (1 if quick else 3)
    got = asyncio.run(measure(secs, n, baseline))
    out = BenchOutput(NAME)
    for name, values in got.items():
        median = statistics.median(values)
        judged = name == "this tree"
        out.results.append(
            Result(
                NAME,
                f"`relayd probe robot` CPU at 10 Hz SIPs ({name})",
                median,
                "%",
                f"<= {TARGET_CPU_PCT:g} %" if judged else "",
                (median <= TARGET_CPU_PCT) if judged else None,
                f"median of {len(values)} x {secs:g} s: " + ", ".join(f"{v:.2f}" for v in values),
            )
        )
    out.details.append(
        f"`relayd probe robot --json` on a pty to a FakeRobot at 10 Hz, {n} interleaved rounds "
        f"of {secs:g} s per tree; CPU is utime+stime of the probe process. Target: ARIA's C++ "
        f"client, {TARGET_CPU_PCT:g} % of a core on the reference machine."
    )
    return out


if __name__ == "__main__":
    for r in run(quick="--quick" in sys.argv).results:
        print(r.figure, r.value_text(), r.verdict(), r.note)
