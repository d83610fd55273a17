"""The control law's settings (relayd.core.control.law), defaults as in docs/CONTROL.md 8.

One frozen record the config builds (relayd/config/params.py) and the brain hands to
the law, the escape, the search and recovery: every rear limit and speed bound is read
from it, never copied.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from relayd.core.avoid.state import AvoidParams
from relayd.core.control.actuator import Actuator
from relayd.core.control.search import SearchParams
from relayd.core.trail.blocked import BlockedParams


@dataclass(frozen=True, slots=True)
class ControlParams:
    """Controller settings; defaults as in docs/CONTROL.md section 8."""

    kp: float = 1.0
    kd: float = 0.3
    w1: float = 10.0
    w2: float = 150.0
    v_max_mm_s: float = 400.0
    threshold_l_dbm: float = -30.0
    threshold_b_dbm: float = -60.0
    hysteresis_db: float = 2.0
    rear_link_required: bool = True
    threshold_o_m: float = 0.8
    stop_distance_m: float = 0.3
    detect_range_m: float = 3.0
    gamma_o_m: float = 1.0
    sip_timeout_s: float = 0.5  # robot.lost_after_s
    #: No fresh RSSI sample for this long is a fault. The daemon sets max(0.5 s, 5 sample
    #: periods) from wifi.sample_hz (relayd/config/params.py): 0.5 s at the default 20 Hz.
    rssi_timeout_s: float = 0.5
    rear_timeout_s: float = 3.0  # RSSI^b older than this is stale
    manual_deadman_s: float = 0.5
    #: False: the paper's obstacle rule alone, no escape (config `control.escape`).
    escape: bool = True
    #: "leader_near" is overruled while the sonar floor says the leader is at least this
    #: far (m); 0 = off, the paper's rule alone (relayd/core/control/rangecue.py, docs/CONTROL.md 5.3).
    leader_gap_max_m: float = 0.0
    #: The escape when forward motion is blocked (relayd/core/avoid/escape.py); its stop
    #: distance and threshold_o are taken from the two fields above.
    avoid: AvoidParams = field(default_factory=AvoidParams)
    #: What VEL/RVEL can express; every follow-mode command is rounded to it here.
    actuator: Actuator = field(default_factory=Actuator)
    #: The turn toward a lost leader beyond the servo's reach (relayd/core/control/search.py).
    search: SearchParams = field(default_factory=SearchParams)
    #: Steer off a side wall nearer than this (m; 0: off), relayd/core/control/steer.py.
    side_keep_m: float = 0.35
    #: Steer no further into a wall within this of the side sonars than along it (m; 0: off).
    wall_slide_m: float = 1.5
    #: Situation 1 slows no lower than this share of the speed for echoes that cannot lie
    #: in the robot's forward path (0: by the nearest forward echo, the paper's), steer.py.
    beside_speed_floor: float = 0.3
    #: "bearing": at the scan bearing (the paper's); "trail": along the trail (docs 7.1).
    pursuit: str = "bearing"
    #: An escape no nearer the trail's head stops on "trail_blocked" (core/trail/blocked.py).
    trail_blocked: BlockedParams = field(default_factory=BlockedParams)
