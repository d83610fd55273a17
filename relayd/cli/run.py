"""`relayd run [-c FILE]`: the daemon, as systemd starts it."""

from __future__ import annotations

import argparse
import asyncio
import gc
import os
import signal
import sys

import structlog

from relayd.config.load import DEFAULT_CONFIG_PATH, config_warnings, load_settings
from relayd.config.model import ConfigError
from relayd.runtime.logsetup import setup_logging


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "-c",
        "--config",
        default=str(DEFAULT_CONFIG_PATH),
        help=f"TOML config (default {DEFAULT_CONFIG_PATH})",
    )
    parser.add_argument(
        "--log-format", choices=["json", "console"], default=None, help="override log.format"
    )
    parser.add_argument(
        "--record",
        metavar="PATH",
        default=None,
        help="record this run to MCAP: a directory (one file per run) or a file ending "
        "in .mcap; turns [record] on with this path (docs/RECORDING.md)",
    )


#: The signals that end relayd with the safe stop (wheels 0, ENABLE 0, CLOSE), as SIGTERM does:
#: every signal whose default action ends the process and that a handler can catch. Left out:
#: SIGPIPE and SIGXFSZ, which Python ignores (a closed log pipe or a full disk gives an error
#: on that write, and the robot keeps its control loop); the synchronous faults (SIGSEGV,
#: SIGBUS, SIGFPE, SIGILL, SIGABRT, SIGTRAP, SIGSYS), after which the interpreter itself is in
#: doubt; SIGKILL and SIGSTOP, which no process can catch. For those the P3-AT's own
#: watchdog stops the wheels (docs/DEPLOY.md, "Signals").
STOP_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name)
    for name in (
        "SIGTERM",
        "SIGINT",
        "SIGHUP",
        "SIGQUIT",
        "SIGUSR1",
        "SIGUSR2",
        "SIGALRM",
        "SIGVTALRM",
        "SIGPROF",
        "SIGXCPU",
        "SIGIO",
        "SIGPWR",
    )
    if hasattr(signal, name)
)


def exit_code(sig: signal.Signals) -> int:
    """SIGTERM is systemd's normal stop (0); any other signal the shell's 128 + its number."""
    return 0 if sig == signal.SIGTERM else 128 + int(sig)


def _config_error(path: str, exc: ConfigError) -> int:
    print(f"{path}: {len(exc.errors)} error(s)", file=sys.stderr)
    for line in exc.errors:
        print(f"  {line}", file=sys.stderr)
    return 2


async def run(args: argparse.Namespace) -> int:
    main = asyncio.current_task()
    if main is None:
        raise RuntimeError("relayd run must be called from a task")
    loop = asyncio.get_running_loop()
    received: list[signal.Signals] = []

    def _stop(sig: signal.Signals) -> None:
        # Cancel once: a second signal (Ctrl-C twice, SIGHUP then SIGTERM) must not
        # interrupt the safe stop the first one started.
        received.append(sig)
        if len(received) == 1:
            main.cancel()
        structlog.get_logger("relayd").info("signal", signal=sig.name, stopping=len(received) == 1)

    # Before anything else: a signal while the config loads must stop us quietly, and one
    # while driving must end in the safe stop, whichever catchable signal it is.
    for sig in STOP_SIGNALS:
        loop.add_signal_handler(sig, _stop, sig)
    try:
        return await _run(args)
    except asyncio.CancelledError:
        if not received:
            raise
        main.uncancel()
        return exit_code(received[0])


async def _run(args: argparse.Namespace) -> int:
    try:
        settings = load_settings(args.config)
    except ConfigError as exc:
        return _config_error(args.config, exc)
    if args.record is not None:
        settings = settings.model_copy(
            update={
                "record": settings.record.model_copy(update={"enabled": True, "path": args.record})
            }
        )
    setup_logging(settings.log.level, args.log_format or settings.log.format)
    from relayd.daemon import Daemon
    from relayd.runtime.sdnotify import SdNotifier

    try:
        daemon = Daemon(settings, env=os.environ, notifier=SdNotifier())
    except ConfigError as exc:
        return _config_error(args.config, exc)
    log = structlog.get_logger("relayd")
    for warning in config_warnings(settings):
        log.warning("config_warning", problem=warning)
    log.info(
        "starting", config=args.config, robot=settings.robot.port, pantilt=settings.pantilt.port
    )
    # Modules, config and drivers live as long as the process: moved out of the cyclic
    # collector's generations, they are not rescanned by full collections, which would
    # otherwise land as multi-millisecond pauses in the SIP -> wheel command path.
    gc.freeze()
    try:
        await daemon.run()
    except ConfigError as exc:
        # Found only at start (a device locked, the API cannot bind): no device was touched.
        return _config_error(args.config, exc)
    except Exception:
        # The daemon's own `finally` has already stopped the robot (wheels 0, ENABLE 0, CLOSE).
        log.exception("crashed")
        return 1
    return 0
