"""Where is the leader? Pure estimation for one relay robot (docs/CONTROL.md sections 2-3).

Turns a finished Yagi scan (servo angle, RSSI and odometry heading per sample) and the
sonar ring into a bearing estimate: scan planning, the weighted centroid (WCA), the
two obstacle situations, the pseudo-RSSI (PRSSI) penalty and leader-lost counting.
Angles in degrees from the robot's forward axis, ccw +; sonar ranges in millimetres on
the wire, metres here; no echo is None or SONAR_MAX_RANGE_MM and up. The decisions (a
window shifted, not clipped, at a servo limit; which sonars are "front"; the larger of
two overlapping penalties, not their sum) are in docs/CONTROL.md sections 2-3.
No I/O, no clock, no logging.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from relayd.core.geometry import SONAR_HEADINGS_DEG, SONAR_MAX_RANGE_MM, wrap_deg

#: Scans in a row with RSSI^l below lost_rssi before the leader counts as lost (docs/CONTROL.md section 6).
LOST_AFTER_SCANS = 3

#: Sonars that count for d_min and the avoidance centroid (see the module docstring).
FRONT_SONARS: tuple[int, ...] = (1, 2, 3, 4, 5, 6)

#: The whole front ring, left side to right side: what PRSSI and `front_readings` use.
FRONT_RING: tuple[int, ...] = (0, 1, 2, 3, 4, 5, 6, 7)

SONAR_MAX_RANGE_M = SONAR_MAX_RANGE_MM / 1000.0

#: A reading looks sideways (not "front") from this absolute heading on.
_SIDEWAYS_DEG = 90.0


@dataclass(frozen=True, slots=True)
class ScanSample:
    """One scan sample: where the Yagi pointed, what it heard, where the robot faced."""

    angle_deg: float  # servo angle relative to the robot's forward axis when sampled (ccw +)
    rssi_dbm: float
    heading_deg: float  # robot odometry heading when sampled


@dataclass(frozen=True, slots=True)
class SonarReading:
    """One sonar in the robot frame."""

    heading_deg: float  # sonar heading in the robot frame (ccw +)
    range_m: float | None  # None = no echo (nothing within the sonar's 5 m)
    index: int | None = None  # the P3-AT sonar number, when known (its mounting pose)


@dataclass(frozen=True, slots=True)
class EstimatorParams:
    """Estimator settings; defaults as in docs/CONTROL.md section 8."""

    gamma: float = 10.0
    threshold_o_m: float = 0.8
    detect_range_m: float = 3.0
    alpha_db: float = 30.0
    beta_per_m: float = 1.0
    gamma_o_m: float = 1.0
    beam_half_width_deg: float = 15.0


@dataclass(frozen=True, slots=True)
class ScanEstimate:
    """What one finished scan says about the leader."""

    bearing_deg: float  # robot frame at the scan's end
    rssi_leader_dbm: float  # best raw RSSI of the scan (RSSI^l)
    situation: int  # 0, 1 or 2 from the sonars at scan end
    angles_deg: tuple[float, ...]  # sample angles in the robot frame at scan end
    rssi_dbm: tuple[float, ...]  # raw
    nrssi_dbm: tuple[float, ...]  # after the PRSSI penalty (== raw when situation != 2)
    #: The bearing's standard deviation when a tracking filter made it (None: the WCA has none).
    bearing_sd_deg: float | None = None


def _finite(name: str, value: float) -> None:
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")


def plan_scan(
    center_deg: float,
    width_deg: float,
    samples: int,
    limits_deg: tuple[float, float],
    ascending: bool,
) -> tuple[float, ...]:
    """The servo angles of the next sweep: `samples` evenly spaced angles, both ends included."""
    lo, hi = limits_deg
    for name, value in (
        ("center_deg", center_deg),
        ("width_deg", width_deg),
        ("limits", lo),
        ("limits", hi),
    ):
        _finite(name, value)
    if samples < 1:
        raise ValueError(f"samples must be >= 1, got {samples}")
    if width_deg < 0:
        raise ValueError(f"width_deg must be >= 0, got {width_deg}")
    if lo > hi:
        raise ValueError(f"limits_deg must be (low, high), got {limits_deg}")
    if samples == 1:
        return (min(max(center_deg, lo), hi),)
    start, end = center_deg - width_deg / 2.0, center_deg + width_deg / 2.0
    if width_deg >= hi - lo:
        start, end = lo, hi
    elif start < lo:
        start, end = lo, lo + width_deg
    elif end > hi:
        start, end = hi - width_deg, hi
    step = (end - start) / (samples - 1)
    # The last angle is set exactly so the sweep really reaches its end (no rounding drift).
    angles = [start + i * step for i in range(samples - 1)] + [end]
    angles = [min(max(a, lo), hi) for a in angles]
    if not ascending:
        angles.reverse()
    return tuple(angles)


def wca_bearing(angles_deg: Sequence[float], rssi_dbm: Sequence[float], gamma: float) -> float:
    """Weighted centroid of the scan angles, w_j = 10^((RSSI_j - max) / gamma)."""
    if len(angles_deg) == 0:
        raise ValueError("wca_bearing needs at least one sample")
    if len(angles_deg) != len(rssi_dbm):
        raise ValueError(f"{len(angles_deg)} angles but {len(rssi_dbm)} RSSI values")
    if not (gamma > 0 and math.isfinite(gamma)):
        raise ValueError(f"gamma must be a positive number, got {gamma!r}")
    for a in angles_deg:
        _finite("angle", a)
    for r in rssi_dbm:
        _finite("rssi", r)
    best = max(rssi_dbm)
    lo, hi = min(angles_deg), max(angles_deg)
    weight_sum = 0.0
    moment = 0.0
    for angle, rssi in zip(angles_deg, rssi_dbm, strict=True):
        # (rssi - best) can only overflow to -inf for absurd inputs; 10 ** -inf is 0.0.
        weight = 10.0 ** ((rssi - best) / gamma)
        weight_sum += weight
        # Moments about the smallest angle keep the sum small and the result in range.
        moment += weight * (angle - lo)
    return min(max(lo + moment / weight_sum, lo), hi)


def to_robot_frame(samples: Sequence[ScanSample], heading_end_deg: float) -> tuple[float, ...]:
    """Each sample's angle in the robot frame at the scan's end: theta_j + heading_j - heading_end."""
    _finite("heading_end_deg", heading_end_deg)
    out = []
    for s in samples:
        _finite("angle_deg", s.angle_deg)
        _finite("heading_deg", s.heading_deg)
        out.append(wrap_deg(s.angle_deg + s.heading_deg - heading_end_deg))
    return tuple(out)


def _is_forward(reading: SonarReading) -> bool:
    return abs(wrap_deg(reading.heading_deg)) < _SIDEWAYS_DEG


def _in_front_ring(reading: SonarReading) -> bool:
    # Rear sonars 9..14 look backwards; they never touch the scan (the Yagi covers +-90).
    return abs(wrap_deg(reading.heading_deg)) <= _SIDEWAYS_DEG


def _echo_m(reading: SonarReading) -> float | None:
    """The reading's range in metres, or None when nothing echoed within reach."""
    if reading.range_m is None:
        return None
    if math.isnan(reading.range_m) or reading.range_m < 0:
        raise ValueError(f"sonar range must be >= 0 m or None, got {reading.range_m!r}")
    if reading.range_m >= SONAR_MAX_RANGE_M:
        return None
    return reading.range_m


def nearest_front_m(front: Sequence[SonarReading]) -> float | None:
    """d_min: the nearest echo among the forward-looking sonars, None when none echoed."""
    ranges = [d for r in front if _is_forward(r) and (d := _echo_m(r)) is not None]
    return min(ranges) if ranges else None


def classify_situation(
    front: Sequence[SonarReading], threshold_o_m: float, detect_range_m: float
) -> int:
    """0: free; 1: d_min < threshold_o (avoid); 2: something in [threshold_o, detect_range) (PRSSI)."""
    d_min = nearest_front_m(front)
    if d_min is not None and d_min < threshold_o_m:
        return 1
    for reading in front:
        d = _echo_m(reading) if _in_front_ring(reading) else None
        if d is not None and threshold_o_m <= d < detect_range_m:
            return 2
    return 0


def avoidance_bearing(
    front: Sequence[SonarReading], gamma_o_m: float, max_range_m: float = 5.0
) -> float:
    """Centroid of the forward sonar headings, w_k = 10^(d_k / gamma_o): steer to open space."""
    if not (gamma_o_m > 0 and math.isfinite(gamma_o_m)):
        raise ValueError(f"gamma_o_m must be a positive number, got {gamma_o_m!r}")
    forward = [r for r in front if _is_forward(r)]
    if not forward:
        raise ValueError("avoidance_bearing needs at least one forward-looking sonar")
    ranges = []
    for r in forward:
        d = _echo_m(r)
        # No echo means open space as far as the sonar can tell: the maximum range.
        ranges.append(max_range_m if d is None else min(d, max_range_m))
    far = max(ranges)
    weight_sum = 0.0
    moment = 0.0
    for reading, d in zip(forward, ranges, strict=True):
        weight = 10.0 ** ((d - far) / gamma_o_m)  # max-subtracted, like the WCA
        weight_sum += weight
        moment += weight * wrap_deg(reading.heading_deg)
    return moment / weight_sum


def prssi_db(distance_m: float, alpha_db: float, beta_per_m: float) -> float:
    """Pseudo-RSSI penalty alpha * exp(-beta * d): large for near objects."""
    _finite("distance_m", distance_m)
    if distance_m < 0:
        raise ValueError(f"distance_m must be >= 0, got {distance_m}")
    return alpha_db * math.exp(-beta_per_m * distance_m)


def apply_prssi(
    angles_deg: Sequence[float],
    rssi_dbm: Sequence[float],
    obstacles: Sequence[SonarReading],
    params: EstimatorParams,
) -> tuple[float, ...]:
    """NRSSI: each sample minus the largest PRSSI of the sonars whose beam contains its angle.

    Only sonars whose range is in [threshold_o, detect_range) penalise.
    """
    if len(angles_deg) != len(rssi_dbm):
        raise ValueError(f"{len(angles_deg)} angles but {len(rssi_dbm)} RSSI values")
    active = []
    for reading in obstacles:
        d = _echo_m(reading) if _in_front_ring(reading) else None
        if d is not None and params.threshold_o_m <= d < params.detect_range_m:
            active.append((reading.heading_deg, prssi_db(d, params.alpha_db, params.beta_per_m)))
    out = []
    for angle, rssi in zip(angles_deg, rssi_dbm, strict=True):
        penalty = 0.0
        for heading, p in active:
            if abs(wrap_deg(angle - heading)) <= params.beam_half_width_deg:
                penalty = max(penalty, p)
        out.append(rssi - penalty)
    return tuple(out)


def estimate_scan(
    samples: Sequence[ScanSample],
    heading_end_deg: float,
    sonar: Sequence[SonarReading],
    params: EstimatorParams,
) -> ScanEstimate:
    """The bearing, RSSI^l and situation of one finished scan (pass `front_readings(...)` as sonar)."""
    if not samples:
        raise ValueError("estimate_scan needs at least one sample")
    angles = to_robot_frame(samples, heading_end_deg)
    raw = tuple(float(s.rssi_dbm) for s in samples)
    situation = classify_situation(sonar, params.threshold_o_m, params.detect_range_m)
    nrssi = apply_prssi(angles, raw, sonar, params) if situation == 2 else raw
    bearing = wca_bearing(angles, nrssi, params.gamma)
    return ScanEstimate(
        bearing_deg=bearing,
        rssi_leader_dbm=max(raw),
        situation=situation,
        angles_deg=angles,
        rssi_dbm=raw,
        nrssi_dbm=nrssi,
    )


def update_lost_count(count: int, rssi_leader_dbm: float, lost_rssi_dbm: float) -> int:
    """Scans in a row with RSSI^l below lost_rssi; lost once it reaches LOST_AFTER_SCANS."""
    _finite("rssi_leader_dbm", rssi_leader_dbm)
    if rssi_leader_dbm < lost_rssi_dbm:
        return max(count, 0) + 1
    return 0


def front_readings(ranges_mm: Sequence[int | None]) -> tuple[SonarReading, ...]:
    """The 16 ring ranges in mm (index order, None = never read) -> the front ring 0..7 in metres."""
    if len(ranges_mm) != len(SONAR_HEADINGS_DEG):
        raise ValueError(f"expected {len(SONAR_HEADINGS_DEG)} sonar ranges, got {len(ranges_mm)}")
    out = []
    for index in FRONT_RING:
        mm = ranges_mm[index]
        if mm is not None and mm < 0:
            raise ValueError(f"sonar {index} range must be >= 0 mm, got {mm}")
        range_m = None if mm is None or mm >= SONAR_MAX_RANGE_MM else mm / 1000.0
        out.append(
            SonarReading(heading_deg=SONAR_HEADINGS_DEG[index], range_m=range_m, index=index)
        )
    return tuple(out)
