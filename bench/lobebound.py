"""What any estimator can do at the servo limits without knowing the lobe: a lower bound.

`python -m bench.lobebound [--quick]` asks whether "within 5 deg, uncalibrated, for every
symmetric main lobe 30-90 deg wide and 10-30 dB deep, leader anywhere in +-85" is a goal
a better fit could reach, or one the measurements rule out. Both figures are for five full
sweeps of the relay's own 25 servo angles over -90..90 (the relay's adaptive window
samples other angles), the level steady between scans, no fading:

- **The two-point bound.** Two lobes of the class, at two bearings more than 10 deg
  apart (both within 85), whose five sweeps a reading cannot tell apart well: for ANY
  estimator of those sweeps, P(error > 5 deg) >= (1 - TV) / 2 on at least one of them
  (Le Cam), where TV is the total-variation distance between the two lobes' laws of
  readings, computed for the exact whole-dB jitter by Monte Carlo of the likelihood ratio
  (the second lobe's level set where it matches the first best, then TV estimated again
  there with fresh draws).
- **The oracle.** A least-squares fit (not the exact likelihood of whole-dB readings) over
  the class itself (bench/lobeclass.py's three shapes on a 1.25 deg x 1.25 dB grid of
  widths and depths) and the bearing, the level free, bearings tried from 40 deg to 85
  (it knows the leader lies there). Run on the class's lobes at 60-85 deg (each draw's
  width and depth moved within half a grid step, inside the class, so the truth is
  rarely one of the oracle's lobes) with the readings a real adapter gives (whole dB, +-1
  dB uniform jitter), `--trials` draws each: its worst error and how often it is beyond
  5 deg. `--grid-to 125` takes away its knowledge that the leader is within 85 deg.

Needs NumPy (matplotlib's own dependency, so in every install that has `[sim]`).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from bench.common import Result
from bench.lobeclass import SHAPES
from bench.run import table

NAME = "lobebound"
Array = npt.NDArray[np.float64]

#: The relay's full sweep (config defaults: 25 samples over limits -90..90).
ANGLES_DEG: Array = np.linspace(-90.0, 90.0, 25)
SCANS = 5
TARGET_DEG = 5.0


@dataclass(frozen=True)
class Lobe:
    shape: str
    beamwidth_deg: float
    depth_db: float

    def __str__(self) -> str:
        return f"{self.shape} {self.beamwidth_deg:g} deg, {self.depth_db:g} dB"

    def gains(self, bearing_deg: float) -> Array:
        g = SHAPES[self.shape](self.beamwidth_deg, self.depth_db)
        return np.array([g(bearing_deg - a) for a in ANGLES_DEG])


#: The oracle's grid of widths (deg) and depths (dB). On a coarser grid it does worse, the
#: truth lying between its lobes (`--grid-step 2.5`, bench/RESULTS.md).
GRID_STEP = 1.25


def class_bank(step: float = GRID_STEP) -> list[Lobe]:
    """The class on a grid: 3 shapes x widths 30..90 x depths 10..30, every `step`."""
    widths = np.arange(30.0, 90.01, step)
    depths = np.arange(10.0, 30.01, step)
    return [Lobe(s, float(w), float(d)) for s in SHAPES for w in widths for d in depths]


def templates(bank: list[Lobe], bearings_deg: Array) -> Array:
    """bank x bearing x angle, each row's mean removed (the level is free)."""
    t = np.array([[lobe.gains(float(b)) for b in bearings_deg] for lobe in bank])
    centred: Array = t - t.mean(axis=2, keepdims=True)
    return centred


def readings(mean_db: Array, rng: np.random.Generator, scans: int = SCANS) -> Array:
    """scans x angle: whole dB, each with a uniform +-1 dB jitter first (bench/brainrig.py)."""
    return np.round(mean_db[None, :] + rng.uniform(-1.0, 1.0, (scans, mean_db.size)))


def oracle(tmpl: Array, bearings_deg: Array, scans: Array) -> float:
    """The bearing of the least-squares template over the class and the bearing grid."""
    y = scans.mean(axis=0)
    ssr = ((tmpl - (y - y.mean())) ** 2).sum(axis=2)
    _, j = np.unravel_index(int(ssr.argmin()), ssr.shape)
    return float(bearings_deg[j])


def _probs(mean_db: Array, ks: Array) -> Array:
    """angle x k: P(reading == k) = the part of [m - 1, m + 1] that rounds to k, over 2."""
    lo = np.maximum(ks[None, :] - 0.5, (mean_db - 1.0)[:, None])
    hi = np.minimum(ks[None, :] + 0.5, (mean_db + 1.0)[:, None])
    p: Array = np.clip(hi - lo, 0.0, None) / 2.0
    return p


def total_variation(a_db: Array, b_db: Array, draws: int, seed: int = 0) -> float:
    """TV between the readings of SCANS scans of means a_db and b_db (Monte Carlo under a)."""
    rng = np.random.default_rng(seed)
    ks = np.arange(
        np.floor(min(a_db.min(), b_db.min())) - 2, np.ceil(max(a_db.max(), b_db.max())) + 3
    )
    pa, pb = _probs(a_db, ks), _probs(b_db, ks)
    log_ratio = np.zeros(draws)
    for _ in range(SCANS):
        for i in range(a_db.size):
            k = rng.choice(ks.size, size=draws, p=pa[i])
            with np.errstate(divide="ignore"):
                log_ratio += np.log(pb[i][k]) - np.log(pa[i][k])
    return float(np.mean(np.maximum(0.0, 1.0 - np.exp(log_ratio))))


def closest_pair(
    bank: list[Lobe], bearings_deg: Array, tmpl: Array, apart_deg: float
) -> tuple[float, tuple[int, int, int, int]]:
    """The two (lobe, bearing) whose sweeps differ least (RMS, levels free), bearings > apart."""
    flat = tmpl.reshape(-1, tmpl.shape[2])
    best = (np.inf, (0, 0, 0, 0))
    for i in range(flat.shape[0]):
        li, bi = divmod(i, bearings_deg.size)
        far = bearings_deg > bearings_deg[bi] + apart_deg
        if not far.any():
            continue
        d = np.sqrt(((tmpl[:, far, :] - flat[i]) ** 2).mean(axis=2))
        lj, bj = np.unravel_index(int(d.argmin()), d.shape)
        if d[lj, bj] < best[0]:
            best = (float(d[lj, bj]), (li, bi, int(lj), int(np.flatnonzero(far)[bj])))
    return best


def _between(lobe: Lobe, rng: np.random.Generator, step: float) -> Lobe:
    """The lobe with its width and depth moved anywhere within half a grid step, inside the
    class: a real antenna is not on the oracle's grid, and one that is would be
    recognised too well."""
    half = step / 2.0
    # Within the class: a row at its edge (10 dB deep, 90 deg wide) moves inward only.
    width = rng.uniform(max(30.0, lobe.beamwidth_deg - half), min(90.0, lobe.beamwidth_deg + half))
    depth = rng.uniform(max(10.0, lobe.depth_db - half), min(30.0, lobe.depth_db + half))
    return Lobe(lobe.shape, width, depth)


def oracle_rows(
    trials: int, quick: bool, grid_to_deg: float = 85.0, step: float = GRID_STEP
) -> list[Result]:
    rng = np.random.default_rng(2026)
    bank = class_bank(step)
    grid = np.arange(40.0, grid_to_deg + 0.01, 0.5)
    tmpl = templates(bank, grid)
    widths = (45.0, 90.0) if quick else (30.0, 45.0, 60.0, 75.0, 90.0)
    depths = (10.0, 30.0) if quick else (10.0, 20.0, 30.0)
    truths = (70.0, 85.0) if quick else (60.0, 65.0, 70.0, 75.0, 80.0, 85.0)
    rows = []
    for shape in SHAPES:
        for bw in widths:
            for depth in depths:
                lobe = Lobe(shape, bw, depth)
                errs = np.array(
                    [
                        oracle(tmpl, grid, readings(_between(lobe, rng, step).gains(b) - 60.0, rng))
                        - b
                        for b in truths
                        for _ in range(trials)
                    ]
                )
                worst = float(np.abs(errs).max())
                beyond = float(np.mean(np.abs(errs) > TARGET_DEG))
                rows.append(
                    Result(
                        NAME,
                        f"oracle, {lobe}: share of draws beyond {TARGET_DEG:g} deg, "
                        f"{truths[0]:g}..{truths[-1]:g} deg, bearings to {grid_to_deg:g}, "
                        f"grid {step:g}",
                        100.0 * beyond,
                        "%",
                        "",
                        None,
                        f"worst {worst:.1f} deg over {errs.size} draws",
                    )
                )
    return rows


def pair_row(draws: int, apart_deg: float = 2.0 * TARGET_DEG) -> Result:
    bank = [
        Lobe(s, float(w), float(d))
        for s in SHAPES
        for w in np.arange(30.0, 90.01, 5.0)
        for d in np.arange(10.0, 30.01, 2.5)
    ]
    grid = np.arange(60.0, 85.01, 0.5)
    rms_db, (li, bi, lj, bj) = closest_pair(bank, grid, templates(bank, grid), apart_deg)
    a = bank[li].gains(float(grid[bi]))
    b = bank[lj].gains(float(grid[bj]))
    b = b + (a - b).mean()
    # The level shift that makes them likest, then TV there on fresh draws (the minimum of
    # several Monte Carlo estimates is biased low).
    shift = min(np.arange(-0.2, 0.21, 0.05), key=lambda s: total_variation(a, b + s, draws))
    tv = total_variation(a, b + shift, draws, seed=1)
    return Result(
        NAME,
        f"any estimator: P(error > {TARGET_DEG:g} deg) on one of two class lobes, "
        f"{SCANS} full sweeps, whole-dB +-1 dB jitter (Le Cam, >=)",
        100.0 * (1.0 - tv) / 2.0,
        "%",
        "",
        None,
        f"{bank[li]} at {grid[bi]:g} vs {bank[lj]} at {grid[bj]:g}: sweeps {rms_db:.2f} dB RMS "
        f"apart, TV {tv:.3f}",
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m bench.lobebound", description=__doc__.splitlines()[0]
    )
    p.add_argument("--quick", action="store_true", help="fewer lobes, bearings and draws")
    p.add_argument("--trials", type=int, default=None, help="draws per lobe and bearing (40)")
    p.add_argument(
        "--grid-to",
        type=float,
        default=85.0,
        help="the oracle's last bearing (85: it knows the leader is within reach)",
    )
    p.add_argument(
        "--grid-step", type=float, default=GRID_STEP, help="the oracle's grid (deg and dB)"
    )
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    trials = args.trials or (5 if args.quick else 40)
    rows = [pair_row(4000 if args.quick else 100_000)]
    rows += oracle_rows(trials, args.quick, args.grid_to, args.grid_step)
    print(table(rows))
    print(f"\n{time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
