"""`relayd fleet`: the whole chain on one page, served at the command center.

    relayd fleet --relay http://192.168.1.31:8080 --relay relay2=http://192.168.1.32:8080
    relayd fleet -c /etc/relayd/fleet.toml

Relays come from `--relay URL` or `--relay NAME=URL` (repeatable, in chain order,
nearest the leader first) and/or the `[fleet]` section of a config file (see
relayd.fleet.config), which also gives each relay its own token for hold-all and
its odometry origin on the map. `--token-file` gives the `--relay` relays a token.
Prints the page's URL once it listens; runs until Ctrl-C. Exit 2 on a bad config.
"""

from __future__ import annotations

import argparse
import asyncio
import ipaddress
import sys
from dataclasses import replace

from relayd.fleet.config import DEFAULT_PORT, FleetSettings, load_fleet, relay_from_arg


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--relay",
        action="append",
        default=[],
        metavar="[NAME=]URL",
        help="a relay's API base URL, repeatable, in chain order from the leader",
    )
    parser.add_argument("-c", "--config", help="a TOML file with a [fleet] section")
    parser.add_argument(
        "--token-file", help="file holding the API token of the --relay relays (for hold-all)"
    )
    parser.add_argument(
        "--bind", default=None, help="address of the fleet page (default 127.0.0.1)"
    )
    parser.add_argument(
        "--allowed-host",
        action="append",
        default=[],
        metavar="NAME",
        help="a name (beyond IP addresses and localhost) the page may be reached by; repeatable",
    )
    parser.add_argument(
        "--port",
        type=int,
        default=None,
        help=f"port of the fleet page (default {DEFAULT_PORT}; 0 = any free port)",
    )
    parser.add_argument(
        "--poll-s",
        type=float,
        default=None,
        help="seconds between polls of each relay (default 0.5)",
    )
    parser.add_argument(
        "--timeout-s",
        type=float,
        default=None,
        help="seconds a relay may take to answer before it is shown as not answering (default 1)",
    )


def settings_from_args(args: argparse.Namespace) -> FleetSettings:
    """Config file first, then --relay entries appended, then the command-line overrides."""
    from relayd.config.model import ConfigError, SecretRef, resolve_secret

    settings = load_fleet(args.config) if args.config else FleetSettings(relays=())
    token = None
    if args.token_file:
        token = resolve_secret(SecretRef("--token-file", None, args.token_file), {})
    extra = tuple(relay_from_arg(text, token) for text in args.relay)
    names = [r.name for r in (*settings.relays, *extra)]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ConfigError([f"--relay: two relays are named {n!r} (use NAME=URL)" for n in dupes])
    overrides = {
        k: v
        for k, v in (
            ("bind", args.bind),
            ("port", args.port),
            ("poll_s", args.poll_s),
            ("timeout_s", args.timeout_s),
        )
        if v is not None
    }
    for key in ("poll_s", "timeout_s"):
        if key in overrides and not overrides[key] > 0:
            raise ConfigError([f"--{key.replace('_', '-')}: must be > 0"])
    settings = replace(
        settings,
        relays=settings.relays + extra,
        allowed_hosts=settings.allowed_hosts + tuple(args.allowed_host),
        **overrides,
    )
    if not settings.relays:
        raise ConfigError(["no relays: give --relay URL or a config with [[fleet.relay]] entries"])
    return settings


async def serve(
    settings: FleetSettings, ready: asyncio.Event | None = None, port_box: list[int] | None = None
) -> None:
    from relayd.api.app import start_api
    from relayd.fleet.server import make_fleet_app

    runner, port = await start_api(make_fleet_app(settings), settings.bind, settings.port)
    try:
        print(
            f"relayd fleet: {len(settings.relays)} relay(s), page at http://{settings.bind}:{port}/",
            flush=True,
        )
        if port_box is not None:
            port_box.append(port)
        if ready is not None:
            ready.set()
        await asyncio.Event().wait()
    finally:
        await runner.cleanup()


async def run(args: argparse.Namespace) -> int:
    from relayd.config.model import ConfigError

    try:
        settings = settings_from_args(args)
    except ConfigError as exc:
        print(f"relayd fleet: {len(exc.errors)} error(s)", file=sys.stderr)
        for line in exc.errors:
            print(f"  {line}", file=sys.stderr)
        return 2
    for line in bind_warnings(settings.bind):
        print(f"relayd fleet: warning: {line}", file=sys.stderr)
    await serve(settings)
    return 0


def bind_warnings(bind: str) -> list[str]:
    """The page's hold-all needs no token (a stop never does): bound beyond loopback,
    anyone who reaches this machine can stop every relay. Say so."""
    try:
        loopback = ipaddress.ip_address(bind).is_loopback
    except ValueError:
        loopback = bind == "localhost"
    if loopback:
        return []
    return [
        f"--bind {bind}: the fleet page is open beyond this machine, and its hold-all "
        "(POST /api/hold-all, no token) stops every relay for anyone who can reach it "
        "(the whole bridge with 0.0.0.0); bind 127.0.0.1 and use `ssh -L` unless that is meant"
    ]
