"""Where the next sweep looks: the sweep's geometry (`ScanParams`), the window rule, and
bearings carried from the robot frame they were measured in to today's.

Pure: no I/O, no clock, no memory. The brain's scan memory (relayd/core/scan/memory.py) calls
it with what it knows: whether the leader is lost, what the bearing model
(relayd/core/scan/leader.py) plans, and the bearing it steers by.
"""

from __future__ import annotations

from dataclasses import dataclass

from relayd.core.events import ScanPlan
from relayd.core.geometry import wrap_deg
from relayd.core.scan.estimator import plan_scan
from relayd.core.scan.window import Window


@dataclass(frozen=True, slots=True)
class ScanParams:
    """The sweep geometry and leader-lost level."""

    scan_channel: int = 0
    link_channel: int = 1
    samples: int = 13
    width_deg: float = 60.0
    limits_deg: tuple[float, float] = (-90.0, 90.0)
    lost_rssi_dbm: float = -85.0
    #: No completed scan for this long (once a bearing exists) stops the wheels; None: no rule.
    scan_timeout_s: float | None = None


def in_current_frame(
    bearing: float | None, heading_then: float | None, heading_now: float | None
) -> float | None:
    """A bearing measured in an earlier robot frame, seen from the robot's heading now."""
    if bearing is None:
        return None
    if heading_then is None or heading_now is None:
        return bearing
    b = bearing - (heading_now - heading_then)
    return wrap_deg(b)


def full_window(sp: ScanParams) -> Window:
    """The servo's whole range, at the configured number of samples."""
    lo, hi = sp.limits_deg
    return Window((lo + hi) / 2.0, hi - lo, sp.samples)


def next_window(
    sp: ScanParams, lost: bool, planned: Window | None, bearing_deg: float | None
) -> Window:
    """The full servo range when the leader is lost, else the bearing model's plan, else the
    configured width centred on the bearing (straight ahead before the first scan)."""
    if lost:
        return full_window(sp)
    if planned is not None:
        return planned
    return Window(0.0 if bearing_deg is None else bearing_deg, sp.width_deg, sp.samples)


def sweep_plan(sp: ScanParams, window: Window, ascending: bool) -> ScanPlan:
    """The servo angles of one sweep over `window`, clipped to the limits, in this direction."""
    return ScanPlan(
        plan_scan(window.centre_deg, window.width_deg, window.samples, sp.limits_deg, ascending)
    )
