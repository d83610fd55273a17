"""The antenna pattern learnt online (`[scan] learn_pattern`) against the main-lobe fit alone.

Where the uncalibrated static error comes from, and whether learning the pattern from
the scans the filter is sure of removes it. Every figure runs the real brain
(`bench.brainrig`: virtual time, the scanner's step timing, hold mode, a relay standing
still, the lobe fit with the adaptive window, whole-dB readings with +-1 dB jitter):

- "fresh": a new relay without learning, the leader 5 m away at the bearing, the bearing
  published after the 5th scan (bench/tracking.py item 6's "no pattern file" figure).
- "learnt": a relay with `learn_pattern = true` warmed up first (the leader still at 0 deg
  for `--warm` scans, then at +30 and -30 deg, with `--warm-bearings wide` also at +55 and
  -55, a third as many scans each), whose learner (what /status's pattern_learned shows
  is printed) is then given to a new relay with the leader at the bearing, 5 scans: what
  a relay that has learnt its antenna makes of a leader it has just found there.

The warm-up is run once per pattern and its learner copied for every bearing.
Prints each bearing's error and the worst, per pattern.

Then, with `--fading-seeds N`, the RMS after 5 scans over -60..60 under the simulator's
LOS and NLOS fading (bench/tracking.py item 6's), fresh against a learner warmed up under
the same fading.

    python -m bench.learnpattern [--patterns builtin,shallow,patch] [--step 5] [--warm 30]
        [--fading-seeds 2]
"""

from __future__ import annotations

import argparse
import copy
import math
import sys
import time

from bench.brainrig import BrainRig, still
from bench.common import rms
from relayd.sim.antennas import FAMILY
from relayd.sim.radio import Radio, RadioParams

SCANS = 5


def _at(b: float) -> tuple[float, float]:
    return 5.0 * math.cos(math.radians(b)), 5.0 * math.sin(math.radians(b))


def _radio(fading: str, seed: int) -> Radio:
    if fading == "none":
        return Radio(RadioParams.outdoor(fading=False, shadow_sigma_db=0.0), [])
    params = RadioParams.outdoor(rician_k_db=-60.0) if fading == "nlos" else RadioParams.outdoor()
    return Radio(params, [], seed=seed)


def _rig(name: str, learn: bool, b: float, seed: int, fading: str = "none") -> BrainRig:
    scan: dict[str, object] = {"estimator": "lobe", "window": "adaptive"}
    if learn:
        scan["learn_pattern"] = True
    rig = BrainRig(
        scan=scan,
        leader=still(*_at(b)),
        pattern=FAMILY[name],
        radio=_radio(fading, seed),
        jitter_db=1.0,
        jitter_seed=seed,
    )
    rig.start()
    return rig


def _error(rig: BrainRig, b: float) -> float:
    return math.remainder(rig.results[-1][1].estimate.bearing_deg - b, 360.0)


#: Where the leader stands during the warm-up after 0 deg ("narrow"; "wide" adds +-55).
WARM_BEARINGS = {"narrow": (30.0, -30.0), "wide": (30.0, -30.0, 55.0, -55.0)}


def warmed(
    name: str, learn: bool, warm: int, seed: int, how: str = "narrow", fading: str = "none"
) -> BrainRig:
    rig = _rig(name, learn, 0.0, seed, fading)
    rig.run_scans(warm)
    for b in WARM_BEARINGS[how]:
        rig.leader = still(*_at(b))
        rig.run_scans(max(1, warm // 3))
    return rig


def profile(name: str, bearings: list[float], warm: int, how: str) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {"fresh": [], "learnt": []}
    for b in bearings:
        rig = _rig(name, False, b, 1000 + int(b))
        rig.run_scans(SCANS)
        out["fresh"].append(_error(rig, b))
    base = warmed(name, True, warm, 7, how)
    learner = base.brain.scans.model.learner  # type: ignore[attr-defined]
    truth = FAMILY[name]
    table = learner.pattern()
    off = max(abs(table.gain_db(x) - truth(x)) for x in range(-30, 31))
    print(
        f"  {name}: after the warm-up {learner.status().to_json()}, |learnt - true| "
        f"<= {off:.2f} dB over +-30 deg, learnt beamwidth {table.beamwidth_deg():.1f} deg"
    )
    for b in bearings:
        rig = _rig(name, True, b, 1000 + int(b))
        rig.brain.scans.model.learner = copy.deepcopy(learner)  # type: ignore[attr-defined]
        rig.run_scans(SCANS)
        out["learnt"].append(_error(rig, b))
    return out


def fading_rms(name: str, fading: str, warm: int, seeds: int) -> tuple[float, float, int]:
    """RMS error after 5 scans over bearings -60..60 under the simulator's fading: fresh
    relays without learning, and relays given a learner warmed up under the same fading."""
    fresh: list[float] = []
    learnt: list[float] = []
    for seed in range(seeds):
        base = warmed(name, True, warm, 500 + seed, fading=fading)
        learner = base.brain.scans.model.learner  # type: ignore[attr-defined]
        for b in range(-60, 61, 10):
            rig = _rig(name, False, b, seed * 1000 + b, fading)
            rig.run_scans(SCANS)
            fresh.append(_error(rig, b))
            rig = _rig(name, True, b, seed * 1000 + b, fading)
            rig.brain.scans.model.learner = copy.deepcopy(learner)  # type: ignore[attr-defined]
            rig.run_scans(SCANS)
            learnt.append(_error(rig, b))
    return rms(fresh), rms(learnt), len(fresh)


def _worst(errs: list[float]) -> int:
    return max(range(len(errs)), key=lambda i: abs(errs[i]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--patterns", default="builtin,shallow,patch")
    ap.add_argument("--step", type=float, default=5.0)
    ap.add_argument("--warm", type=int, default=30)
    ap.add_argument("--warm-bearings", choices=sorted(WARM_BEARINGS), default="narrow")
    ap.add_argument(
        "--fading-seeds", type=int, default=0, help="also the RMS under LOS and NLOS fading"
    )
    args = ap.parse_args(argv)
    names = [n for n in args.patterns.split(",") if n]
    unknown = [n for n in names if n not in FAMILY]
    if unknown:
        print(f"--patterns: unknown {unknown} (known: {', '.join(FAMILY)})", file=sys.stderr)
        return 2
    n = int(170.0 / args.step) + 1
    bearings = [-85.0 + args.step * i for i in range(n)]
    t0 = time.monotonic()
    for name in names:
        prof = profile(name, bearings, args.warm, args.warm_bearings)
        print(f"\n{name}: error (deg) after 5 scans, by bearing")
        print("bearing  " + "  ".join(f"{k:>7}" for k in prof))
        for i, b in enumerate(bearings):
            print(f"{b:7.0f}  " + "  ".join(f"{prof[k][i]:7.2f}" for k in prof))
        worst = {k: _worst(errs) for k, errs in prof.items()}
        print(
            "worst    "
            + "  ".join(f"{abs(prof[k][worst[k]]):7.2f}" for k in prof)
            + "   at "
            + ", ".join(f"{k} {bearings[worst[k]]:g}" for k in prof),
            flush=True,
        )
        for fading in ("los", "nlos") if args.fading_seeds > 0 else ():
            f, lr, runs = fading_rms(name, fading, args.warm, args.fading_seeds)
            print(
                f"{name} {fading.upper()}: RMS fresh {f:.2f} deg, learnt {lr:.2f} deg ({runs} runs)"
            )
    print(f"\n{time.monotonic() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
