"""A bare aiohttp JSON server: `python -m bench.bare PAYLOAD.json --port P`.

The baseline for the /status benchmark: one GET /status handler that serialises the
same document relayd served (a copy captured from it) with the same compact
`json.dumps` on every request, and nothing else running in its process. Prints
"ready" once listening.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from pathlib import Path
from typing import Any

from aiohttp import web


def make_app(payload: Any) -> web.Application:
    async def status(_request: web.Request) -> web.Response:
        return web.Response(
            text=json.dumps(payload, separators=(",", ":")), content_type="application/json"
        )

    app = web.Application()
    app.router.add_get("/status", status)
    return app


async def _serve(payload: Any, port: int) -> None:
    runner = web.AppRunner(make_app(payload), access_log=None)
    await runner.setup()
    await web.TCPSite(runner, "127.0.0.1", port).start()
    print("ready", flush=True)
    try:
        await asyncio.Event().wait()
    finally:
        await runner.cleanup()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.bare", description=__doc__.splitlines()[0])
    p.add_argument("payload", type=Path)
    p.add_argument("--port", type=int, required=True)
    args = p.parse_args(argv)
    payload = json.loads(args.payload.read_text(encoding="utf-8"))
    try:
        asyncio.run(_serve(payload, args.port))
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
