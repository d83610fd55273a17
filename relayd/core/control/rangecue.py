"""How far is the leader at least? A lower bound on its distance from the front sonars.

RSSI^l cannot tell distance under shadowing; the sonar ring can bound it from below:
whatever lies inside a beam is at least as far as that beam's echo. `leader_floor_m`
turns the front ring and the tracking filter's estimate into such a floor, offered only
when every front sonar has been read, the filter is sure (sd at most 10 degrees) and
the estimate +- max(2 sd, 20 degrees) lies inside the fan the ring sees whole
(`cover_deg`). The controller's link rule keeps following past "leader_near" while the
floor says "far". Why the floor holds, the margins and what it does not cover:
docs/CONTROL.md section 5.3. Pure: angles in degrees in the robot frame, ccw +; metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import cache

from relayd.core.geometry import SONAR_HEADINGS_DEG, SONAR_POSES, wrap_deg
from relayd.core.scan.estimator import FRONT_RING, SONAR_MAX_RANGE_M, SonarReading

#: Half the beam of a P3-AT sonar (30 degrees wide): as the estimator's PRSSI uses it.
HALF_BEAM_DEG = 15.0
#: The leader is believed within the estimate +- this many of the filter's standard deviations ...
SIGMAS = 2.0
#: ... but never narrower than +- this (see the module docstring).
MIN_HALF_DEG = 20.0
#: ... and only while the filter is sure of itself: its sd at most this (the tracker calls
#: a track confident at 8 degrees).
MAX_SD_DEG = 10.0
#: The floor speaks for a leader whose centre is at least this far from the robot's centre.
#: Nearer, its near surface would be within 0.36 m of the front transducers (0.245 m out),
#: inside threshold_o, where the obstacle rule and the guard govern. From 0.7 m on the
#: covers of neighbouring sonars overlap by at least 1.4 degrees (at 0.6 m the 30 and 50
#: degree sonars leave a 0.05 degree sliver at +-35 degrees uncovered).
NEAR_M = 0.7
#: The least distance from a leader's centre to its near surface: a person seen edge-on
#: is ~0.25 m deep, a P3-AT 0.5 m wide and 0.63 m long.
CORE_M = 0.1


def known_front(ranges_mm: Sequence[int | None]) -> tuple[SonarReading, ...]:
    """The front ring (0..7) in metres, index order, leaving out a sonar never read (None),
    so "never read" is never taken for "no echo"; a range at or beyond 5 m is no echo."""
    out = []
    for index in FRONT_RING:
        mm = ranges_mm[index] if index < len(ranges_mm) else None
        if mm is None or mm < 0:
            continue
        out.append(
            SonarReading(
                SONAR_HEADINGS_DEG[index],
                None if mm >= SONAR_MAX_RANGE_M * 1000 else mm / 1000.0,
                index=index,
            )
        )
    return tuple(out)


def _transducer_m(index: int) -> tuple[float, float, float]:
    pose = SONAR_POSES[index]
    return pose.x_mm / 1000.0, pose.y_mm / 1000.0, pose.heading_deg


def _bearing_at(tx: float, ty: float, dir_deg: float, dist_m: float) -> float | None:
    """The bearing (deg, from the robot's centre) of the point `dist_m` from the centre that the
    transducer at (tx, ty) sees in direction `dir_deg`; None if that ray misses the circle."""
    vx, vy = math.cos(math.radians(dir_deg)), math.sin(math.radians(dir_deg))
    tv = tx * vx + ty * vy
    disc = tv * tv - (tx * tx + ty * ty) + dist_m * dist_m
    if disc < 0.0:
        return None
    s = -tv + math.sqrt(disc)
    return math.degrees(math.atan2(ty + s * vy, tx + s * vx))


def cover_deg(
    index: int, near_m: float = NEAR_M, half_beam_deg: float = HALF_BEAM_DEG
) -> tuple[float, float]:
    """(low, high): the bearings whose whole ray from `near_m` outwards lies inside sonar
    `index`'s beam; low > high when there are none."""
    tx, ty, heading = _transducer_m(index)
    lo_inf, hi_inf = heading - half_beam_deg, heading + half_beam_deg
    # The beam's edges met on the circle of radius near_m, as bearings from the centre.
    lo_near = _bearing_at(tx, ty, heading - half_beam_deg, near_m)
    hi_near = _bearing_at(tx, ty, heading + half_beam_deg, near_m)
    if lo_near is None or hi_near is None:
        return 0.0, -1.0
    lo = max(lo_inf, heading + wrap_deg(lo_near - heading))
    hi = min(hi_inf, heading + wrap_deg(hi_near - heading))
    return lo, hi


def centre_bound_m(
    index: int, range_m: float, core_m: float = CORE_M, half_beam_deg: float = HALF_BEAM_DEG
) -> float:
    """The least distance from the robot's centre of a leader's centre in sonar `index`'s beam
    when that sonar echoes at `range_m`: min |t + (range_m + core_m) u| over the beam's
    directions u, reached at an edge (t.u > 0 over the beam and varies as a cosine)."""
    tx, ty, heading = _transducer_m(index)
    s = range_m + core_m
    return min(
        math.hypot(tx + s * math.cos(a), ty + s * math.sin(a))
        for a in (math.radians(heading - half_beam_deg), math.radians(heading + half_beam_deg))
    )


@cache
def fan_deg(
    near_m: float = NEAR_M, half_beam_deg: float = HALF_BEAM_DEG
) -> tuple[tuple[float, float], ...]:
    """The front fan: the bearings some front-ring sonar sees whole from `near_m` out, as
    sorted, merged intervals."""
    spans = sorted(
        span
        for span in (cover_deg(i, near_m, half_beam_deg) for i in FRONT_RING)
        if span[0] <= span[1]
    )
    merged: list[tuple[float, float]] = []  # cached: the ring's geometry does not change
    for lo, hi in spans:
        if merged and lo <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], hi))
        else:
            merged.append((lo, hi))
    return tuple(merged)


def leader_floor_m(
    front: Sequence[SonarReading],
    bearing_deg: float | None,
    sd_deg: float | None,
    *,
    sigmas: float = SIGMAS,
    min_half_deg: float = MIN_HALF_DEG,
    max_sd_deg: float = MAX_SD_DEG,
    near_m: float = NEAR_M,
    core_m: float = CORE_M,
    half_beam_deg: float = HALF_BEAM_DEG,
) -> float | None:
    """A lower bound (m) on the distance from the robot's centre to the leader's centre,
    `centre_bound_m` over the whole front ring; None when the bearing or its sd is unknown
    or not finite, when sd > max_sd_deg, when bearing +- max(sigmas * sd, min_half_deg)
    is not inside the front fan, or when a front-ring sonar is missing from `front` (never read: `known_front`).
    See the module docstring for what the bound assumes."""
    if (
        bearing_deg is None
        or sd_deg is None
        or not (math.isfinite(bearing_deg) and math.isfinite(sd_deg))
    ):
        return None
    if sd_deg > max_sd_deg:
        return None
    by_index = {r.index: r.range_m for r in front if r.index is not None}
    if any(i not in by_index for i in FRONT_RING):
        return None
    half = max(sigmas * sd_deg, min_half_deg, 0.0)
    b = wrap_deg(bearing_deg)
    if not any(lo <= b - half and b + half <= hi for lo, hi in fan_deg(near_m, half_beam_deg)):
        return None
    floor = math.inf
    for i in FRONT_RING:
        r = by_index[i]
        r = (
            SONAR_MAX_RANGE_M
            if r is None or not math.isfinite(r) or r >= SONAR_MAX_RANGE_M
            else max(r, 0.0)
        )
        floor = min(floor, centre_bound_m(i, r, core_m, half_beam_deg))
    return floor


#: Once released, the relay keeps following until the floor falls this far below the gap
#: limit (sonar noise and the leader's own pace make the floor wander by ~0.1 m).
RELEASE_HYSTERESIS_M = 0.3
#: The release never drives slower than this (mm/s): a command the P3-AT executes.
CREEP_MM_S = 50.0
#: No release while RSSI^l is this far (dB) or more above threshold_l: the bright spots the
#: release is for were 8-10 dB above the path-loss median (2-2.5 sigma of 4 dB shadowing),
#: and threshold_l is about the median at the stop distance, so a leader beyond the gap
#: limit heard louder than this is rarer than those spots; what it mostly means is a leader
#: really close that the sonars miss, which the release must not drive into
#: (docs/CONTROL.md 5.3).
RELEASE_MAX_ABOVE_DB = 10.0


def far_by_sonar(
    floor_m: float | None,
    gap_max_m: float,
    was_released: bool,
    rssi_leader_dbm: float,
    threshold_l_dbm: float,
) -> bool:
    """The sonar floor says the leader is beyond `gap_max_m` (0: the release is off); once
    released, until it falls `RELEASE_HYSTERESIS_M` below. No floor, or RSSI^l at least
    `RELEASE_MAX_ABOVE_DB` above threshold_l (too loud for a far leader): not far."""
    if gap_max_m <= 0.0 or floor_m is None or not math.isfinite(floor_m):
        return False
    if not rssi_leader_dbm < threshold_l_dbm + RELEASE_MAX_ABOVE_DB:
        return False
    return floor_m >= gap_max_m - (RELEASE_HYSTERESIS_M if was_released else 0.0)


def release_speed_mm_s(threshold_l_dbm: float, w1: float, w2: float, v_max_mm_s: float) -> float:
    """The speed law's own speed at threshold_l (where the law was designed to stop: the
    leader's pace when the law is matched to it), kept within [CREEP_MM_S, v_max]."""
    v = -w1 * threshold_l_dbm - w2
    return min(max(v, CREEP_MM_S), v_max_mm_s)
