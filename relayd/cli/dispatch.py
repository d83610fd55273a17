"""The `relayd` command line: thin entry points over the library.

Each subcommand lives in its own module exposing `configure(parser)` and
`async def run(args) -> int` (or a synchronous `run`), imported only when used so
`relayd check-config` never pulls in aiohttp and a probe never starts the daemon.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import importlib
import inspect
import signal
import sys
from collections.abc import Coroutine, Iterator, Sequence
from typing import Any

from relayd import __version__

#: subcommand -> module implementing it
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("relayd.cli.run", "run the daemon"),
    "check-config": (
        "relayd.cli.check_config",
        "validate a config file and print the effective settings",
    ),
    "sim": ("relayd.cli.sim", "run a convoy of real relayd instances in the simulated world"),
    "sweep": ("relayd.cli.sweep", "Monte Carlo simulator runs over a grid, on a Dask cluster"),
    "status": ("relayd.cli.status", "fetch and pretty-print a robot's /status"),
    "fleet": (
        "relayd.cli.fleet",
        "serve one page for the whole chain of relays, with a hold-all button",
    ),
    "replay": (
        "relayd.cli.replay",
        "replay a recording through the brain and compare its decisions",
    ),
}
PROBES: dict[str, tuple[str, str]] = {
    "robot": ("relayd.probe.robot", "talk to a P3-AT base (read-only: never enables the motors)"),
    "pantilt": ("relayd.probe.pantilt", "move or read one servo of the pan-tilt controller"),
    "wifi": ("relayd.probe.wifi", "sample the Wi-Fi adapter's RSSI"),
    "ap": (
        "relayd.probe.ap",
        "read an airOS radio's link quality, once or for --seconds"
        " (password from RELAYD_AP_PASSWORD)",
    ),
}
FAKES: dict[str, tuple[str, str]] = {
    "robot": ("relayd.fakes.robot", "serve a protocol-true fake P3-AT on a pty or TCP port"),
    "pantilt": ("relayd.fakes.pantilt", "serve a fake Maestro or SSC-32 servo controller on a pty"),
    "ap": (
        "relayd.fakes.ap",
        "serve a fake airOS radio over HTTP on loopback"
        " (accepted password: RELAYD_AP_PASSWORD, default ubnt)",
    ),
    "rig": (
        "relayd.fakes.rig_cmd",
        "all of one relay's devices faked, with a leader; writes a config for `relayd run`. "
        "The fake world keeps its state while it serves: a second run finds the robot where "
        "the first left it",
    ),
}


CALIBRATIONS: dict[str, tuple[str, str]] = {
    "path-loss": (
        "relayd.calibrate.cli",
        "fit L0, n and sigma on a straight drive away from a node; print thresholds",
    ),
    "antenna": (
        "relayd.calibrate.antenna_cli",
        "measure the scan antenna's pattern from sweeps of a still node; write the pattern file",
    ),
}


class CommandParser(argparse.ArgumentParser):
    """A subcommand's parser that lets its module add the options the first time it parses.

    The module is imported only when its subcommand is on the command line, so
    `relayd check-config` never pulls in aiohttp, yet `relayd run --help` lists every
    option of `run` (the options exist before argparse looks at `--help`). A leaf
    command rejects unknown options itself, so the error shows its own usage, not
    the top-level one.
    """

    def __init__(self, *args: Any, module: str | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.module = module
        self._configured = module is None

    def configure(self) -> None:
        if not self._configured and self.module is not None:
            self._configured = True
            importlib.import_module(self.module).configure(self)

    def is_leaf(self) -> bool:
        return self.module is not None

    def parse_known_args(  # type: ignore[override]
        self,
        args: Sequence[str] | None = None,
        namespace: argparse.Namespace | None = None,
    ) -> tuple[argparse.Namespace, list[str]]:
        self.configure()
        ns, extras = super().parse_known_args(args, namespace)
        if extras and self.is_leaf():
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return ns, extras


def _add_group(
    sub: argparse._SubParsersAction[CommandParser], table: dict[str, tuple[str, str]]
) -> None:
    for name, (module, help_text) in table.items():
        p = sub.add_parser(name, help=help_text, description=help_text, module=module)
        p.set_defaults(_module=module)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="relayd", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"relayd {__version__}")
    sub = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=CommandParser
    )
    _add_group(sub, COMMANDS)
    probe = sub.add_parser("probe", help="bring-up tools, one device at a time")
    _add_group(
        probe.add_subparsers(
            dest="device", required=True, metavar="DEVICE", parser_class=CommandParser
        ),
        PROBES,
    )
    calibrate = sub.add_parser("calibrate", help="guided bring-up measurements")
    _add_group(
        calibrate.add_subparsers(
            dest="what", required=True, metavar="WHAT", parser_class=CommandParser
        ),
        CALIBRATIONS,
    )
    fake = sub.add_parser("fake", help="serve a fake device for trying relayd without hardware")
    _add_group(
        fake.add_subparsers(
            dest="device", required=True, metavar="DEVICE", parser_class=CommandParser
        ),
        FAKES,
    )
    return parser


def command_tree(
    parser: argparse.ArgumentParser | None = None, prefix: tuple[str, ...] = ()
) -> list[tuple[tuple[str, ...], CommandParser]]:
    """Every leaf subcommand (`("probe", "wifi")`, ...) with its parser, found by walking the parser."""
    parser = parser or build_parser()
    out: list[tuple[tuple[str, ...], CommandParser]] = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                if isinstance(child, CommandParser) and child.is_leaf():
                    out.append(((*prefix, name), child))
                else:
                    out.extend(command_tree(child, (*prefix, name)))
    return out


def _keep_rich_out() -> None:
    """Stop structlog from importing rich (and pygments) into a relayd process.

    relayd never renders with rich: its console logs use plain tracebacks and its JSON
    logs drop the frames' locals (relayd.runtime.logsetup). structlog imports rich anyway when
    it is installed, as it is in a development install (schemathesis needs it), which
    costs the daemon about 3 MB of resident memory. A `None` entry in sys.modules makes
    `import rich` fail the way a missing package does, which structlog handles. Only a
    process that relayd's own command line started, before structlog is loaded: never
    a process (a test run) that imported relayd as a library.
    """
    if "structlog" not in sys.modules and "rich" not in sys.modules:
        sys.modules["rich"] = None  # type: ignore[assignment]  # None: "not installed", by design


def main(argv: Sequence[str] | None = None) -> int:
    # Ctrl-C before a command has its own handlers (while the imports and the config load,
    # the first 0.2 s) is the shell's 130 too, without a traceback. While the command's
    # modules are imported it is only noted: a KeyboardInterrupt raised inside a class
    # body's __set_name__ (pydantic's) comes out as a RuntimeError no handler expects.
    try:
        interrupted: list[int] = []
        with _interrupts_noted(interrupted):
            args, runner = _prepare(argv)
        if interrupted:
            return 130
        return _run(args, runner)
    except KeyboardInterrupt:
        return 130


@contextlib.contextmanager
def _interrupts_noted(into: list[int]) -> Iterator[None]:
    """SIGINT appends to `into` instead of raising, for the block (main thread only)."""
    try:
        previous = signal.signal(signal.SIGINT, lambda signum, _frame: into.append(signum))
    except ValueError:  # not the main thread: nothing to defer
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _prepare(argv: Sequence[str] | None) -> tuple[argparse.Namespace, Any]:
    if argv is None:
        _keep_rich_out()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    runner = importlib.import_module(args._module).run
    # Probes and tools print data on stdout: their logs go to stderr. `run` and `sim`
    # configure their own logging from the config.
    from relayd.runtime.logsetup import StdStream, setup_logging

    setup_logging("info", "console", stream=StdStream("stderr"))
    return args, runner


def _run(args: argparse.Namespace, runner: Any) -> int:
    code = (
        asyncio.run(until_signal(runner(args)))
        if inspect.iscoroutinefunction(runner)
        else runner(args)
    )
    return int(code or 0)


async def until_signal(command: Coroutine[Any, Any, int | None]) -> int | None:
    """Run an async command; SIGTERM or SIGINT cancels it so its `finally` cleans up.

    Without this SIGTERM kills a fake outright and leaves its pty symlinks behind.
    SIGTERM is a normal stop (exit 0), Ctrl-C keeps the shell's 130. `relayd run`
    installs its own handlers for every catchable fatal signal, which replace these;
    `relayd sim`, which picks its own event loop, runs its command through this.
    """
    loop = asyncio.get_running_loop()
    task = asyncio.ensure_future(command)
    received: list[signal.Signals] = []

    def _stop(sig: signal.Signals) -> None:
        received.append(sig)
        task.cancel()

    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, _stop, sig)
    try:
        return await task
    except asyncio.CancelledError:
        if not received:
            raise
        return 130 if received[0] == signal.SIGINT else 0
    finally:
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.remove_signal_handler(sig)


if __name__ == "__main__":
    sys.exit(main())
