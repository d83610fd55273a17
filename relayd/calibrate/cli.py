"""`relayd calibrate path-loss`: measure L0, n and sigma on a straight drive, print thresholds.

A robot drives (or is pushed) straight away from a stationary node. From a recording
(`--from FILE`) or from a running relayd (`--url`, read-only unless `--drive`) it
collects RSSI against odometry distance, fits the log-distance model robustly
(relayd/calibrate/fit.py), prints L0, n and sigma with confidence intervals and the
thresholds for a wanted hop length and/or hop throughput at an outage probability,
and writes `path-loss.toml` (a [control] snippet), `path-loss.json` and
`path-loss.png` into `--out`. Exit 0 on a fit, 1 when the data cannot be fitted or
the source fails, 2 on bad options.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from relayd.calibrate.fit import FitError, PathLossFit, fit_path_loss
from relayd.calibrate.report import (
    Thresholds,
    Wanted,
    config_snippet,
    plot_fit,
    text_report,
    thresholds,
)
from relayd.calibrate.sources import (
    LINKS,
    NEAR_M,
    LiveOptions,
    Reading,
    SourceError,
    readings_from_recording,
    sample_live,
)
from relayd.cli.argtypes import positive_float
from relayd.core.link.rates import RATE_TABLES

#: --drive never goes faster than this (mm/s): a calibration is a slow, watched drive.
MAX_DRIVE_MM_S = 300.0


def _outage(text: str) -> float:
    value = float(text)
    if not 0 < value < 0.5:
        raise argparse.ArgumentTypeError(f"must be in (0, 0.5), got {text}")
    return value


def configure(parser: argparse.ArgumentParser) -> None:
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--from", dest="from_file", metavar="FILE", help="a relayd recording (.mcap)")
    src.add_argument(
        "--url", help="a running relayd's API (e.g. http://192.168.1.31:8080): live readings"
    )
    parser.add_argument(
        "--link",
        choices=LINKS,
        default="rear",
        help="rear: the rear AP's RSSI^b and rates (default); front: the NanoStation's; "
        "leader: the Yagi adapter's RSSI (point the Yagi at the node)",
    )
    parser.add_argument(
        "--start-distance-m",
        type=positive_float,
        default=1.0,
        help="distance from the node where the drive starts (default 1 m)",
    )
    parser.add_argument(
        "--hop-m",
        type=positive_float,
        help="wanted hop length (or following gap for --link leader)",
    )
    parser.add_argument(
        "--target-mbps",
        type=positive_float,
        help="wanted hop throughput (Mbit/s, after MAC overhead)",
    )
    parser.add_argument(
        "--outage", type=_outage, default=0.1, help="accepted outage probability (default 0.1)"
    )
    parser.add_argument(
        "--phy",
        choices=sorted(RATE_TABLES),
        default="802.11g",
        help="the rate table for --target-mbps (default 802.11g)",
    )
    parser.add_argument("--mac-efficiency", type=positive_float, default=0.5, help="(default 0.5)")
    parser.add_argument(
        "--out", type=Path, default=Path("."), help="where the .toml, .json and .png go (default .)"
    )
    parser.add_argument("--seed", type=int, default=0, help="bootstrap seed (default 0)")
    live = parser.add_argument_group("live (--url)")
    live.add_argument(
        "--drive",
        action="store_true",
        help="drive the robot straight ahead at --speed-mm-s through the daemon's manual mode "
        "(every fail-safe applies; ends in hold). Without it: read-only, push the robot.",
    )
    live.add_argument(
        "--speed-mm-s",
        type=positive_float,
        default=150.0,
        help=f"--drive speed (default 150, at most {MAX_DRIVE_MM_S:g})",
    )
    live.add_argument(
        "--near-m",
        type=float,
        default=NEAR_M,
        help="--drive goes at a third of --speed-mm-s until this far from the node: the first "
        "metres pin L0 (default 4 m; 0: one speed)",
    )
    live.add_argument(
        "--distance-m", type=positive_float, default=20.0, help="stop after this far (default 20 m)"
    )
    live.add_argument(
        "--seconds", type=positive_float, default=180.0, help="stop after this long (default 180 s)"
    )
    live.add_argument(
        "--hz", type=positive_float, default=4.0, help="/status polls per second (default 4)"
    )
    live.add_argument(
        "--token-env",
        default="RELAYD_API_TOKEN",
        help="environment variable with the API token, for --drive (default RELAYD_API_TOKEN)",
    )


async def run(args: argparse.Namespace) -> int:
    if args.speed_mm_s > MAX_DRIVE_MM_S:
        print(f"relayd calibrate: --speed-mm-s at most {MAX_DRIVE_MM_S:g}", file=sys.stderr)
        return 2
    wanted = Wanted(
        link=args.link,
        hop_m=args.hop_m,
        target_mbps=args.target_mbps,
        outage=args.outage,
        phy=args.phy,
        mac_efficiency=args.mac_efficiency,
    )
    readings: list[Reading]
    try:
        if args.from_file is not None:
            source = str(args.from_file)
            readings = readings_from_recording(
                args.from_file, link=args.link, start_distance_m=args.start_distance_m
            )
        else:
            source = args.url
            token = os.environ.get(args.token_env) if args.drive else None
            if args.drive and not token:
                print(
                    f"relayd calibrate: --drive needs the API token in ${args.token_env}",
                    file=sys.stderr,
                )
                return 2
            opts = LiveOptions(
                url=args.url,
                link=args.link,
                start_distance_m=args.start_distance_m,
                hz=args.hz,
                seconds=args.seconds,
                distance_m=args.distance_m,
                drive=args.drive,
                speed_mm_s=args.speed_mm_s,
                token=token,
                near_m=args.near_m,
            )
            how = f"driving at {args.speed_mm_s:g} mm/s" if args.drive else "read-only"
            print(f"sampling {args.url} ({how}); Ctrl-C ends it", file=sys.stderr)
            readings, why = await sample_live(opts)
            print(f"sampling ended: {why}; {len(readings)} readings", file=sys.stderr)
        fit = fit_path_loss(
            [r.distance_m for r in readings], [r.rssi_dbm for r in readings], seed=args.seed
        )
    except (SourceError, FitError) as exc:
        # Data that give no model: a clear refusal, exit 2, and nothing written.
        print(f"relayd calibrate: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # the robot's API unreachable
        print(f"relayd calibrate: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    try:
        thr = thresholds(fit, readings, wanted)
        report = text_report(fit, thr, wanted, source)
    except (FitError, ValueError) as exc:
        print(f"relayd calibrate: {exc}", file=sys.stderr)
        return 2
    print(report)
    written = write_outputs(args.out, fit, thr, wanted, readings, source)
    print(f"wrote {', '.join(str(w) for w in written)}")
    return 0


def write_outputs(
    out: Path,
    fit: PathLossFit,
    thr: Thresholds,
    wanted: Wanted,
    readings: list[Reading],
    source: str,
) -> list[Path]:
    """path-loss.toml, path-loss.json and (with matplotlib) path-loss.png in `out`."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "path-loss.toml").write_text(config_snippet(fit, thr, wanted, source), encoding="utf-8")
    doc = {
        "source": source,
        "link": wanted.link,
        "fit": fit.to_json(),
        "thresholds": {
            "key": thr.key,
            "by_hop_length": thr.by_length,
            "by_throughput": thr.by_throughput,
            "by_measured_rate": thr.by_measured_rate,
            "bound": thr.bound,
            "chosen": thr.chosen,
        },
        "wanted": {
            "hop_m": wanted.hop_m,
            "target_mbps": wanted.target_mbps,
            "outage": wanted.outage,
            "phy": wanted.phy,
            "mac_efficiency": wanted.mac_efficiency,
        },
        "readings": len(readings),
    }
    (out / "path-loss.json").write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    written = [out / "path-loss.toml", out / "path-loss.json"]
    if plot_fit(fit, readings, thr, out / "path-loss.png", f"{wanted.link} link: {source}"):
        written.append(out / "path-loss.png")
    return written
