"""`relayd replay FILE...`: a recording's inputs through the same brain, compared with what it did.

    relayd replay FILE [FILE...] [--json] [--set SECTION.KEY=VALUE]... [--plot DIR]
                  [--partial] [--any-version]

Several FILEs are the parts of one rotated run, in order. Exit status: 0 when the
replayed brain's actions equal the recorded ones, 1 when they diverge, 2 when a file
cannot be read (it names where it broke), was made by another relayd version
(without --any-version) or an argument is bad. A what-if (`--set`) reports how the
decisions differ and never fails on those differences.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from relayd import __version__


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "files",
        nargs="+",
        metavar="FILE",
        help="a recording (.mcap); several: one run's parts in order",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="what-if: replay with this config key changed (repeatable), e.g. control.kp=2.0",
    )
    parser.add_argument(
        "--plot",
        metavar="DIR",
        default=None,
        help="draw RSSI/bearing and the odometry path into DIR (needs matplotlib)",
    )
    parser.add_argument(
        "--partial",
        action="store_true",
        help="replay a cut file (killed daemon, full disk) up to its last complete chunk",
    )
    parser.add_argument(
        "--any-version",
        action="store_true",
        help="replay a recording made by another relayd version (differences may then be code changes)",
    )


def _fail(message: str) -> int:
    print(f"relayd replay: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    from relayd.config.load import parse_settings
    from relayd.config.model import ConfigError
    from relayd.record.codec import FORMAT
    from relayd.record.reader import RecordingError, join_parts, read_recording
    from relayd.record.replay import (
        OverrideError,
        apply_overrides,
        compare,
        make_brain,
        parse_override,
    )

    try:
        overrides = [parse_override(text) for text in args.overrides]
        parts = [read_recording(f, partial=args.partial) for f in args.files]
        rec = join_parts(parts)
    except (RecordingError, OverrideError) as exc:
        return _fail(str(exc))
    info = rec.info
    if info.format != FORMAT:
        return _fail(
            f"{rec.path}: recording format {info.format} (relayd {info.version}); "
            f"this relayd {__version__} reads format {FORMAT} only"
        )
    if info.version != __version__ and not args.any_version:
        return _fail(
            f"{rec.path} was recorded by relayd {info.version}; this is relayd {__version__}. "
            "Its decisions may differ for that reason alone: replay it with relayd "
            f"{info.version}, or pass --any-version to compare anyway"
        )
    try:
        settings = parse_settings(info.config)
    except ConfigError as exc:
        return _fail(
            f"{rec.path}: the recorded config does not validate with relayd {__version__}: "
            + "; ".join(exc.errors)
        )
    try:
        what_if_settings = apply_overrides(info.config, overrides) if overrides else None
    except OverrideError as exc:
        return _fail(f"--set: {exc}")
    if rec.broke is not None:
        print(f"relayd replay: partial: {rec.broke}", file=sys.stderr)
    result = compare(rec, make_brain(settings))

    def since_start(t: float) -> float:
        return round(t - info.clock_t0, 6)

    first = None
    if result.first is not None:
        first = {
            "t": since_start(result.first["t"]),
            "seq": result.first["seq"],
            "event": result.first["event"],
            "recorded": result.first["recorded"],
            "replayed": result.first["replayed"],
        }
    out: dict[str, Any] = {
        "file": str(rec.path),
        "files": [str(p.path) for p in parts],
        "recorded_by": info.version,
        "replayed_by": __version__,
        "robot": rec.robot,
        "complete": rec.complete,
        "broke": rec.broke,
        "dropped": int(rec.recorder["dropped"])
        if rec.recorder and "dropped" in rec.recorder
        else None,
        "events": result.events,
        "actions": result.actions,
        "divergences": result.divergences,
        "first_divergence": first,
    }
    if what_if_settings is not None:
        w = compare(rec, make_brain(what_if_settings))
        out["what_if"] = {
            "set": {k: v for k, v in overrides},
            "differences": w.divergences,
            "first_t": None if w.first is None else since_start(w.first["t"]),
            "max_wheel_diff_mm_s": round(w.max_wheel_diff_mm_s, 3),
            "max_bearing_diff_deg": round(w.max_bearing_diff_deg, 3),
        }
    if args.plot is not None:
        from relayd.cli.replay_plots import plot_recording
        from relayd.sim import plots as sim_plots

        if not sim_plots.available():
            return _fail("--plot needs matplotlib (pip install 'relayd[sim]')")
        out["plots"] = [str(p) for p in plot_recording(rec, Path(args.plot))]
    if args.json:
        # Strict JSON: a time the recording left empty (null, read as NaN) is null here too.
        print(json.dumps(finite(out), indent=2, allow_nan=False))
    else:
        print(_human(out))
    return 0 if result.divergences == 0 else 1


def finite(node: Any) -> Any:
    """`node` with every NaN or infinity replaced by None (JSON has no such numbers)."""
    if isinstance(node, float):
        return node if math.isfinite(node) else None
    if isinstance(node, dict):
        return {k: finite(v) for k, v in node.items()}
    if isinstance(node, list | tuple):
        return [finite(v) for v in node]
    return node


def _human(o: dict[str, Any]) -> str:
    robot = o["robot"]
    who = (
        f"{robot['name']} ({robot['robot_class']} {robot['subclass']})"
        if robot
        else "an unidentified robot"
    )
    lines = [
        f"{o['file']}: relayd {o['recorded_by']} recording of {who}: {o['events']} events, "
        f"{o['actions']} actions" + ("" if o["complete"] else " (file not finished)")
    ]
    if o["dropped"]:
        lines.append(
            f"  the recorder lost {o['dropped']} event(s): divergences after a gap are expected"
        )
    f = o["first_divergence"]
    if f is None:
        lines.append("  replay: no divergence: the brain decides exactly as recorded")
    else:
        lines.append(
            f"  replay: {o['divergences']} divergence(s); the first at t={f['t']:.3f} s ({f['event']} #{f['seq']})"
        )
        lines.append(f"    recorded: {json.dumps(f['recorded'])}")
        lines.append(f"    replayed: {json.dumps(f['replayed'])}")
    w = o.get("what_if")
    if w is not None:
        sets = ", ".join(f"{k}={v}" for k, v in w["set"].items())
        if w["differences"] == 0:
            lines.append(f"  what-if {sets}: no decision differs")
        else:
            lines.append(
                f"  what-if {sets}: {w['differences']} of {o['events']} steps decide differently, the first "
                f"at t={w['first_t']:.3f} s; largest wheel-speed difference {w['max_wheel_diff_mm_s']:.1f} mm/s, "
                f"largest bearing difference {w['max_bearing_diff_deg']:.1f} deg"
            )
    for p in o.get("plots", []):
        lines.append(f"  plot: {p}")
    return "\n".join(lines)
