"""/status throughput and p99 latency against a bare aiohttp JSON handler.

relayd (`relayd run` subprocess on a FakeRig, follow mode, every device live) and
bench/bare.py (one handler serialising a copy of the /status document relayd just
served) each run in their own process; the same client (bench/load.py, its own
process, 8 connections, back-to-back requests) loads them in turn, alternating
bare / relayd for several rounds in the same run so drift in the machine's load hits
both. Throughput is the mean over rounds; the throughput ratio is the median of the
per-round ratios (one round disturbed by another process on the machine cannot decide
it); latency p99 is the worst round's. Because both servers and the client share a
2-core machine with whatever else runs on it, the benchmark also reads each server's
CPU time (/proc/<pid>/stat) during its slices: CPU per request is what decides
capacity, and it hardly moves with other processes' load.
"""

from __future__ import annotations

import asyncio
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import aiohttp

from bench.common import BenchOutput, Result, free_port, percentile, proc_cpu_s
from bench.live import REPO, LoadProcess, RelaydProcess, _child_env
from relayd.fakes.rig import FakeRig
from relayd.sim.runner import scratch_root

NAME = "status"
#: /status throughput at least this share of bare aiohttp's (the event core's limit).
TARGET_RATIO = 0.84
#: CPU per request: bare's over relayd's, at least this (what an idle core could serve).
TARGET_CPU_RATIO = 0.7


async def _bare_server(payload_path: Path, port: int) -> asyncio.subprocess.Process:
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "bench.bare",
        str(payload_path),
        "--port",
        str(port),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        env=_child_env(),
        cwd=str(REPO),
    )
    assert proc.stdout is not None
    async with asyncio.timeout(30.0):
        line = await proc.stdout.readline()
    if line.strip() != b"ready":
        raise RuntimeError(f"bare server failed: {line!r}")
    return proc


async def measure(
    *,
    seconds: float = 5.0,
    rounds: int = 3,
    concurrency: int = 8,
    work: Path | None = None,
    scan: dict[str, Any] | None = None,
) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="relayd-bench-status-", dir=scratch_root()) as tmp:
        wdir = work or Path(tmp)
        rig = FakeRig(wdir)
        await rig.start()
        bare: asyncio.subprocess.Process | None = None
        runs: dict[str, list[dict[str, Any]]] = {"bare": [], "relayd": []}
        try:
            async with RelaydProcess(rig, scan=scan or {}, log={"level": "warning"}) as relayd:
                doc = await relayd.wait_for(
                    lambda d: d.get("scan_count", 0) >= 1, 60.0, "first scan"
                )
                async with (
                    aiohttp.ClientSession() as session,
                    session.get(relayd.url + "/status") as resp,
                ):
                    body = await resp.read()
                payload_path = wdir / "status-payload.json"
                payload_path.write_bytes(body)
                port = free_port()
                bare = await _bare_server(payload_path, port)
                urls = {"bare": f"http://127.0.0.1:{port}/status", "relayd": relayd.url + "/status"}
                pids = {"bare": bare.pid, "relayd": relayd.pid}
                for _ in range(rounds):
                    for name in ("bare", "relayd"):
                        load = await LoadProcess(
                            urls[name], rps=0, seconds=seconds, concurrency=concurrency
                        ).start()
                        cpu0 = proc_cpu_s(pids[name])
                        report = dict(await load.wait())
                        # CPU the server spent (its whole process) while this slice ran.
                        report["server_cpu_s"] = proc_cpu_s(pids[name]) - cpu0
                        runs[name].append(report)
        finally:
            if bare is not None and bare.returncode is None:
                bare.terminate()
                await bare.wait()
            await rig.stop()
    return {"runs": runs, "payload_bytes": len(body), "state": doc.get("state")}


def _summary(runs: list[dict[str, Any]]) -> tuple[float, float, int]:
    rps = sum(float(r["rps"]) for r in runs) / len(runs)
    p99 = max(float(r["p99_ms"]) for r in runs)
    errors = sum(int(r["errors"]) for r in runs)
    return rps, p99, errors


def cpu_per_request_us(runs: list[dict[str, Any]]) -> float:
    """Server CPU time per answered request (us), over all slices."""
    requests = sum(int(r["requests"]) for r in runs)
    return (
        1e6 * sum(float(r["server_cpu_s"]) for r in runs) / requests if requests else float("nan")
    )


def run(
    quick: bool = False, *, seconds: float | None = None, rounds: int | None = None
) -> BenchOutput:
    secs = seconds if seconds is not None else (1.0 if quick else 2.0)
    n = rounds if rounds is not None else (3 if quick else 10)
    data = asyncio.run(measure(seconds=secs, rounds=n))
    relayd_rps, relayd_p99, relayd_err = _summary(data["runs"]["relayd"])
    bare_rps, bare_p99, bare_err = _summary(data["runs"]["bare"])
    ratios = [
        float(a["rps"]) / float(b["rps"])
        for a, b in zip(data["runs"]["relayd"], data["runs"]["bare"], strict=True)
        if float(b["rps"]) > 0
    ]
    ratio = percentile(ratios, 50)
    relayd_cpu = cpu_per_request_us(data["runs"]["relayd"])
    bare_cpu = cpu_per_request_us(data["runs"]["bare"])
    cpu_ratio = bare_cpu / relayd_cpu if relayd_cpu > 0 else float("nan")
    out = BenchOutput(NAME)
    per_round = ", ".join(
        f"{a['rps']:.0f}/{b['rps']:.0f}"
        for a, b in zip(data["runs"]["relayd"], data["runs"]["bare"], strict=True)
    )
    out.results += [
        Result(
            NAME,
            "/status throughput, relayd",
            relayd_rps,
            "req/s",
            "",
            None,
            f"{relayd_err} errors; payload {data['payload_bytes']} bytes",
        ),
        Result(
            NAME,
            "/status throughput, bare aiohttp",
            bare_rps,
            "req/s",
            "",
            None,
            f"{bare_err} errors",
        ),
        Result(
            NAME,
            "/status throughput relayd / bare (median of rounds)",
            ratio,
            "",
            f">= {TARGET_RATIO:g}",
            ratio >= TARGET_RATIO if ratios else None,
            f"{n} rounds x {secs:g} s each, relayd/bare per round: {per_round}",
        ),
        Result(
            NAME,
            "server CPU per /status request, relayd",
            relayd_cpu,
            "us",
            "",
            None,
            "whole process, including the daemon's own background work (see steady)",
        ),
        Result(NAME, "server CPU per /status request, bare aiohttp", bare_cpu, "us"),
        Result(
            NAME,
            "/status efficiency relayd / bare (CPU per request)",
            cpu_ratio,
            "",
            f">= {TARGET_CPU_RATIO:g}",
            cpu_ratio >= TARGET_CPU_RATIO,
            "bare CPU/request over relayd's: the capacity ratio on an otherwise idle core; "
            "unlike throughput it does not move with other processes' load",
        ),
        Result(
            NAME,
            "/status p99 latency, relayd",
            relayd_p99,
            "ms",
            "",
            None,
            "8 connections, back to back",
        ),
        Result(NAME, "/status p99 latency, bare aiohttp", bare_p99, "ms"),
    ]
    out.details.append("Per slice (load reports): " + json.dumps(data["runs"]))
    return out
