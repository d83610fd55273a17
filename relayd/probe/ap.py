"""`relayd probe ap`: log in to one airOS radio and print its link quality once.

The password comes from the environment (`RELAYD_AP_PASSWORD`), never from the command
line where `ps` would show it. With `--json` the line is
`{"signal_dbm","rssi","noise_dbm","ccq_pct","tx_mbps","rx_mbps","stations":[...], ...}`.
Exit codes: 0 read, 1 the radio could not be read (reason on stderr), 2 usage error
(no password in the environment, bad URL).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from drivers.airos import AirOsAuthError, AirOsClient, AirOsError, LinkQuality
from drivers.airos.client import Firmware
from relayd.probe import warnings_to_stderr

PASSWORD_ENV = "RELAYD_AP_PASSWORD"
FIRMWARES: dict[str, Firmware] = {"auto": "auto", "6": 6, "8": 8}


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--url", required=True, help="the radio, e.g. http://192.168.1.21")
    parser.add_argument("--username", default="ubnt", help="login name (default ubnt)")
    parser.add_argument("--legacy-tls", action="store_true",
                        help="allow TLS 1.0 / legacy ciphers (airOS 6 over https)")
    parser.add_argument("--firmware", choices=("auto", "6", "8"), default="auto",
                        help="login flow: airOS 5/6 form, airOS 8 /api/auth, or try both")
    parser.add_argument("--timeout", type=float, default=5.0,
                        help="per-request timeout in seconds (default 5)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _human(q: LinkQuality) -> str:
    def v(x: float | None, unit: str) -> str:
        return "--" if x is None else f"{x:g} {unit}"

    lines = [
        f"radio    {q.hostname or '?'}  mode={q.mode or '?'}  essid={q.essid or '?'}",
        f"signal   {v(q.signal_dbm, 'dBm')}  (rssi {v(q.rssi, '').strip()})  noise {v(q.noise_dbm, 'dBm')}",
        f"ccq      {v(q.ccq_pct, '%')}  tx {v(q.tx_mbps, 'Mbit/s')}  rx {v(q.rx_mbps, 'Mbit/s')}",
    ]
    for s in q.stations:
        lines.append(f"station  {s.mac or '?'}  {v(s.signal_dbm, 'dBm')}  ccq {v(s.ccq_pct, '%')}"
                     f"  tx {v(s.tx_mbps, 'Mbit/s')}  rx {v(s.rx_mbps, 'Mbit/s')}")
    return "\n".join(lines)


async def run(args: argparse.Namespace) -> int:
    password = os.environ.get(PASSWORD_ENV)
    if password is None:
        print(f"relayd probe ap: set {PASSWORD_ENV} to the radio's password", file=sys.stderr)
        return 2
    firmware = FIRMWARES[args.firmware]
    try:
        client = AirOsClient(args.url, args.username, password, firmware=firmware,
                             legacy_tls=args.legacy_tls, timeout_s=args.timeout)
    except ValueError as exc:
        print(f"relayd probe ap: {exc}", file=sys.stderr)
        return 2
    with warnings_to_stderr():
        try:
            quality = await client.fetch()
        except AirOsAuthError as exc:
            print(f"relayd probe ap: {exc}: wrong username or password", file=sys.stderr)
            return 1
        except AirOsError as exc:
            print(f"relayd probe ap: {args.url}: {exc}", file=sys.stderr)
            return 1
        finally:
            await client.close()
    if args.json:
        print(json.dumps(quality.to_json()), flush=True)
    else:
        print(_human(quality), flush=True)
    return 0
