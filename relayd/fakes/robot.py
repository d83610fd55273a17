"""`relayd fake robot`: serve a protocol-true fake P3-AT on a pty or a loopback TCP port.

Prints the path or URL to open first, then serves until interrupted. Point
`relayd probe robot --port <it>` or a config's `[robot] port` at what it prints.
"""

from __future__ import annotations

import argparse
import asyncio
import sys

from drivers.arcos.fake import FakeRobot


def configure(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--pty", action="store_true", help="serve on a new pseudo-terminal")
    where.add_argument("--tcp", type=int, metavar="PORT", help="serve on 127.0.0.1:PORT (0 = any)")
    parser.add_argument("--link", metavar="PATH", help="with --pty: a stable symlink to the pty")
    parser.add_argument("--name", default="relay", help="robot name answered to SYNC2")
    parser.add_argument("--class", dest="robot_class", default="Pioneer", help="robot class")
    parser.add_argument(
        "--subclass", default="p3at", help="p3at (0.465 mm units) or p3at-sh (1 mm)"
    )


async def run(args: argparse.Namespace) -> int:
    if args.link and not args.pty:
        print("relayd fake robot: --link needs --pty", file=sys.stderr)
        return 2
    fake = FakeRobot(args.name, args.robot_class, args.subclass)
    try:
        where = fake.serve_pty(args.link) if args.pty else await fake.serve_tcp(args.tcp)
    except OSError as exc:
        print(f"relayd fake robot: {exc}", file=sys.stderr)
        return 1
    print(where, flush=True)
    try:
        await asyncio.Event().wait()
    finally:
        await fake.stop()
    return 0
