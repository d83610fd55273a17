"""A connection flood against one loopback port, run as its own process by tests/api/test_flood.py.

`python tests/api/flood.py PORT --idle N --slow M --hold-s S`: opens N connections that
send nothing and M "slow-header" clients that send a request line and then one
header byte a second without ever finishing, holds them for S seconds, closes them
and prints one JSON line of figures. Bounded in count and time, loopback only. It
prints `{"flooding": ...}` once every connection has been tried, so the test knows
when the flood is in place. Its own process, so the test's event loop (which runs
the fake devices) is not the one doing thousands of connects.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import resource
import socket
import time

HOST = "127.0.0.1"
MAX_CONNECTIONS = 5000
CONNECT_TIMEOUT_S = 3.0


async def _connect(port: int, sem: asyncio.Semaphore) -> socket.socket | None:
    loop = asyncio.get_running_loop()
    async with sem:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setblocking(False)
        try:
            async with asyncio.timeout(CONNECT_TIMEOUT_S):
                await loop.sock_connect(sock, (HOST, port))
        except (OSError, TimeoutError):
            sock.close()
            return None
        return sock


async def _slow_header(sock: socket.socket, until: float, stats: dict[str, int]) -> None:
    loop = asyncio.get_running_loop()
    header = b"X-Slow: " + b"a" * 1000
    try:
        await loop.sock_sendall(sock, b"GET /status HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        for byte in header:
            if time.monotonic() >= until:
                return
            await loop.sock_sendall(sock, bytes([byte]))
            await asyncio.sleep(1.0)
    except OSError:
        stats["slow_cut_by_server"] += 1


async def flood(port: int, idle: int, slow: int, hold_s: float) -> dict[str, object]:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = min(hard, idle + slow + 256) if hard != resource.RLIM_INFINITY else idle + slow + 256
    if soft < want:
        resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))
    sem = asyncio.Semaphore(64)
    t0 = time.monotonic()
    idle_socks = await asyncio.gather(*(_connect(port, sem) for _ in range(idle)))
    slow_socks = await asyncio.gather(*(_connect(port, sem) for _ in range(slow)))
    until = time.monotonic() + hold_s
    stats = {"slow_cut_by_server": 0}
    print(json.dumps({"flooding": True, "connect_s": round(time.monotonic() - t0, 2)}), flush=True)
    slow_tasks = [
        asyncio.create_task(_slow_header(s, until, stats)) for s in slow_socks if s is not None
    ]
    await asyncio.sleep(max(0.0, until - time.monotonic()))
    for task in slow_tasks:
        task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await asyncio.gather(*slow_tasks, return_exceptions=True)
    for s in (*idle_socks, *slow_socks):
        if s is not None:
            s.close()
    return {
        "idle_connected": sum(s is not None for s in idle_socks),
        "slow_connected": sum(s is not None for s in slow_socks),
        **stats,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("port", type=int)
    parser.add_argument("--idle", type=int, default=1100)
    parser.add_argument("--slow", type=int, default=100)
    parser.add_argument("--hold-s", type=float, default=20.0)
    args = parser.parse_args()
    if args.idle + args.slow > MAX_CONNECTIONS or not 0 < args.hold_s <= 120:
        parser.error(f"at most {MAX_CONNECTIONS} connections, held at most 120 s")
    print(json.dumps(asyncio.run(flood(args.port, args.idle, args.slow, args.hold_s))), flush=True)


if __name__ == "__main__":
    main()
