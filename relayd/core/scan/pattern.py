"""An antenna's measured pattern: off-axis angle -> gain relative to its peak, and its file format.

A pattern is a table of (off-axis angle, relative dB) points, interpolated linearly in
angle. The off-axis angle is the leader's bearing minus the scan servo's angle (robot
frame, degrees, counter-clockwise positive, as everywhere in relayd): a leader at +30 deg
heard with the servo at 0 is 30 deg off axis. The table is normalised so its highest
point is 0 dB; an antenna whose peak is not on its mechanical axis (a mount, the robot's
own body) keeps its peak where it is, which is what lets the fit find the leader rather
than the antenna's axis.

A table may cover the whole circle (-180..180) or only what was measured (a servo's
sweep sees +-90 deg and a little more). Beyond a partial table the gain is taken as the
table's lowest value: the leader is at least that far down there, and a fit that knows
nothing of the back half must not invent a lobe in it.

The file (`[scan] pattern_file`, written by `relayd calibrate antenna`) is TOML:

    [pattern]
    name = "yagi on relay1"
    angles_deg = [-180.0, -175.0, ...]   # strictly increasing, within -180..180
    gain_db = [-22.1, -21.7, ...]        # as many, finite, relative (normalised on load)
    symmetric = false                    # true: angles 0..180 only, mirrored

    [conditions]                         # how it was measured: free-form, kept as text
    node = "command center AP"
    distance_m = 8.0
    ...

`parse_pattern` checks it and names the key of any problem; `pattern_toml` writes one.
Pure: text in, text out; reading and writing the file is the caller's.
"""

from __future__ import annotations

import bisect
import itertools
import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

#: The dense lookup's step (deg): the fit evaluates the pattern tens of thousands of times a
#: scan, and a list index is far cheaper than a bisection.
LOOKUP_STEP_DEG = 0.25
FORMAT_VERSION = 1


class PatternError(ValueError):
    """A pattern table or file that cannot be used; the message names the key."""


def wrap180(angle_deg: float) -> float:
    """The angle in [-180, 180)."""
    return (angle_deg + 180.0) % 360.0 - 180.0


@dataclass(frozen=True, slots=True)
class AntennaPattern:
    """A relative gain pattern: `gain_db(off_axis_deg)`, 0 dB at its peak."""

    angles_deg: tuple[float, ...]
    gain_db_table: tuple[float, ...]
    name: str = ""
    #: How and where it was measured (free-form text, as the file's [conditions] had it).
    conditions: tuple[tuple[str, str], ...] = ()
    #: Off-axis angles (lo, hi) where the table is data; outside them it is only an upper
    #: bound (a pattern learnt online: the gain there is at most the last value learnt).
    #: None: the whole table is data, as a measured file's is.
    known_deg: tuple[float, float] | None = None
    _lookup: tuple[float, ...] = field(default=(), init=False, repr=False, compare=False)
    _beamwidth: float | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        a, g = self.angles_deg, self.gain_db_table
        if len(a) != len(g):
            raise PatternError(f"gain_db: {len(g)} values for {len(a)} angles_deg")
        if len(a) < 3:
            raise PatternError("angles_deg: at least 3 points are needed")
        if not all(math.isfinite(x) for x in (*a, *g)):
            raise PatternError("angles_deg, gain_db: every value must be a finite number")
        if a[0] < -180.0 or a[-1] > 180.0:
            raise PatternError(f"angles_deg: must lie within -180..180, got {a[0]:g}..{a[-1]:g}")
        if any(b <= x for x, b in itertools.pairwise(a)):
            raise PatternError("angles_deg: must be strictly increasing")
        top = max(g)
        norm = tuple(x - top for x in g)
        object.__setattr__(self, "gain_db_table", norm)
        n = round(360.0 / LOOKUP_STEP_DEG)
        object.__setattr__(
            self,
            "_lookup",
            tuple(self._interp(-180.0 + i * LOOKUP_STEP_DEG) for i in range(n + 1)),
        )
        left, right = self.half_widths_deg()
        bw = None if left is None or right is None else left + right
        object.__setattr__(self, "_beamwidth", bw)

    @property
    def full_circle(self) -> bool:
        """Whether the table goes round (its ends meet across +-180 within one table step)."""
        a = self.angles_deg
        step = max(b - x for x, b in itertools.pairwise(a))
        return (a[0] + 360.0) - a[-1] <= step + 1e-9

    def _interp(self, off_deg: float) -> float:
        """Linear interpolation in the table (exact, slow): the lookup is built from it."""
        a, g = self.angles_deg, self.gain_db_table
        x = wrap180(off_deg)
        if x < a[0] or x > a[-1]:
            if not self.full_circle:
                return min(g)
            # Across +-180: from the last point to the first one, 360 deg further on.
            lo_a, hi_a = a[-1], a[0] + 360.0
            xx = x if x >= a[-1] else x + 360.0
            f = (xx - lo_a) / (hi_a - lo_a) if hi_a > lo_a else 0.0
            return g[-1] + f * (g[0] - g[-1])
        i = bisect.bisect_right(a, x)
        if i >= len(a):
            return g[-1]
        j = i - 1
        f = (x - a[j]) / (a[i] - a[j])
        return g[j] + f * (g[i] - g[j])

    @property
    def lookup(self) -> tuple[float, ...]:
        """The gain every LOOKUP_STEP_DEG from -180 to 180 (both ends), for hot loops."""
        return self._lookup

    def gain_db(self, off_axis_deg: float) -> float:
        """Relative gain (dB, <= 0) at this off-axis angle."""
        x = (off_axis_deg + 180.0) % 360.0 / LOOKUP_STEP_DEG
        i = int(x)
        lk = self._lookup
        if i >= len(lk) - 1:
            return lk[-1]
        f = x - i
        return lk[i] + f * (lk[i + 1] - lk[i])

    def known(self, off_axis_deg: float) -> bool:
        """Whether the table is data at this off-axis angle (not only a bound)."""
        if self.known_deg is None:
            return True
        x = wrap180(off_axis_deg)
        return self.known_deg[0] <= x <= self.known_deg[1]

    def slope_db_per_deg(self, off_axis_deg: float) -> float:
        """The pattern's slope there (central difference over one lookup step)."""
        h = LOOKUP_STEP_DEG
        return (self.gain_db(off_axis_deg + h) - self.gain_db(off_axis_deg - h)) / (2.0 * h)

    # -- what it looks like --------------------------------------------------------------

    def peak_deg(self) -> float:
        """Where the pattern is highest (the table's point; the antenna's squint)."""
        g = self.gain_db_table
        return self.angles_deg[max(range(len(g)), key=lambda i: g[i])]

    def _crossing(self, start: float, direction: float, level_db: float) -> float | None:
        """The first angle from `start` going `direction` where the gain falls to level_db."""
        step = 0.1
        x = start
        prev = self.gain_db(x)
        for _ in range(int(180.0 / step)):
            x2 = x + direction * step
            cur = self.gain_db(x2)
            if cur <= level_db:
                f = (prev - level_db) / (prev - cur) if prev != cur else 0.0
                return x + direction * step * f
            x, prev = x2, cur
        return None

    def half_widths_deg(self, level_db: float = -3.0) -> tuple[float | None, float | None]:
        """How far (deg) the gain stays above `level_db` left (negative side) and right of the peak."""
        p = self.peak_deg()
        lo, hi = self._crossing(p, -1.0, level_db), self._crossing(p, 1.0, level_db)
        return (None if lo is None else p - lo), (None if hi is None else hi - p)

    def beamwidth_deg(self, level_db: float = -3.0) -> float | None:
        """Between the `level_db` points around the peak (None: the gain never falls that far)."""
        if level_db == -3.0:
            return self._beamwidth  # computed once: the fit asks every scan
        left, right = self.half_widths_deg(level_db)
        return None if left is None or right is None else left + right

    def front_to_back_db(self) -> float | None:
        """Peak minus the gain 180 deg from it (None: the table does not reach there)."""
        back = wrap180(self.peak_deg() + 180.0)
        if not self.full_circle and not (self.angles_deg[0] <= back <= self.angles_deg[-1]):
            return None
        return -self.gain_db(back)

    def main_lobe_deg(self) -> tuple[float, float]:
        """The main lobe's extent: from the peak down each side to its first null, the
        lowest point before the gain rises again by more than 1.5 dB (a measured table's
        ripple of a few tenths is no null), or where the table ends."""
        p = self.peak_deg()
        ends = []
        for d in (-1.0, 1.0):
            low_x, low = p, self.gain_db(p)
            x = p
            for _ in range(int(180.0 / 0.5)):
                x += d * 0.5
                cur = self.gain_db(x)
                if cur < low:
                    low_x, low = x, cur
                elif low < -3.0 and cur > low + 1.5:
                    break
            ends.append(low_x)
        return ends[0], ends[1]

    def side_lobe_db(self) -> float | None:
        """The highest gain outside the main lobe and away from the back (the +-30 deg around
        180 deg from the peak): the worst side lobe, None when there is none in the table."""
        lo, hi = self.main_lobe_deg()
        back = wrap180(self.peak_deg() + 180.0)
        best: float | None = None
        a, g = self.angles_deg, self.gain_db_table
        for i in range(1, len(a) - 1):
            x = a[i]
            if lo <= x <= hi or abs(wrap180(x - back)) <= 30.0:
                continue
            if g[i] >= g[i - 1] and g[i] >= g[i + 1] and (best is None or g[i] > best):
                best = g[i]
        return best


def symmetric_table(
    half_angles_deg: Sequence[float], half_gain_db: Sequence[float]
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """A whole table from its 0..180 half, mirrored about 0."""
    pairs = sorted(zip(half_angles_deg, half_gain_db, strict=True))
    if not pairs or pairs[0][0] < 0.0:
        raise PatternError("angles_deg: a symmetric pattern gives angles 0..180 only")
    mirrored = [(-a, g) for a, g in reversed(pairs) if a > 0.0 and -a > -180.0 - 1e-9]
    full = mirrored + pairs
    return tuple(a for a, _ in full), tuple(g for _, g in full)


def _floats(doc: Mapping[str, Any], key: str) -> list[float]:
    v = doc.get(key)
    if not isinstance(v, list) or not v:
        raise PatternError(f"pattern.{key}: must be a non-empty array of numbers")
    out = []
    for i, x in enumerate(v):
        if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
            raise PatternError(f"pattern.{key}[{i}]: must be a finite number, got {x!r}")
        out.append(float(x))
    return out


def parse_pattern(text: str) -> AntennaPattern:
    """A pattern from the text of a pattern file; PatternError naming the key when unusable."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise PatternError(f"not valid TOML: {exc}") from None
    section = doc.get("pattern")
    if not isinstance(section, dict):
        raise PatternError("[pattern]: missing (the table of angles_deg and gain_db)")
    known = {"name", "angles_deg", "gain_db", "symmetric", "format"}
    extra = sorted(set(section) - known)
    if extra:
        raise PatternError(f"pattern.{extra[0]}: unknown key (known: {', '.join(sorted(known))})")
    fmt = section.get("format", FORMAT_VERSION)
    if fmt != FORMAT_VERSION:
        raise PatternError(
            f"pattern.format: this relayd reads format {FORMAT_VERSION}, got {fmt!r}"
        )
    name = section.get("name", "")
    if not isinstance(name, str):
        raise PatternError("pattern.name: must be a string")
    symmetric = section.get("symmetric", False)
    if not isinstance(symmetric, bool):
        raise PatternError("pattern.symmetric: must be true or false")
    angles, gains = _floats(section, "angles_deg"), _floats(section, "gain_db")
    if len(angles) != len(gains):
        raise PatternError(f"pattern.gain_db: {len(gains)} values for {len(angles)} angles_deg")
    if symmetric:
        if any(b <= a for a, b in itertools.pairwise(angles)):
            raise PatternError("pattern.angles_deg: must be strictly increasing")
        a_t, g_t = symmetric_table(angles, gains)
    else:
        a_t, g_t = tuple(angles), tuple(gains)
    cond = doc.get("conditions", {})
    if not isinstance(cond, dict):
        raise PatternError("[conditions]: must be a table")
    conditions = tuple((str(k), str(v)) for k, v in cond.items())
    try:
        return AntennaPattern(a_t, g_t, name, conditions)
    except PatternError as exc:
        raise PatternError(f"pattern.{exc}") from None


def _toml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def _toml_value(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float) and math.isfinite(v):
        return repr(round(float(v), 3)) if isinstance(v, float) else str(v)
    return _toml_str(str(v))


def pattern_toml(
    pattern: AntennaPattern, conditions: Mapping[str, object] | None = None, comment: str = ""
) -> str:
    """The pattern file for `pattern` (its conditions, or these), as `parse_pattern` reads it."""
    lines = [f"# {line}" for line in comment.splitlines()]
    lines += [
        "[pattern]",
        f"format = {FORMAT_VERSION}",
        f"name = {_toml_str(pattern.name)}",
        "symmetric = false",
        "angles_deg = [" + ", ".join(f"{a:.2f}" for a in pattern.angles_deg) + "]",
        "gain_db = [" + ", ".join(f"{g:.2f}" for g in pattern.gain_db_table) + "]",
        "",
        "[conditions]",
    ]
    items = dict(pattern.conditions) if conditions is None else dict(conditions)
    lines += [f"{k} = {_toml_value(v)}" for k, v in items.items()]
    return "\n".join(lines) + "\n"


def sampled(
    gain: Any, name: str, step_deg: float = 1.0, conditions: tuple[tuple[str, str], ...] = ()
) -> AntennaPattern:
    """A full-circle table of a gain function (off-axis deg -> dB) every `step_deg`."""
    n = round(360.0 / step_deg)
    angles = tuple(-180.0 + i * step_deg for i in range(n))
    return AntennaPattern(angles, tuple(float(gain(a)) for a in angles), name, conditions)
