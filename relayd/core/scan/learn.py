"""The scan antenna's pattern learnt online, without a pattern file, from scans the filter is sure of.

`relayd calibrate antenna` measures a pattern with a node at a known direction. Without
that file the tracking filter still knows where the leader is once it has seen it a few
times: each scan it is sure of is then a small calibration sweep, the servo at a_i, the
leader at the track's bearing b, so sample i tells the gain at off-axis angle b - a_i up
to the scan's level (distance, shadowing). This module collects those samples:

- **Only sure scans.** The track's sd at most `sure_sd_deg`, and the bearing at least
  `edge_margin_deg` inside the sweep: near a servo limit the lobe is seen on one side
  only and the main-lobe fit's bearing is biased toward the sweep's middle, which the
  learnt pattern would then learn as the antenna's shape and repeat. A scan that is not
  sure is refused whole (`add` says so); nothing of it enters the table.
- **The level from the lobe's top.** Each scan's level is the mean of rssi - T(b - a)
  over the samples the current table T puts within `level_window_db` of its peak (at
  least three): near the peak a prior and a real antenna differ least (over the floor
  by 10 dB and more). The samples are chosen by the table, not by the readings: the
  loudest readings are the ones with the luckiest noise, and a level read from them
  lifts the peak's bins above the rest (a 90 deg lobe was learnt 77 deg wide that way).
  What error is left is a constant on one scan, and shrinks as the table learns.
- **Bins with a prior.** Off-axis angle in `bin_deg` bins round the circle; a bin the
  data never reach stays the prior, and a visited one is the running mean of its samples
  alone (a prior kept in the mean with even one sample's weight pulled a narrow lobe's
  floor 0.4 dB towards a 90 deg prior's shoulder). The prior is the built-in lobe the main-lobe fit assumes: a parabola in dB,
  12 dB down at one beamwidth off axis (the beamwidth learnt from two-sided fits when
  known, else `prior_beamwidth_deg`), floored at `prior_floor_db`.
- **Forgetting.** A bin remembers at most `max_weight` samples (beyond, the running mean
  is an exponential one): an antenna that is bent or swapped is relearnt.
- **Gaps, noise, symmetry.** A still leader is sampled at the same off-axis angles scan
  after scan (the servo's steps); a bin in a gap of at most `gap_fill_deg` between
  covered bins is interpolated between them, not left at the prior. Covered bins are
  smoothed over a 10 deg triangle, and with `symmetric` each side is the mean of both.
- **Beyond the learnt lobe, a bound.** With `bound_beyond`, outward of the lobe covered
  without a break the table is flat at the lobe's last value and the pattern says where
  it is data (`AntennaPattern.known_deg`): the fit (relayd/core/scan/patternfit.py)
  censors the rest instead of taking a guess for a measurement.
- **Progress.** The sure scans taken, the degrees of off-axis angle covered (bins with
  `min_bin_samples` samples, and the gaps between them), and `ready` once there are
  `ready_scans` scans and the table is covered `ready_half_deg` each side of its peak:
  the fit uses the table from then on.

The learnt pattern is relative to the track's bearing, so an antenna whose peak is off
its mechanical axis is learnt with its peak on the axis: a constant offset only a pattern
file measured against a known direction can remove. Pure: no I/O, no clock.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from relayd.core.scan.pattern import AntennaPattern, wrap180


@dataclass(frozen=True, slots=True)
class LearnParams:
    """Settings of the online pattern learner."""

    #: Off-axis bin width (deg).
    bin_deg: float = 2.0
    #: A scan is learnt from only while the track's sd is at most this (deg).
    sure_sd_deg: float = 4.0
    #: ... and its bearing at least this far (deg) inside the sweep's ends.
    edge_margin_deg: float = 30.0
    #: A bin remembers at most this many samples (older ones fade).
    max_weight: float = 400.0
    #: The prior lobe: 12 dB down at this beamwidth off axis (3 dB at half of it) ...
    prior_beamwidth_deg: float = 90.0
    #: ... floored here (dB).
    prior_floor_db: float = -20.0
    #: A scan's level comes from its samples the table puts within this much (dB) of its peak.
    level_window_db: float = 3.0
    #: A bin counts as covered with this many samples ...
    min_bin_samples: int = 3
    #: ... or when it lies in a gap at most this wide (deg) between covered bins: a servo's
    #: steps (7.5 deg) sample the same off-axis angles scan after scan while the leader
    #: stands still, and the lobe between them is interpolated, not the prior.
    gap_fill_deg: float = 10.0
    #: A bin where the slope turns by more than this (dB per bin, over three bins each
    #: side) is a corner, smoothed over its nearest neighbours only.
    kink_db_per_bin: float = 0.6
    #: The table is used once this many sure scans have entered it and it is covered this
    #: far (deg) each side of its peak.
    ready_scans: int = 15
    ready_half_deg: float = 30.0
    #: Beyond the covered lobe the table is a bound (flat at the lobe's last learnt value,
    #: `AntennaPattern.known_deg` set, the fit censors there) rather than the prior's
    #: continuation taken as data.
    bound_beyond: bool = True
    #: Learn a lobe symmetric about its axis (each side the mean of both).
    symmetric: bool = True

    def __post_init__(self) -> None:
        if not 0.0 < self.bin_deg <= 10.0 or 360.0 % self.bin_deg > 1e-9:
            raise ValueError(f"bin_deg must divide 360 and be in (0, 10], got {self.bin_deg}")
        if self.max_weight < 1.0:
            raise ValueError(f"max_weight must be >= 1, got {self.max_weight}")
        if self.sure_sd_deg <= 0.0 or self.prior_beamwidth_deg <= 0.0:
            raise ValueError("sure_sd_deg and prior_beamwidth_deg must be > 0")


@dataclass(frozen=True, slots=True)
class LearnStatus:
    """How far the learnt pattern has come (/status `pattern_learned`)."""

    scans: int
    refused: int
    coverage_deg: float
    ready: bool

    def to_json(self) -> dict[str, object]:
        return {
            "scans": self.scans,
            "refused": self.refused,
            "coverage_deg": round(self.coverage_deg, 1),
            "ready": self.ready,
        }


def prior_db(off_deg: float, beamwidth_deg: float, floor_db: float) -> float:
    """The built-in lobe: -12 (off / beamwidth)^2 dB, floored (the main-lobe fit's model)."""
    return max(floor_db, -12.0 * (wrap180(off_deg) / beamwidth_deg) ** 2)


class PatternLearner:
    """Accumulates sure scans into an off-axis -> relative dB table (see the module doc)."""

    def __init__(
        self, params: LearnParams = LearnParams(), beamwidth_deg: float | None = None
    ) -> None:
        self.params = params
        n = round(360.0 / params.bin_deg)
        self._centres = tuple(-180.0 + (i + 0.5) * params.bin_deg for i in range(n))
        bw = beamwidth_deg if beamwidth_deg is not None and beamwidth_deg > 0 else None
        bw = bw or params.prior_beamwidth_deg
        self._prior = tuple(prior_db(c, bw, params.prior_floor_db) for c in self._centres)
        self._mean = list(self._prior)
        self._weight = [0.0] * n
        self._samples = [0] * n
        self.scans = 0
        self.refused = 0
        self._table: AntennaPattern | None = None
        self._filled: list[float] | None = None
        self._known: tuple[float, float] | None = None

    def set_prior_beamwidth(self, beamwidth_deg: float) -> None:
        """Shape the prior with this beamwidth (the one learnt from two-sided fits); only
        before any scan has entered, so no data is overwritten."""
        if self.scans == 0 and beamwidth_deg > 0.0:
            p = self.params
            self._prior = tuple(prior_db(c, beamwidth_deg, p.prior_floor_db) for c in self._centres)
            self._mean = list(self._prior)
            self._filled = self._table = None

    def _covered(self) -> list[bool]:
        return [s >= self.params.min_bin_samples for s in self._samples]

    def _fill(self) -> tuple[list[float], list[bool]]:
        """The table as the fit sees it, and which bins are covered (sampled enough, or in a
        narrow gap between such bins, interpolated). Covered bins are smoothed over their
        covered neighbours (a 10 deg triangle: whole-dB readings leave a bin's mean a few
        tenths off, and a wide lobe's flat top must not grow false peaks). Outward of the
        covered lobe the prior's shape goes on from the last covered bin, never above it:
        where the data stop the table must not step (the fit would take the step for a lobe
        edge)."""
        n = len(self._mean)
        covered = self._covered()
        raw = list(self._mean)
        seen = [i for i in range(n) if covered[i]]
        if not seen:
            # Nothing covered yet: the prior, not one or two raw samples in some bins.
            return list(self._prior), covered
        max_gap = round(self.params.gap_fill_deg / self.params.bin_deg)
        filled = list(covered)
        for a, b in zip(seen, seen[1:] + seen[:1], strict=True):
            gap = (b - a) % n
            if 1 < gap <= max_gap + 1:
                for k in range(1, gap):
                    i = (a + k) % n
                    raw[i] = self._mean[a] + (self._mean[b] - self._mean[a]) * k / gap
                    filled[i] = True
        values = list(raw)
        for i in range(n):
            if filled[i]:
                reach = 1 if self._kink(raw, filled, i) else 2
                pairs = [
                    (reach + 1 - abs(k), raw[(i + k) % n])
                    for k in range(-reach, reach + 1)
                    if filled[(i + k) % n]
                ]
                values[i] = sum(w * v for w, v in pairs) / sum(w for w, _ in pairs)
        if self.params.symmetric:
            # Mirror about the axis (bin i and n-1-i are +-x): the track's own error
            # scatters a few scans' samples to one side, and a wide lobe's flat top
            # tilts by a few tenths of a dB, which moves the fit by degrees.
            both = [filled[i] and filled[n - 1 - i] for i in range(n)]
            values = [
                0.5 * (values[i] + values[n - 1 - i]) if both[i] else values[i] for i in range(n)
            ]
            filled = [filled[i] or filled[n - 1 - i] for i in range(n)]
            values = [
                values[i] if filled[i] or not filled[n - 1 - i] else values[n - 1 - i]
                for i in range(n)
            ]
        peak = max((i for i in range(n) if filled[i]), key=lambda i: values[i])
        floor = values[peak] + self.params.prior_floor_db
        self._known = self._lobe_extent(peak, filled)
        for step in (1, -1):
            last_v, last_p = values[peak], self._prior[peak]
            inside = True
            for k in range(1, n // 2 + (1 if step == 1 else 0)):
                i = (peak + step * k) % n
                inside = inside and filled[i]
                if self.params.bound_beyond and not inside:
                    values[i] = last_v  # a bound: at most the lobe's last learnt value
                elif filled[i]:
                    last_v, last_p = values[i], self._prior[i]
                else:
                    values[i] = max(min(last_v, self._prior[i] + last_v - last_p), floor)
        return values, filled

    def _kink(self, raw: list[float], filled: list[bool], i: int) -> bool:
        """Whether the slope turns sharply at bin i (a narrow lobe meeting its floor): the
        10 deg triangle would round that corner by a dB, so it is smoothed over 6 deg only.
        A lobe's own curvature turns the slope by a tenth of a dB per bin at most."""
        n = len(raw)
        ends = [(i + k) % n for k in (-3, 3)]
        if not all(filled[j] for j in ends):
            return False
        left_db = (raw[i] - raw[ends[0]]) / 3.0
        right_db = (raw[ends[1]] - raw[i]) / 3.0
        return abs(right_db - left_db) > self.params.kink_db_per_bin

    def _lobe_extent(self, peak: int, filled: list[bool]) -> tuple[float, float] | None:
        """The off-axis angles (deg) covered without a break round the peak, or None when
        that is the whole circle."""
        n = len(filled)
        ends = []
        for step in (-1, 1):
            k = 0
            while k < n // 2 and filled[(peak + step * (k + 1)) % n]:
                k += 1
            if k >= n // 2:
                return None
            ends.append(self._centres[peak] + step * k * self.params.bin_deg)
        return ends[0], ends[1]

    def _values(self) -> list[float]:
        if self._filled is None:
            self._filled = self._fill()[0]
        return self._filled

    def _bin(self, off_deg: float) -> int:
        i = int((wrap180(off_deg) + 180.0) / self.params.bin_deg)
        return min(i, len(self._centres) - 1)

    def value_db(self, off_deg: float) -> float:
        """The table at this off-axis angle (linear between bin centres, not normalised)."""
        x = (wrap180(off_deg) + 180.0) / self.params.bin_deg - 0.5
        i = math.floor(x)
        f = x - i
        v = self._values()
        n = len(v)
        return v[i % n] * (1.0 - f) + v[(i + 1) % n] * f

    def sure(self, angles_deg: Sequence[float], bearing_deg: float, sd_deg: float) -> bool:
        """Whether a scan with the track at (bearing, sd) may be learnt from."""
        p = self.params
        if not angles_deg or not math.isfinite(bearing_deg) or not sd_deg <= p.sure_sd_deg:
            return False
        lo, hi = min(angles_deg), max(angles_deg)
        return lo + p.edge_margin_deg <= bearing_deg <= hi - p.edge_margin_deg

    def add(
        self,
        angles_deg: Sequence[float],
        rssi_dbm: Sequence[float],
        bearing_deg: float,
        sd_deg: float,
    ) -> bool:
        """Learn from one finished scan, the track at `bearing_deg` +- `sd_deg` (the scan's
        frame); False (nothing learnt) when the scan is not sure or shows no main lobe."""
        if len(angles_deg) != len(rssi_dbm):
            raise ValueError(f"{len(angles_deg)} angles but {len(rssi_dbm)} RSSI values")
        if not self.sure(angles_deg, bearing_deg, sd_deg) or not all(map(math.isfinite, rssi_dbm)):
            self.refused += 1
            return False
        p = self.params
        offs = [bearing_deg - a for a in angles_deg]
        # The level from the samples the table puts near its peak: chosen by the table,
        # not by the readings (the loudest samples are the ones with the luckiest noise).
        top = max(self._values())
        model = [self.value_db(o) for o in offs]
        ranked = sorted(range(len(offs)), key=lambda i: -model[i])
        count = max(3, sum(1 for m in model if m >= top - p.level_window_db))
        near = [rssi_dbm[i] - model[i] for i in ranked[:count]]
        if len(near) < 3:
            self.refused += 1
            return False
        level = sum(near) / len(near) + top
        for o, y in zip(offs, rssi_dbm, strict=True):
            k = self._bin(o)
            w = min(self._weight[k] + 1.0, p.max_weight)
            self._mean[k] += (y - level - self._mean[k]) / w
            self._weight[k] = w
            self._samples[k] += 1
        self.scans += 1
        self._table = self._filled = None
        return True

    def _coverage(self) -> tuple[float, bool]:
        """Degrees of off-axis angle covered, and whether the table is covered
        `ready_half_deg` each side of its peak without a break."""
        values, filled = self._fill()
        n = len(values)
        peak = max(range(n), key=lambda i: values[i])
        reach = round(self.params.ready_half_deg / self.params.bin_deg)
        around = all(filled[(peak + k) % n] for k in range(-reach, reach + 1))
        return sum(filled) * self.params.bin_deg, around

    @property
    def ready(self) -> bool:
        return self.scans >= self.params.ready_scans and self._coverage()[1]

    def status(self) -> LearnStatus:
        degrees, around = self._coverage()
        ready = self.scans >= self.params.ready_scans and around
        return LearnStatus(self.scans, self.refused, degrees, ready)

    def pattern(self) -> AntennaPattern:
        """The learnt table as a pattern (normalised to its peak; rebuilt after new scans)."""
        if self._table is None:
            self._table = AntennaPattern(
                self._centres,
                tuple(self._values()),
                "learnt online",
                (("scans", str(self.scans)),),
                known_deg=self._known if self.params.bound_beyond else None,
            )
        return self._table
