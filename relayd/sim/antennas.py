"""The simulator's family of scan antennas: named patterns a scenario can give any relay.

The simulated Yagi has always been `relayd.sim.radio.yagi_gain_db` (cos^2, 90 deg between
its 3 dB points, floored at `radio.yagi_floor_db`): that is "builtin", and a scenario that
names no pattern gets it through the very same function, so its traces do not change.
The others are the shapes real antennas have, for the bench and for scenarios that set
`[scan] pattern = "NAME"` (every relay) or `pattern = "NAME"` in one `[[relay]]`:

- "shallow": a low-gain lobe 60 deg wide between its 3 dB points and only 12 dB deep
  (cos^n, floored at -12): where the built-in fit was 20 deg off.
- "deep": 45 deg wide and 30 dB deep.
- "yagi": a 40 deg main lobe with a first null near +-48 deg, side lobes at -10 dB near
  +-60 deg and a -15 dB back lobe, -25 dB between them: a long Yagi's shape.
- "asymmetric": 50 deg wide with its peak 8 deg off the mechanical axis and one flank
  steeper than the other (a mount, the robot's mast beside the antenna), -20 dB floor.
- "patch": a panel's wide, flat-topped lobe (70 deg between its 3 dB points) with steep
  shoulders (-12 dB at +-50 deg) and an -18 dB back.
- "helical": a real antenna's measured pattern, not a formula: an XW-24O-H10 2.4 GHz
  helical at 2440 MHz, from a published turntable measurement (relayd/sim/patterns/, its
  source in the file's header and docs/CONTROL.md). 39 deg between its 3 dB points, side
  lobes only 3.4 dB down near +-45 deg, -13 dB at the back: the shape no formula here has.

`DRAWN` is the part of the family the generated worlds draw from (the six shapes they
always drew from, so a generated world's antennas do not change as the family grows).

Each is a function of the off-axis angle (deg; leader bearing minus servo angle) to
relative dB, 0 at its peak. `family_pattern` tabulates one as an
`relayd.core.scan.pattern.AntennaPattern`, the form a pattern file has.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from importlib import resources

from relayd.core.scan.pattern import AntennaPattern, parse_pattern, sampled
from relayd.sim.radio import yagi_gain_db

Gain = Callable[[float], float]

BUILTIN = "builtin"


def _wrap(off_deg: float) -> float:
    return math.remainder(off_deg, 360.0)


def cos_n(beamwidth_deg: float, floor_db: float, squint_deg: float = 0.0) -> Gain:
    """A cos^n power lobe with this 3 dB beamwidth, floored, its peak at `squint_deg`."""
    n = -3.0 / (10.0 * math.log10(math.cos(math.radians(beamwidth_deg / 2.0))))

    def gain(off_deg: float) -> float:
        a = abs(_wrap(off_deg - squint_deg))
        c = math.cos(math.radians(a)) if a < 90.0 else 0.0
        return floor_db if c <= 0.0 else max(floor_db, 10.0 * n * math.log10(c))

    return gain


def _yagi(off_deg: float) -> float:
    a = abs(_wrap(off_deg))
    main = -12.0 * (a / 40.0) ** 2
    side = -10.0 - 12.0 * ((a - 60.0) / 15.0) ** 2
    back = -15.0 - 12.0 * ((180.0 - a) / 40.0) ** 2
    return max(main, side, back, -25.0)


def _asymmetric(off_deg: float) -> float:
    x = _wrap(off_deg - 8.0)
    # The 3 dB points 22 deg left and 28 deg right of the peak: 50 deg wide, lopsided.
    half = 22.0 if x < 0 else 28.0
    return max(-20.0, -3.0 * (x / half) ** 2)


def _patch(off_deg: float) -> float:
    a = abs(_wrap(off_deg))
    # A super-Gaussian: flat top, -3 dB at 35 deg, -12 dB at 50 deg.
    return max(-18.0, -3.0 * float((a / 35.0) ** 3.9))


def _builtin(off_deg: float) -> float:
    return yagi_gain_db(off_deg)


def measured(filename: str) -> AntennaPattern:
    """A measured pattern table shipped in relayd/sim/patterns/ (the pattern file format)."""
    return parse_pattern((resources.files("relayd.sim") / "patterns" / filename).read_text())


_HELICAL = measured("helical_xw24o_h10.toml")

FAMILY: dict[str, Gain] = {
    BUILTIN: _builtin,
    "shallow": cos_n(60.0, -12.0),
    "deep": cos_n(45.0, -30.0),
    "yagi": _yagi,
    "asymmetric": _asymmetric,
    "patch": _patch,
    "helical": _HELICAL.gain_db,
}

DRAWN: tuple[str, ...] = (BUILTIN, "shallow", "deep", "yagi", "asymmetric", "patch")


def pattern_gain(name: str) -> Gain:
    """The family's pattern of that name; ValueError naming the known ones."""
    try:
        return FAMILY[name]
    except KeyError:
        raise ValueError(f"unknown antenna pattern {name!r} (known: {', '.join(FAMILY)})") from None


def family_pattern(name: str, step_deg: float = 1.0) -> AntennaPattern:
    """The named pattern as a table every `step_deg` round the circle."""
    return sampled(pattern_gain(name), name, step_deg)
