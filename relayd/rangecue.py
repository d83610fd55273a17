"""How far is the leader at least? A lower bound on its distance from the front sonars.

RSSI^l cannot tell distance under shadowing: a relay standing in a spot 8-10 dB above the
path-loss median hears its leader "near" at 5-6 m and stands still on "leader_near" while
the leader walks away. The sonar ring in front of it tells better, in one direction:
every echo is the nearest surface inside its beam, so a leader whose centre lies inside a
beam is at least as far as that beam's echo. `leader_floor_m` turns the front ring and the
bearing filter's estimate (bearing, sd) into that bound; the controller's link rule
(docs/CONTROL.md section 5.3) uses it to keep following when the floor says "far".

What the floor means: if the leader's centre lies within `sigmas` standard deviations of
the bearing and no nearer than `near_m` to the robot's centre, then the distance between
the two centres is at least the floor. Why:

- Coverage. Seen from its transducer (offset from the robot's centre, drivers/arcos/
  sonar.py), a point moving out along a ray from the robot's centre turns monotonically,
  from where it is at `near_m` to the ray's own direction at infinity. So the ray is
  inside a beam from `near_m` on exactly when both ends are: `cover_deg` gives, per
  sonar, the interval of bearings it sees whole. The bearing interval must lie in the
  union of those intervals, else there is no floor (None).
- Bound. The leader's centre then lies in the beam of some sonar k whose cover interval
  overlaps the bearing interval. The segment from that transducer to the centre is inside
  the beam (a cone from its apex), so it crosses the leader's surface, which is at least
  `core_m` before the centre (a person is ~0.25 m deep, a P3-AT 0.5 m wide): the echo r_k
  is at most the transducer-to-centre distance less `core_m`. The front transducers look
  away from the robot's centre (t.u > 0 over every beam), so the distance from the robot's
  centre is at least min |t + (r_k + core_m) u| over the beam's directions u, which is at
  least r_k + core_m. The floor is the smallest of these over the overlapping sonars.
- No echo counts as the sonar's maximum range: nothing in that beam within 5 m.

What it does not cover: a leader nearer than `near_m` (the beams of the +-10 degree
sonars cross only 0.55 m ahead: nearer, straight ahead, is between them), a sonar that
misses the leader (a soft target at several metres, an echo lost to specular reflection):
the floor is then the range of whatever lies behind, or the maximum. The controller's
use of it says why that adds no new hazard (docs/CONTROL.md section 5.3). A sonar never
read is left out, so an unread ring gives no floor rather than "nothing there".
Pure: no I/O, no clock; angles in degrees in the robot frame, ccw positive; metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from drivers.arcos.sonar import SONAR_POSES
from relayd.estimator import (
    FRONT_RING,
    SONAR_HEADINGS_DEG,
    SONAR_MAX_RANGE_M,
    SonarReading,
    wrap_deg,
)

#: Half the beam of a P3-AT sonar (30 degrees wide): as the estimator's PRSSI uses it.
HALF_BEAM_DEG = 15.0
#: The bearing interval is the estimate +- this many of the filter's standard deviations.
SIGMAS = 2.0
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
        out.append(SonarReading(SONAR_HEADINGS_DEG[index], None if mm >= SONAR_MAX_RANGE_M * 1000 else mm / 1000.0,
                                index=index))
    return tuple(out)


def _transducer_m(index: int) -> tuple[float, float, float]:
    pose = SONAR_POSES[index]
    return pose.x_mm / 1000.0, pose.y_mm / 1000.0, pose.heading_deg


def _seen_from(tx: float, ty: float, bearing_deg: float, dist_m: float) -> float:
    """The direction (deg) from a transducer at (tx, ty) of the point at this bearing and distance."""
    b = math.radians(bearing_deg)
    return math.degrees(math.atan2(dist_m * math.sin(b) - ty, dist_m * math.cos(b) - tx))


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


def cover_deg(index: int, near_m: float = NEAR_M, half_beam_deg: float = HALF_BEAM_DEG) -> tuple[float, float]:
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


def centre_bound_m(index: int, range_m: float, core_m: float = CORE_M,
                   half_beam_deg: float = HALF_BEAM_DEG) -> float:
    """The least distance from the robot's centre of a leader's centre in sonar `index`'s beam
    when that sonar echoes at `range_m`: min |t + (range_m + core_m) u| over the beam's
    directions u, reached at an edge (t.u > 0 over the beam and varies as a cosine)."""
    tx, ty, heading = _transducer_m(index)
    s = range_m + core_m
    return min(math.hypot(tx + s * math.cos(a), ty + s * math.sin(a))
               for a in (math.radians(heading - half_beam_deg), math.radians(heading + half_beam_deg)))


def _covered(low: float, high: float, spans: list[tuple[float, float]]) -> bool:
    """[low, high] lies inside the union of the spans."""
    reach = low
    for lo, hi in sorted(spans):
        if lo > reach:
            break
        reach = max(reach, hi)
        if reach >= high:
            return True
    return reach >= high


def leader_floor_m(front: Sequence[SonarReading], bearing_deg: float | None, sd_deg: float | None, *,
                   sigmas: float = SIGMAS, near_m: float = NEAR_M, core_m: float = CORE_M,
                   half_beam_deg: float = HALF_BEAM_DEG) -> float | None:
    """A lower bound (m) on the distance from the robot's centre to the leader's centre, from
    the front sonars whose beams cover the bearing +- sigmas * sd; None when the bearing or
    its sd is unknown or not finite, or the interval is not wholly covered (see the module
    docstring for what the bound assumes). `front` holds only sonars that have been read
    (`known_front`); a reading with no index, or of the rear ring, is ignored."""
    if bearing_deg is None or sd_deg is None or not (math.isfinite(bearing_deg) and math.isfinite(sd_deg)):
        return None
    half = sigmas * max(sd_deg, 0.0)
    if half >= 180.0:
        return None
    b = wrap_deg(bearing_deg)
    low, high = b - half, b + half
    spans: list[tuple[float, float]] = []
    floor = math.inf
    for reading in front:
        if reading.index is None or reading.index not in FRONT_RING:
            continue
        lo, hi = cover_deg(reading.index, near_m, half_beam_deg)
        if lo > hi:
            continue
        spans.append((lo, hi))
        if lo <= high and hi >= low:
            r = reading.range_m
            r = SONAR_MAX_RANGE_M if r is None or not math.isfinite(r) or r >= SONAR_MAX_RANGE_M else max(r, 0.0)
            floor = min(floor, centre_bound_m(reading.index, r, core_m, half_beam_deg))
    if not _covered(low, high, spans) or not math.isfinite(floor):
        return None
    return floor


#: Once released, the relay keeps following until the floor falls this far below the gap
#: limit (sonar noise and the leader's own pace make the floor wander by ~0.1 m).
RELEASE_HYSTERESIS_M = 0.3
#: The release never drives slower than this (mm/s): a command the P3-AT executes.
CREEP_MM_S = 50.0


def far_by_sonar(floor_m: float | None, gap_max_m: float, was_released: bool) -> bool:
    """The sonar floor says the leader is beyond `gap_max_m` (0: the release is off); once
    released, until it falls `RELEASE_HYSTERESIS_M` below. No floor: not far."""
    if gap_max_m <= 0.0 or floor_m is None or not math.isfinite(floor_m):
        return False
    return floor_m >= gap_max_m - (RELEASE_HYSTERESIS_M if was_released else 0.0)


def release_speed_mm_s(threshold_l_dbm: float, w1: float, w2: float, v_max_mm_s: float) -> float:
    """The speed law's own speed at threshold_l (where the law was designed to stop: the
    leader's pace when the law is matched to it), kept within [CREEP_MM_S, v_max]."""
    v = -w1 * threshold_l_dbm - w2
    return min(max(v, CREEP_MM_S), v_max_mm_s)
