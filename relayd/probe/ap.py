"""`relayd probe ap`: log in to one airOS radio and print its link quality.

Once by default; with `--seconds S` a reading every `--interval` seconds for S seconds
(one line each, with `t` since the start) and the median signal on stderr at the end:
the path-loss measurement in docs/DEPLOY.md takes about 30 s per distance.

The password comes from the environment (`RELAYD_AP_PASSWORD`), never from the command
line where `ps` would show it. With `--json` the line is
`{"signal_dbm","rssi","noise_dbm","ccq_pct","tx_mbps","rx_mbps","stations":[...], ...}`.
Exit codes: 0 read (at least once), 1 the radio could not be read (reason on stderr),
2 usage error (no password in the environment, bad URL, bad --seconds/--interval).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import statistics
import sys

from drivers.airos import AirOsAuthError, AirOsClient, AirOsError, LinkQuality
from drivers.airos.client import Firmware
from relayd.probe import emit, warnings_to_stderr

PASSWORD_ENV = "RELAYD_AP_PASSWORD"
FIRMWARES: dict[str, Firmware] = {"auto": "auto", "6": 6, "8": 8}


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--url", required=True, help="the radio, e.g. http://192.168.1.21")
    parser.add_argument("--username", default="ubnt", help="login name (default ubnt)")
    parser.add_argument(
        "--legacy-tls",
        action="store_true",
        help="allow TLS 1.0 / legacy ciphers (airOS 6 over https)",
    )
    parser.add_argument(
        "--firmware",
        choices=("auto", "6", "8"),
        default="auto",
        help="login flow: airOS 5/6 form, airOS 8 /api/auth, or try both",
    )
    parser.add_argument(
        "--timeout", type=float, default=5.0, help="per-request timeout in seconds (default 5)"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object per reading")
    parser.add_argument(
        "--seconds",
        type=float,
        default=0.0,
        help="keep reading for this long (default 0: one reading)",
    )
    parser.add_argument(
        "--interval",
        type=float,
        default=1.0,
        help="seconds between readings with --seconds (default 1)",
    )


def _human(q: LinkQuality) -> str:
    def v(x: float | None, unit: str) -> str:
        return "--" if x is None else f"{x:g} {unit}"

    lines = [
        f"radio    {q.hostname or '?'}  mode={q.mode or '?'}  essid={q.essid or '?'}",
        f"signal   {v(q.signal_dbm, 'dBm')}  (rssi {v(q.rssi, '').strip()})  noise {v(q.noise_dbm, 'dBm')}",
        f"ccq      {v(q.ccq_pct, '%')}  tx {v(q.tx_mbps, 'Mbit/s')}  rx {v(q.rx_mbps, 'Mbit/s')}",
    ]
    for s in q.stations:
        lines.append(
            f"station  {s.mac or '?'}  {v(s.signal_dbm, 'dBm')}  ccq {v(s.ccq_pct, '%')}"
            f"  tx {v(s.tx_mbps, 'Mbit/s')}  rx {v(s.rx_mbps, 'Mbit/s')}"
        )
    return "\n".join(lines)


async def run(args: argparse.Namespace) -> int:
    if not (
        math.isfinite(args.seconds)
        and args.seconds >= 0
        and math.isfinite(args.interval)
        and args.interval > 0
    ):
        print("relayd probe ap: --seconds must be >= 0 and --interval > 0", file=sys.stderr)
        return 2
    password = os.environ.get(PASSWORD_ENV)
    if password is None:
        print(f"relayd probe ap: set {PASSWORD_ENV} to the radio's password", file=sys.stderr)
        return 2
    firmware = FIRMWARES[args.firmware]
    try:
        client = AirOsClient(
            args.url,
            args.username,
            password,
            firmware=firmware,
            legacy_tls=args.legacy_tls,
            timeout_s=args.timeout,
        )
    except ValueError as exc:
        print(f"relayd probe ap: {exc}", file=sys.stderr)
        return 2
    with warnings_to_stderr():
        try:
            return await _readings(args, client)
        finally:
            await client.close()


async def _readings(args: argparse.Namespace, client: AirOsClient) -> int:
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    series = args.seconds > 0
    signals: list[float] = []
    read = 0
    while True:
        t = loop.time() - t0
        try:
            quality = await client.fetch()
        except AirOsAuthError as exc:
            print(f"relayd probe ap: {exc}: wrong username or password", file=sys.stderr)
            return 1
        except AirOsError as exc:
            print(f"relayd probe ap: {args.url}: {exc}", file=sys.stderr)
            if not series:
                return 1
        else:
            read += 1
            if quality.signal_dbm is not None:
                signals.append(quality.signal_dbm)
            if not _show(args, quality, round(t, 3) if series else None):
                return 0  # the reader took what it wanted (`| head -1`)
        next_t = t + args.interval
        if not series or next_t > args.seconds:
            break
        await asyncio.sleep(max(0.0, t0 + next_t - loop.time()))
    if series:
        median = (
            f"median signal {statistics.median(signals):g} dBm" if signals else "no signal reading"
        )
        print(f"# {read} reading(s) in {args.seconds:g} s, {median}", file=sys.stderr)
    return 0 if read else 1


def _show(args: argparse.Namespace, quality: LinkQuality, t: float | None) -> bool:
    """One reading on stdout; False when the reader has gone."""
    if args.json:
        doc = quality.to_json()
        return emit(json.dumps(doc if t is None else {"t": t, **doc}))
    if t is None:
        return emit(_human(quality))
    return emit(f"{t:8.3f} s  " + _human(quality).replace("\n", "\n            "))
