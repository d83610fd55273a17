"""`relayd fake pantilt`: serve a fake Maestro or SSC-32 servo controller on a pty until Ctrl-C.

Prints the device path first (the stable `--link` path if given), so a script can read
it and point `relayd probe pantilt --port` or a config's `[pantilt] port` at it.
"""

from __future__ import annotations

import argparse
import asyncio
import sys

from drivers.pantilt.fake import FakeMaestro, FakeSsc32
from drivers.transport.clock import Clock


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--protocol",
        choices=("maestro", "ssc32"),
        default="maestro",
        help="controller to play: Pololu Maestro or Lynxmotion SSC-32 (default maestro)",
    )
    parser.add_argument(
        "--link", default=None, help="also make this symlink to the pty (stable across hang-ups)"
    )
    parser.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="clock speed-up for servo slews (default 1 = real time)",
    )


async def run(args: argparse.Namespace) -> int:
    try:
        clock = Clock(args.speed)
    except ValueError as exc:
        print(f"relayd fake pantilt: {exc}", file=sys.stderr)
        return 2
    fake: FakeMaestro | FakeSsc32 = (
        FakeMaestro(clock=clock) if args.protocol == "maestro" else FakeSsc32(clock=clock)
    )
    try:
        path = fake.serve_pty(args.link)
    except OSError as exc:
        print(f"relayd fake pantilt: cannot create the pty: {exc}", file=sys.stderr)
        return 1
    print(path, flush=True)
    try:
        await asyncio.Event().wait()  # until Ctrl-C cancels us
    finally:
        fake.close()
    return 0
