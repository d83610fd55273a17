"""Domain facts about angles and the P3-AT's body, each defined once.

- `wrap_deg`: the one angle-wrap convention, (-180, 180]. It returns an angle already in
  range unchanged, bit for bit, which `(a + 180) % 360 - 180` does not. It is defined with
  the robot's odometry (drivers.arcos.sip), which the drivers cannot import from here.
  `wrap_rad` is the same convention in radians, (-pi, pi], for the core's filters.
- The sonar ring: the mounting poses are the device's own fact and live with its driver
  (drivers.arcos.sonar, which decodes the SIP's sonar readings); here they are re-exported
  with what the core, the drivers' fake and the simulator derive from them.
- The footprint: the P3-AT's length and width, and the radii the simulator and the
  escape build on.
"""

from __future__ import annotations

import math

from drivers.arcos.sip import wrap_deg
from drivers.arcos.sonar import SONAR_POSES, SonarPose

#: The ring's 16 transducers, in the SIP's index order (docs/PROTOCOLS.md 1.11).
SONAR_COUNT = len(SONAR_POSES)
#: Their headings in the robot frame, ccw +.
SONAR_HEADINGS_DEG: tuple[float, ...] = tuple(float(p.heading_deg) for p in SONAR_POSES)
#: The sonar's reach; a reading at or beyond it is "no echo".
SONAR_MAX_RANGE_MM = 5000

#: The P3-AT's footprint (m): 626 mm long, 505 mm wide.
ROBOT_LENGTH_M = 0.626
ROBOT_WIDTH_M = 0.505
#: Half the width: footprint side to centreline.
HALF_WIDTH_M = ROBOT_WIDTH_M / 2.0
#: Half the length: the centre of rotation to the front or rear edge.
HALF_LENGTH_M = ROBOT_LENGTH_M / 2.0
#: The circle a turn in place sweeps.
ROBOT_RADIUS_M = math.hypot(ROBOT_LENGTH_M, ROBOT_WIDTH_M) / 2.0


def wrap_rad(angle_rad: float) -> float:
    """An angle in radians wrapped to (-pi, pi]: `wrap_deg`'s convention and code in radians
    (an angle already in range comes back bit for bit)."""
    a = math.fmod(angle_rad, math.tau)
    if a <= -math.pi:
        a += math.tau
    elif a > math.pi:
        a -= math.tau
    return a


__all__ = [
    "HALF_LENGTH_M",
    "HALF_WIDTH_M",
    "ROBOT_LENGTH_M",
    "ROBOT_RADIUS_M",
    "ROBOT_WIDTH_M",
    "SONAR_COUNT",
    "SONAR_HEADINGS_DEG",
    "SONAR_MAX_RANGE_MM",
    "SONAR_POSES",
    "SonarPose",
    "wrap_deg",
    "wrap_rad",
]
