"""The uncalibrated lobe fit over a class of symmetric main lobes, standing still.

`python -m bench.lobeclass [--quick]`: for symmetric main lobes 30-90 deg wide between
their 3 dB points and 10-30 dB deep, of three shapes (cos^n, Gaussian in dB, and the
flat-topped super-Gaussian -3 |off / half|^4 a panel has), the relay's bearing after the
5th scan with no pattern file and no learning (a fresh relay: the default lobe fit with
the adaptive window), the leader 5 m away at every 5 deg of -85..85, whole-dB readings
with +-1 dB jitter, no fading: bench/tracking.py item 6's static figure, over the class
instead of the family. Prints one row per lobe: the worst |error|, where, and the worst
within +-65 deg (away from the servo limits).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable

from bench.common import Result
from bench.run import table
from bench.tracking import _antenna_error
from relayd.sim.antennas import cos_n

NAME = "lobeclass"
Gain = Callable[[float], float]


def gaussian(beamwidth_deg: float, depth_db: float) -> Gain:
    """-12 (off / beamwidth)^2 dB (3 dB down at half the beamwidth), floored."""
    return lambda off: max(-depth_db, -12.0 * (math.remainder(off, 360.0) / beamwidth_deg) ** 2)


def flat_top(beamwidth_deg: float, depth_db: float, power: float = 4.0) -> Gain:
    """-3 |off / half-beamwidth|^power dB, floored: flat on top, steep shoulders."""
    half = beamwidth_deg / 2.0
    return lambda off: max(-depth_db, -3.0 * abs(math.remainder(off, 360.0) / half) ** power)


SHAPES: dict[str, Callable[[float, float], Gain]] = {
    "cos^n": lambda bw, d: cos_n(bw, -d),
    "gaussian": gaussian,
    "flat-top": flat_top,
}


def lobe_rows(quick: bool) -> list[Result]:
    step = 20.0 if quick else 5.0
    bearings = [-85.0 + step * i for i in range(int(170 / step) + 1)]
    widths = (30.0, 90.0) if quick else (30.0, 45.0, 60.0, 75.0, 90.0)
    depths = (10.0, 30.0) if quick else (10.0, 20.0, 30.0)
    scan: dict[str, object] = {"estimator": "lobe", "window": "adaptive"}
    rows = []
    for shape, make in SHAPES.items():
        for bw in widths:
            for depth in depths:
                gain = make(bw, depth)
                errs = [_antenna_error(scan, gain, b, None, 1000 + int(b)) for b in bearings]
                i = max(range(len(errs)), key=lambda k: abs(errs[k]))
                inner = max(abs(e) for b, e in zip(bearings, errs, strict=True) if abs(b) <= 65)
                rows.append(
                    Result(
                        NAME,
                        f"{shape} {bw:g} deg, {depth:g} dB, no pattern file: static worst "
                        "|error| after 5 scans, -85..85",
                        abs(errs[i]),
                        "deg",
                        "<= 5 deg",
                        abs(errs[i]) <= 5.0,
                        f"at {bearings[i]:+.0f} deg ({errs[i]:+.1f}); within +-65: {inner:.1f}",
                    )
                )
                print(f"{shape} {bw:g}/{depth:g} done", file=sys.stderr, flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m bench.lobeclass", description=__doc__.splitlines()[0]
    )
    p.add_argument("--quick", action="store_true", help="2 widths, 2 depths, every 20 deg")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    print(table(lobe_rows(args.quick)))
    print(f"\n{time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
