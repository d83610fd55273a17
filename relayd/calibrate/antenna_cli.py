"""`relayd calibrate antenna`: measure the scan antenna's pattern with the robot as the turntable.

A node stands at a known bearing (`--node-bearing-deg`, robot frame; default straight
ahead) 3-15 m from a still relay that sweeps its scan servo (hold mode). From a recording
(`--from FILE`) or a running relayd (`--url`, read-only, `--sweeps` new scans) it
collects the sweeps, averages them into a pattern (relayd/calibrate/antenna.py), prints
beamwidth, front-to-back, side lobes, asymmetry and repeatability, and writes
`antenna-pattern.toml` (the `[scan] pattern_file`), `antenna-pattern.json` and
`antenna-pattern.png` into `--out`. A measurement it cannot trust (flat, too few
samples, the node too close, an unstable shape) is refused with the reasons and nothing
is written. Exit 0 on a pattern, 1 when refused or the source fails, 2 on bad options.
With `--turn-steps N` (live only, started on purpose: the robot moves) the relay turns
itself in place between sweeps to measure the back half too (calibrate/antenna_turn.py).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from datetime import UTC, datetime
from pathlib import Path

from relayd.calibrate.antenna import (
    AntennaCalibration,
    CalibrationRefused,
    measure_pattern,
    plot_pattern,
    text_report,
)
from relayd.calibrate.antenna_sources import sample_live, samples_from_recording
from relayd.calibrate.antenna_turn import MAX_TURN_MM_S, TurnOptions, sample_turning
from relayd.calibrate.sources import SourceError
from relayd.cli.argtypes import positive_float
from relayd.core.scan.pattern import pattern_toml


def _bearing(text: str) -> float:
    value = float(text)
    if not -180.0 <= value <= 180.0:
        raise argparse.ArgumentTypeError(f"must be within -180..180, got {text}")
    return value


def configure(parser: argparse.ArgumentParser) -> None:
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--from", dest="from_file", metavar="FILE", help="a relayd recording (.mcap)")
    src.add_argument(
        "--url", help="a running relayd's API (e.g. http://192.168.1.31:8080): live sweeps"
    )
    parser.add_argument(
        "--node-bearing-deg",
        type=_bearing,
        default=0.0,
        help="where the node stands, robot frame, counter-clockwise positive (default 0: ahead)",
    )
    parser.add_argument(
        "--distance-m",
        type=positive_float,
        help="how far away the node stands (refused under 3 m)",
    )
    parser.add_argument(
        "--name", default="", help="a name for the pattern (the antenna, the relay)"
    )
    parser.add_argument(
        "--out", type=Path, default=Path("."), help="where the .toml, .json and .png go (default .)"
    )
    live = parser.add_argument_group("live (--url)")
    live.add_argument(
        "--sweeps", type=int, default=12, help="new scans to collect (default 12, at least 4)"
    )
    live.add_argument(
        "--seconds", type=positive_float, default=120.0, help="stop after this long (default 120 s)"
    )
    turn = parser.add_argument_group("turning in place (--url; the robot moves)")
    turn.add_argument(
        "--turn-steps",
        type=int,
        default=0,
        metavar="N",
        help="turn the relay in place to N headings 360/N deg apart, --sweeps at each, to "
        "measure the back half too (manual mode through the daemon; hold at the end)",
    )
    turn.add_argument(
        "--turn-speed-mm-s",
        type=positive_float,
        default=100.0,
        help=f"wheel speed while turning (default 100, at most {MAX_TURN_MM_S:g})",
    )
    turn.add_argument(
        "--token-env",
        default="RELAYD_API_TOKEN",
        help="environment variable with the API token, for --turn-steps (default RELAYD_API_TOKEN)",
    )


def _turn_problem(args: argparse.Namespace) -> str | None:
    """Why the --turn-steps options cannot be used (None: they can, or are not asked for)."""
    if not args.turn_steps:
        return None
    if args.turn_steps < 2:
        return "--turn-steps: at least 2 headings (or 0: no turning)"
    if args.from_file is not None:
        return "--turn-steps: needs --url (a recording cannot turn the robot)"
    if args.turn_speed_mm_s > MAX_TURN_MM_S:
        return f"--turn-speed-mm-s: at most {MAX_TURN_MM_S:g}"
    if not os.environ.get(args.token_env):
        return f"--turn-steps: needs the API token in ${args.token_env}"
    return None


async def run(args: argparse.Namespace) -> int:
    if args.sweeps < 4:
        print("relayd calibrate antenna: --sweeps at least 4", file=sys.stderr)
        return 2
    if (problem := _turn_problem(args)) is not None:
        print(f"relayd calibrate antenna: {problem}", file=sys.stderr)
        return 2
    try:
        if args.from_file is not None:
            source = str(args.from_file)
            samples = samples_from_recording(source)
        elif args.turn_steps:
            source = args.url
            print(
                f"turning {args.url} in place to {args.turn_steps} headings "
                f"({args.sweeps} sweeps each); Ctrl-C stops it and leaves it in hold",
                file=sys.stderr,
            )
            opts = TurnOptions(
                url=args.url,
                token=os.environ[args.token_env],
                steps=args.turn_steps,
                sweeps_per_step=args.sweeps,
                seconds_per_step=args.seconds,
                speed_mm_s=args.turn_speed_mm_s,
            )
            samples = await sample_turning(
                opts, progress=lambda m: print(f"  {m}", file=sys.stderr)
            )
        else:
            source = args.url
            print(f"sampling {args.url} (read-only); Ctrl-C ends it", file=sys.stderr)
            samples, why = await sample_live(
                args.url,
                sweeps=args.sweeps,
                seconds=args.seconds,
                progress=lambda n: print(f"  sweep {n}", file=sys.stderr),
            )
            print(f"sampling ended: {why}; {len(samples)} samples", file=sys.stderr)
        cal = measure_pattern(
            samples,
            node_bearing_deg=args.node_bearing_deg,
            distance_m=args.distance_m,
            name=args.name or "measured",
        )
    except CalibrationRefused as exc:
        print("relayd calibrate antenna: refused, no pattern written:", file=sys.stderr)
        for reason in exc.reasons:
            print(f"  - {reason}", file=sys.stderr)
        return 1
    except SourceError as exc:
        print(f"relayd calibrate antenna: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # the robot's API unreachable
        print(f"relayd calibrate antenna: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    print(text_report(cal, source))
    written = write_outputs(args.out, cal, source, args)
    print(f"wrote {', '.join(str(w) for w in written)}")
    return 0


def write_outputs(
    out: Path, cal: AntennaCalibration, source: str, args: argparse.Namespace
) -> list[Path]:
    """antenna-pattern.toml, .json and (with matplotlib) .png in `out`."""
    out.mkdir(parents=True, exist_ok=True)
    conditions: dict[str, object] = {
        "measured_by": "relayd calibrate antenna",
        "source": source,
        "date": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "node_bearing_deg": args.node_bearing_deg,
        "distance_m": args.distance_m if args.distance_m is not None else "not given",
        "sweeps": cal.sweeps,
        "samples": cal.samples,
        "peak_dbm": round(cal.peak_dbm, 1),
        "repeat_db": round(cal.repeat_db, 2),
    }
    toml = out / "antenna-pattern.toml"
    toml.write_text(
        pattern_toml(
            cal.pattern,
            conditions,
            comment="The scan antenna's pattern: set [scan] pattern_file to this file.",
        ),
        encoding="utf-8",
    )
    doc = {
        "source": source,
        "conditions": conditions,
        "beamwidth_deg": cal.beamwidth_deg,
        "half_widths_deg": list(cal.half_widths_deg),
        "peak_off_axis_deg": cal.squint_deg,
        "front_to_back_db": cal.front_to_back_db,
        "side_lobe_db": cal.side_lobe_db,
        "repeat_db": cal.repeat_db,
        "worst_se_db": cal.worst_se_db,
        "peak_spread_deg": cal.peak_spread_deg,
        "warnings": list(cal.warnings),
        "angles_deg": list(cal.pattern.angles_deg),
        "gain_db": list(cal.pattern.gain_db_table),
    }
    js = out / "antenna-pattern.json"
    js.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    written = [toml, js]
    png = out / "antenna-pattern.png"
    if plot_pattern(cal, str(png), f"scan antenna: {source}"):
        written.append(png)
    return written
