"""The P3-AT's 16-sonar ring: mounting poses, latest range per sonar, derived views.

Ranges are mm from the transducer face as ARCOS reports them. A reading at or above
`NO_ECHO_MM` (5000 mm, ARIA's maximum) means no echo came back: it counts as "read"
(the sonar is alive and saw nothing within range) but yields no obstacle point.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from drivers.arcos.sip import NO_ECHO_MM

SONAR_COUNT = 16
FRONT_SONARS = range(8)
REAR_SONARS = range(8, 16)


@dataclass(frozen=True, slots=True)
class SonarPose:
    """Mounting pose in the robot frame: x forward, y left (mm), heading ccw + (deg)."""

    x_mm: float
    y_mm: float
    heading_deg: float


#: ARIA params/p3at.p == ArRobotTypes.cpp == MobileSim p3at (docs/PROTOCOLS.md 1.11).
SONAR_POSES: tuple[SonarPose, ...] = (
    SonarPose(147, 136, 90),
    SonarPose(193, 119, 50),
    SonarPose(227, 79, 30),
    SonarPose(245, 27, 10),
    SonarPose(245, -27, -10),
    SonarPose(227, -79, -30),
    SonarPose(193, -119, -50),
    SonarPose(147, -136, -90),
    SonarPose(-144, -136, -90),
    SonarPose(-189, -119, -130),
    SonarPose(-223, -79, -150),
    SonarPose(-241, -27, -170),
    SonarPose(-241, 27, 170),
    SonarPose(-223, 79, 150),
    SonarPose(-189, 119, 130),
    SonarPose(-144, 136, 90),
)


@dataclass(frozen=True, slots=True)
class SonarPoint:
    """One echo in the robot frame, and as seen from the robot centre."""

    index: int
    x_mm: float
    y_mm: float
    angle_deg: float  # bearing from the robot centre, ccw +
    distance_mm: float  # from the robot centre


def reading_point(index: int, range_mm: float) -> SonarPoint:
    """Where a reading of `range_mm` on sonar `index` puts the obstacle (robot frame)."""
    pose = SONAR_POSES[index]
    h = math.radians(pose.heading_deg)
    x = pose.x_mm + range_mm * math.cos(h)
    y = pose.y_mm + range_mm * math.sin(h)
    return SonarPoint(index, x, y, math.degrees(math.atan2(y, x)), math.hypot(x, y))


class SonarRing:
    """Latest range and arrival time per sonar; only sonars present in a SIP are updated."""

    __slots__ = ("ignored", "ranges_mm", "updated_t")

    def __init__(self) -> None:
        self.ranges_mm: list[int | None] = [None] * SONAR_COUNT
        self.updated_t: list[float | None] = [None] * SONAR_COUNT
        self.ignored = 0  # readings for sonar numbers this ring does not have

    def update(self, readings: Iterable[tuple[int, int]], t: float) -> None:
        for index, range_mm in readings:
            if 0 <= index < SONAR_COUNT:
                self.ranges_mm[index] = min(int(range_mm), NO_ECHO_MM)
                self.updated_t[index] = t
            else:
                self.ignored += 1

    def has_echo(self, index: int) -> bool:
        r = self.ranges_mm[index]
        return r is not None and r < NO_ECHO_MM

    def age_s(self, index: int, now: float) -> float | None:
        t = self.updated_t[index]
        return None if t is None else max(0.0, now - t)

    def front_min_mm(
        self, *, max_age_s: float | None = None, now: float | None = None
    ) -> int | None:
        """Nearest front-ring range (sonars 0-7); `NO_ECHO_MM` if they all saw nothing.

        None when no front sonar has a (fresh enough) reading at all.
        """
        best: int | None = None
        for i in FRONT_SONARS:
            r = self.ranges_mm[i]
            if r is None:
                continue
            if max_age_s is not None and now is not None:
                age = self.age_s(i, now)
                if age is None or age > max_age_s:
                    continue
            best = r if best is None else min(best, r)
        return best

    def points(self, indices: Iterable[int] = range(SONAR_COUNT)) -> list[SonarPoint]:
        """Obstacle points in the robot frame for the sonars that have an echo."""
        return [
            reading_point(i, r)
            for i in indices
            if (r := self.ranges_mm[i]) is not None and r < NO_ECHO_MM
        ]

    def clear(self) -> None:
        self.ranges_mm = [None] * SONAR_COUNT
        self.updated_t = [None] * SONAR_COUNT
