"""A Foxglove viewer stand-in: `python -m bench.viewer ws://HOST:PORT/`.

Runs in its own process, as a Foxglove app would on the operator's laptop. It speaks
the Foxglove WebSocket protocol (subprotocol `foxglove.sdk.v1`): reads `serverInfo`
and `advertise`, subscribes to every channel, prints "ready", then reads and counts
every message-data frame until SIGINT/SIGTERM, and prints one JSON line: messages,
bytes, seconds, channels, and the oldest a message was when it arrived (its log time
against the wall clock, ms: how far the live view lags).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import signal
import struct
import sys
import time
from typing import Any

import aiohttp

SUBPROTOCOL = "foxglove.sdk.v1"


async def _view(url: str) -> dict[str, float]:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    channels: dict[int, str] = {}
    messages = nbytes = 0
    lag_max_ms = 0.0
    async with (
        aiohttp.ClientSession() as session,
        session.ws_connect(url, protocols=[SUBPROTOCOL], max_msg_size=0) as ws,
    ):
        while not channels:
            doc = json.loads((await ws.receive(timeout=30)).data)
            if doc["op"] == "advertise":
                channels = {ch["id"]: ch["topic"] for ch in doc["channels"]}
        await ws.send_str(
            json.dumps(
                {
                    "op": "subscribe",
                    "subscriptions": [{"id": cid, "channelId": cid} for cid in channels],
                }
            )
        )
        print("ready", flush=True)
        start = time.perf_counter()

        async def read() -> None:
            nonlocal messages, nbytes, lag_max_ms
            async for msg in ws:
                if msg.type == aiohttp.WSMsgType.BINARY and msg.data[0] == 0x01:
                    _sub, log_time = struct.unpack_from("<IQ", msg.data, 1)
                    messages += 1
                    nbytes += len(msg.data)
                    lag_max_ms = max(lag_max_ms, (time.time_ns() - log_time) / 1e6)

        reader = asyncio.create_task(read())
        await stop.wait()
        reader.cancel()
        seconds = time.perf_counter() - start
    return {
        "messages": messages,
        "bytes": nbytes,
        "seconds": round(seconds, 2),
        "channels": len(channels),
        "lag_max_ms": round(lag_max_ms, 1),
    }


class ViewerProcess:
    """This module in its own process; `start()` waits for "ready", `stop()` returns its figures."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.proc: asyncio.subprocess.Process | None = None

    async def start(self) -> ViewerProcess:
        from bench.live import REPO, _child_env

        self.proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "bench.viewer",
            self.url,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
            env=_child_env(),
            cwd=str(REPO),
        )
        assert self.proc.stdout is not None
        async with asyncio.timeout(30.0):
            line = await self.proc.stdout.readline()
        if line.strip() != b"ready":
            err = await self.proc.stderr.read() if self.proc.stderr else b""
            raise RuntimeError(
                f"viewer failed to start: {line!r} {err.decode(errors='replace')[-800:]}"
            )
        return self

    async def stop(self) -> dict[str, Any]:
        proc = self.proc
        assert proc is not None
        if proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGINT)
        async with asyncio.timeout(30.0):
            out, err = await proc.communicate()
        try:
            report: dict[str, Any] = json.loads(out.decode().strip().splitlines()[-1])
        except (IndexError, ValueError):
            raise RuntimeError(
                f"viewer gave no report: {out!r} {err.decode(errors='replace')[-800:]}"
            ) from None
        return report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("url")
    args = ap.parse_args()
    print(json.dumps(asyncio.run(_view(args.url))), flush=True)


if __name__ == "__main__":
    main()
