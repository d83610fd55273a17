"""`relayd probe wifi`: sample the Yagi adapter's RSSI with one source, no convoy logic.

Prints one line per sample at the sample rate: with `--json` an object
`{"t", "rssi_dbm", "fresh"}` (t in seconds since the probe started), otherwise a
readable line. Exits 0 when at least one fresh sample was seen, 1 otherwise (with the
source's last error on stderr), so it doubles as a bring-up check. A missing interface,
procfs file or `iw` binary exits 1 at once, with the reason; `--seconds` bounds every run.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import shutil
import sys

from drivers.transport.clock import REAL_CLOCK
from drivers.wifi import SOURCE_KINDS, make_source
from relayd.probe import emit, warnings_to_stderr


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--source",
        choices=SOURCE_KINDS,
        default="nl80211",
        help="where the RSSI comes from (default nl80211)",
    )
    parser.add_argument(
        "--interface",
        default="yagi0",
        help="wireless interface (default yagi0, the udev rules' name)",
    )
    parser.add_argument(
        "--path", default=None, help="procfs source: the /proc/net/wireless-format file to read"
    )
    parser.add_argument("--iw", default="iw", help="iw source: the iw binary (default: on PATH)")
    parser.add_argument(
        "--seconds", type=float, default=10.0, help="how long to sample (default 10)"
    )
    parser.add_argument("--hz", type=float, default=20.0, help="sample rate (default 20)")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")


async def run(args: argparse.Namespace) -> int:
    if not args.hz > 0 or not args.seconds >= 0:
        print("relayd probe wifi: --hz must be > 0 and --seconds >= 0", file=sys.stderr)
        return 2
    if args.source == "iw" and shutil.which(args.iw) is None:
        # Every read would fail the same way: say so now, not after --seconds of "stale".
        print(
            f"relayd probe wifi: no iw binary at {args.iw!r} (install the iw package, "
            "or give its path with --iw)",
            file=sys.stderr,
        )
        return 1
    with warnings_to_stderr():
        return await _sample(args)


def _print(args: argparse.Namespace, t: float, rssi_dbm: float | None, fresh: bool) -> bool:
    """One sample on stdout; False when the reader has gone."""
    if args.json:
        return emit(json.dumps({"t": t, "rssi_dbm": rssi_dbm, "fresh": fresh}))
    level = "   --" if rssi_dbm is None else f"{rssi_dbm:5.0f}"
    return emit(f"{t:8.3f} s  {level} dBm  {'fresh' if fresh else 'stale'}")


async def _sample(args: argparse.Namespace) -> int:
    clock = REAL_CLOCK
    source = make_source(args.source, args.interface, path=args.path, clock=clock, iw_path=args.iw)
    t0 = clock.now()
    fresh_seen = 0
    printed = 0
    try:
        # A read that hangs (a stuck `iw`) must not hold the probe past --seconds.
        async with asyncio.timeout(args.seconds + 2.0):
            async for sample in source.stream(args.hz):
                t = round(sample.t - t0, 3)
                # The first sample is always shown: `--seconds 0` means one reading, even
                # when a loaded machine takes a moment to deliver it.
                if printed and t > args.seconds:
                    break
                if (
                    not source.available
                    and source.last_error is not None
                    and source.last_error.startswith("interface missing")
                ):
                    # Nothing to sample: say why at once instead of printing "stale" lines.
                    print(f"relayd probe wifi: {source.last_error}", file=sys.stderr)
                    return 1
                fresh_seen += sample.fresh
                if not _print(args, t, sample.rssi_dbm, sample.fresh):
                    return 0  # the reader took what it wanted (`| head -1`)
                printed += 1
    except TimeoutError:
        print(
            f"relayd probe wifi: {args.source} did not answer within {args.seconds:g} s",
            file=sys.stderr,
        )
        return 1
    finally:
        await source.close()
    counters = " ".join(f"{k}={v}" for k, v in source.counters.items())
    if fresh_seen == 0:
        print(
            f"relayd probe wifi: no fresh sample from {args.source} on {args.interface}"
            f" ({source.last_error or 'no update seen'}; {counters})",
            file=sys.stderr,
        )
        return 1
    if not args.json:
        print(f"# {counters}", file=sys.stderr)
    return 0
