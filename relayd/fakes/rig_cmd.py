"""`relayd fake rig`: every device of one relay, faked, with a leader to follow.

Starts a fake P3-AT and a fake Maestro on pseudo-terminals, an RSSI file the Yagi
"hears" a leader through, and two fake airOS radios on loopback, then writes a
config for them and prints its path. `relayd run -c <that path>` in another terminal
is then a whole relay running on this machine, no hardware needed: it sweeps the fake
servo, finds the leader, and drives the fake robot towards it. Serves until Ctrl-C.

The fake world keeps its state while it serves, as a real robot would: a second
`relayd run` finds the robot where the first one left it (near the leader, so it starts
in leader_near). Restart `relayd fake rig` to start over from 0,0.
"""

from __future__ import annotations

import argparse
import asyncio
import shutil
import sys
import tempfile
from pathlib import Path

from relayd.fakes.rig import FakeRig


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--dir",
        type=Path,
        default=None,
        help="where to put the pty links, RSSI file, secrets and config (default: a temp dir)",
    )
    parser.add_argument(
        "--leader",
        type=float,
        nargs=2,
        default=(6.0, 2.0),
        metavar=("X_M", "Y_M"),
        help="the leader's position on the floor, robot starts at 0,0 facing +x (default: 6 2)",
    )
    parser.add_argument(
        "--rear-dbm",
        type=float,
        default=-55.0,
        help="RSSI^b the rear radio reports (default: -55)",
    )
    parser.add_argument(
        "--api-bind",
        default="127.0.0.1",
        help="[api] bind in the written config (default: 127.0.0.1)",
    )
    parser.add_argument(
        "--api-port",
        type=int,
        default=8080,
        help="[api] port in the written config (default: 8080)",
    )


async def run(args: argparse.Namespace) -> int:
    work = args.dir or Path(tempfile.mkdtemp(prefix="relayd-rig-"))
    rig = FakeRig(work, leader_xy_m=tuple(args.leader), rear_signal_dbm=args.rear_dbm)
    try:
        await rig.start()
        path = rig.write_config(
            secrets_in_files=True, api_bind=args.api_bind, api_port=args.api_port
        )
        print(path, flush=True)
        print(
            "the fake world keeps its state while it serves: a second `relayd run` finds the "
            "robot where the first left it; restart this command to start over",
            file=sys.stderr,
            flush=True,
        )
        await asyncio.Event().wait()
    finally:
        # SIGTERM or Ctrl-C: the pty links go with the ptys (a stale link would point a
        # later `relayd run` at whatever pty number the kernel hands out next). A temp
        # dir we made goes entirely; a --dir the user named keeps its config and secrets.
        await rig.stop()
        if args.dir is None:
            shutil.rmtree(work, ignore_errors=True)
    return 0
