"""The `relayd` command line: thin entry points over the library.

Each subcommand lives in its own module exposing `configure(parser)` and
`async def run(args) -> int` (or a synchronous `run`), imported only when used so
`relayd check-config` never pulls in aiohttp and a probe never starts the daemon.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib
import inspect
import sys
from collections.abc import Sequence

from relayd import __version__

#: subcommand -> module implementing it
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("relayd.commands.run", "run the daemon"),
    "check-config": ("relayd.commands.check_config", "validate a config file and print the effective settings"),
    "sim": ("relayd.commands.sim", "run a convoy of real relayd instances in the simulated world"),
    "sweep": ("relayd.commands.sweep", "Monte Carlo simulator runs over a grid, on a Dask cluster"),
    "status": ("relayd.commands.status", "fetch and pretty-print a robot's /status"),
}
PROBES: dict[str, tuple[str, str]] = {
    "robot": ("relayd.probe.robot", "talk to a P3-AT base (read-only: never enables the motors)"),
    "pantilt": ("relayd.probe.pantilt", "move or read one servo of the pan-tilt controller"),
    "wifi": ("relayd.probe.wifi", "sample the Wi-Fi adapter's RSSI"),
    "ap": ("relayd.probe.ap", "read an airOS radio's link quality once"),
}
FAKES: dict[str, tuple[str, str]] = {
    "robot": ("relayd.fakes.robot", "serve a protocol-true fake P3-AT on a pty or TCP port"),
    "pantilt": ("relayd.fakes.pantilt", "serve a fake Maestro or SSC-32 servo controller on a pty"),
    "ap": ("relayd.fakes.ap", "serve a fake airOS radio over HTTP on loopback"),
    "rig": ("relayd.fakes.rig_cmd", "all of one relay's devices faked, with a leader; writes a config for `relayd run`"),
}


def _add_group(sub: argparse._SubParsersAction[argparse.ArgumentParser],
               table: dict[str, tuple[str, str]]) -> None:
    for name, (module, help_text) in table.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        # configure() is looked up lazily in main(): record the parser for it.
        p.set_defaults(_parser=p)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="relayd", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"relayd {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_group(sub, COMMANDS)
    probe = sub.add_parser("probe", help="bring-up tools, one device at a time")
    _add_group(probe.add_subparsers(dest="device", required=True, metavar="DEVICE"), PROBES)
    fake = sub.add_parser("fake", help="serve a fake device for trying relayd without hardware")
    _add_group(fake.add_subparsers(dest="device", required=True, metavar="DEVICE"), FAKES)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    # Two passes: find the subcommand, let its module add its own options, parse again.
    known, _ = parser.parse_known_args(argv)
    module = importlib.import_module(known._module)
    module.configure(known._parser)
    args = parser.parse_args(argv)
    runner = module.run
    # Probes and tools print data on stdout: their logs go to stderr. `run` and `sim`
    # configure their own logging from the config.
    from relayd.logsetup import StdStream, setup_logging

    setup_logging("info", "console", stream=StdStream("stderr"))
    try:
        code = asyncio.run(runner(args)) if inspect.iscoroutinefunction(runner) else runner(args)
    except KeyboardInterrupt:
        code = 130
    return int(code or 0)


if __name__ == "__main__":
    sys.exit(main())
