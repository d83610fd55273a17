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


def _config_error(path: str, exc: ConfigError) -> int:
    print(f"{path}: {len(exc.errors)} error(s)", file=sys.stderr)
    for line in exc.errors:
        print(f"  {line}", file=sys.stderr)
    return 2


async def run(args: argparse.Namespace) -> int:
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
    main = asyncio.current_task()
    if main is None:
        raise RuntimeError("relayd run must be called from a task")
    loop = asyncio.get_running_loop()
    task = asyncio.create_task(daemon.run(), name="relayd:daemon")

    def _stop(signame: str) -> None:
        log.info("signal", signal=signame)
        task.cancel()

    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, _stop, sig.name)
    try:
        await task
    except asyncio.CancelledError:
        pass
    except ConfigError as exc:
        # Found only at start (the API cannot bind): the devices were never touched.
        return _config_error(args.config, exc)
    return 0
