"""Steady state: CPU (percent of one core) and resident memory of one idle-but-working relayd.

`relayd run` (subprocess) drives a FakeRig with every device live: the P3-AT fake
streaming SIPs at 10 Hz, the Maestro sweeping, the RSSI file read at 20 Hz, both airOS
fakes polled, in follow mode (the fake robot drives towards the rig's leader and stops
near it, which is a steady state too). Nobody polls its API during the measurement.
Once its first scans are done, CPU is the growth of utime+stime in /proc/<pid>/stat
over the window; resident memory is VmRSS from /proc/<pid>/status sampled every
second (mean and max) and VmHWM (the peak since start).
"""

from __future__ import annotations

import asyncio
import tempfile
import time
from pathlib import Path
from typing import Any

from bench.common import BenchOutput, Result, proc_cpu_s, proc_status_kb, proc_threads
from bench.live import RelaydProcess
from relayd.fakes.rig import FakeRig
from relayd.sim.runner import scratch_root

NAME = "steady"
#: The event-core rebuild's limits (no worse than before it); its aim is 1.5 % and 50 MB.
TARGET_CPU_PCT = 2.7
TARGET_RSS_MB = 55.0


async def measure(
    *, seconds: float = 60.0, work: Path | None = None, config: dict[str, Any] | None = None
) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="relayd-bench-steady-", dir=scratch_root()) as tmp:
        rig = FakeRig(work or Path(tmp))
        await rig.start()
        try:
            async with RelaydProcess(rig, **(config or {})) as relayd:
                await relayd.wait_for(lambda d: d.get("scan_count", 0) >= 2, 60.0, "two scans")
                pid = relayd.pid
                rss: list[int] = []
                cpu0, t0 = proc_cpu_s(pid), time.monotonic()
                end = t0 + seconds
                while (now := time.monotonic()) < end:
                    rss.append(proc_status_kb(pid, "VmRSS") or 0)
                    await asyncio.sleep(min(1.0, end - now))
                cpu1, t1 = proc_cpu_s(pid), time.monotonic()
                rss.append(proc_status_kb(pid, "VmRSS") or 0)
                hwm = proc_status_kb(pid, "VmHWM") or 0
                threads = proc_threads(pid)
                doc = await relayd.wait_for(lambda d: True, 10.0, "status")
        finally:
            await rig.stop()
    return {
        "seconds": t1 - t0,
        "cpu_pct": 100.0 * (cpu1 - cpu0) / (t1 - t0),
        "rss_mb_mean": sum(rss) / len(rss) / 1024.0,
        "rss_mb_max": max(rss) / 1024.0,
        "hwm_mb": hwm / 1024.0,
        "threads": threads,
        "state": doc.get("state"),
        "reason": doc.get("reason"),
        "scans": doc.get("scan_count"),
    }


def run(quick: bool = False, *, seconds: float | None = None) -> BenchOutput:
    secs = seconds if seconds is not None else (15.0 if quick else 60.0)
    d = asyncio.run(measure(seconds=secs))
    out = BenchOutput(NAME)
    note = f"over {d['seconds']:.0f} s; relayd state {d['state']} ({d['reason']}), {d['threads']} threads"
    out.results += [
        Result(
            NAME,
            "relayd CPU, percent of one core",
            d["cpu_pct"],
            "%",
            f"<= {TARGET_CPU_PCT:g} %",
            d["cpu_pct"] <= TARGET_CPU_PCT,
            note,
        ),
        Result(
            NAME,
            "relayd resident memory (max VmRSS)",
            d["rss_mb_max"],
            "MB",
            f"<= {TARGET_RSS_MB:g} MB",
            d["rss_mb_max"] <= TARGET_RSS_MB,
            f"mean {d['rss_mb_mean']:.1f} MB, VmHWM {d['hwm_mb']:.1f} MB",
        ),
    ]
    return out
