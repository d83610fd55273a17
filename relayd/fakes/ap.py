"""`relayd fake ap`: serve a fake airOS radio (FakeAirOs) on loopback until Ctrl-C.

Prints the base URL first, so a script can read it and point `relayd probe ap` or a
config's `[ap.*] url` at it. The accepted password comes from `RELAYD_AP_PASSWORD`
(default "ubnt", the radios' factory password).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys

from drivers.airos.fake import FakeAirOs

PASSWORD_ENV = "RELAYD_AP_PASSWORD"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--fixture",
        default=None,
        help="a status.cgi JSON capture to serve (default: built-in loco M5 station)",
    )
    parser.add_argument("--port", type=int, default=0, help="TCP port (default: any free port)")
    parser.add_argument(
        "--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)"
    )
    parser.add_argument(
        "--version",
        type=int,
        choices=(6, 8),
        default=6,
        help="login flow to speak: airOS 6 form or airOS 8 /api/auth (default 6)",
    )
    parser.add_argument("--username", default="ubnt", help="accepted login name (default ubnt)")


async def run(args: argparse.Namespace) -> int:
    password = os.environ.get(PASSWORD_ENV, "ubnt")
    try:
        fake = FakeAirOs(
            args.username,
            password,
            fixture=args.fixture,
            version=args.version,
            host=args.host,
            port=args.port,
        )
    except (OSError, ValueError) as exc:
        print(f"relayd fake ap: {exc}", file=sys.stderr)
        return 2
    try:
        url = await fake.start()
    except OSError as exc:
        print(f"relayd fake ap: cannot listen on {args.host}:{args.port}: {exc}", file=sys.stderr)
        return 1
    print(url, flush=True)
    try:
        await asyncio.Event().wait()  # until Ctrl-C cancels us
    finally:
        await fake.stop()
    return 0
