"""HTTP load generator: `python -m bench.load URL [--rps R] [--seconds S] [--concurrency C]`.

Runs in its own process so its CPU is not the server's. With `--rps R > 0` it paces
requests at R per second overall (slot i is due at start + i/R; a worker that falls
behind sends at once, so a server slower than R simply gets as much as it can take);
with `--rps 0` every worker sends back to back (closed loop: the server's capacity).
Prints "ready" once the first request was answered, then runs until --seconds or
SIGINT/SIGTERM, and prints one JSON line: requests, errors, seconds, rps and latency
p50/p99/max in ms (latency measured from the moment a request is sent).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import signal
import sys
import time

import aiohttp

from bench.common import percentile


async def _load(url: str, rps: float, seconds: float, concurrency: int) -> dict[str, float]:
    latencies: list[float] = []
    errors = 0
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    connector = aiohttp.TCPConnector(limit=concurrency, force_close=False)
    async with aiohttp.ClientSession(connector=connector) as session:
        async with session.get(url) as resp:
            await resp.read()
        print("ready", flush=True)
        start = time.perf_counter()
        end = start + seconds
        slot = 0

        async def worker() -> None:
            nonlocal slot, errors
            while not stop.is_set():
                if rps > 0:
                    due = start + slot / rps
                    slot += 1
                    delay = due - time.perf_counter()
                    if delay > 0:
                        await asyncio.sleep(delay)
                if stop.is_set() or time.perf_counter() >= end:
                    return
                t0 = time.perf_counter()
                try:
                    async with session.get(url) as resp:
                        await resp.read()
                        ok = resp.status == 200
                except (aiohttp.ClientError, OSError):
                    ok = False
                if ok:
                    latencies.append(time.perf_counter() - t0)
                else:
                    errors += 1

        workers = [asyncio.create_task(worker()) for _ in range(concurrency)]
        await _until(stop, workers, seconds)
        elapsed = time.perf_counter() - start
    ms = [x * 1000.0 for x in latencies]
    return {
        "requests": len(latencies),
        "errors": errors,
        "seconds": round(elapsed, 3),
        "rps": round(len(latencies) / elapsed, 1) if elapsed > 0 else 0.0,
        "p50_ms": round(percentile(ms, 50), 3),
        "p99_ms": round(percentile(ms, 99), 3),
        "max_ms": round(max(ms), 3) if ms else float("nan"),
    }


async def _until(stop: asyncio.Event, workers: list[asyncio.Task[None]], seconds: float) -> None:
    """Wait until every worker is done (time is up) or a signal arrived; then end them."""
    all_done = asyncio.ensure_future(asyncio.wait(workers))
    stop_wait = asyncio.ensure_future(stop.wait())
    await asyncio.wait(
        [all_done, stop_wait], timeout=seconds + 10.0, return_when=asyncio.FIRST_COMPLETED
    )
    stop.set()
    for w in workers:
        if not w.done():
            w.cancel()
    await asyncio.gather(*workers, return_exceptions=True)
    for f in (all_done, stop_wait):
        f.cancel()
    await asyncio.gather(all_done, stop_wait, return_exceptions=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.load", description=__doc__.splitlines()[0])
    p.add_argument("url")
    p.add_argument(
        "--rps", type=float, default=1000.0, help="requests per second overall; 0 = flat out"
    )
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--concurrency", type=int, default=8)
    args = p.parse_args(argv)
    report = asyncio.run(_load(args.url, args.rps, args.seconds, args.concurrency))
    print(json.dumps(report), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
