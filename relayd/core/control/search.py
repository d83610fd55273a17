"""A lost relay whose leader is probably behind it turns in place to find it.

While the leader is lost and the tracking filter's last evidence (`search_bearing`) put
it at or beyond a servo limit, at least `min_bearing_deg` off the nose, `search_step`
turns the relay in place toward that side at `rate_deg_s` until the evidence is ahead or
the leader is found; an episode is bounded by `max_turn_deg` and its time. Evidence
within the sweep gets no turn. It promises: every command keeps each wheel within v_max
and passes `relayd.core.avoid.ring.guard` (no turn without room). Why and what it
measured: docs/CONTROL.md section 6.1. Pure: time and heading come in as arguments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from relayd.core.avoid.ring import guard
from relayd.core.control.actuator import Actuator
from relayd.core.geometry import wrap_deg
from relayd.core.scan.estimator import SonarReading


@dataclass(frozen=True, slots=True)
class SearchParams:
    """The turn toward a lost leader (config `control.search_*`, docs/CONTROL.md section 6.1)."""

    #: False: a lost relay stands, as the paper's does.
    enabled: bool = True
    #: The in-place turn rate (deg/s): slow enough that a full-range sweep (2.5 s) is not
    #: smeared beyond a lobe fit, and safe in a corridor with people in it.
    rate_deg_s: float = 25.0
    #: Evidence at least this far off the nose (deg) starts a search.
    min_bearing_deg: float = 60.0
    #: One full turn, then stand.
    max_turn_deg: float = 360.0

    def __post_init__(self) -> None:
        for name in ("rate_deg_s", "min_bearing_deg", "max_turn_deg"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"search {name} must be a positive number, got {v!r}")


@dataclass(frozen=True, slots=True)
class SearchState:
    """One lost episode's search: which way, how far, since when."""

    #: +1 turning left (ccw), -1 right; 0 not turning.
    side: int = 0
    turned_deg: float = 0.0
    heading_deg: float | None = None
    started_t: float | None = None
    #: The turn is over (found nothing within its bounds): stand until the leader is found.
    done: bool = False


def search_step(
    state: SearchState,
    bearing_deg: float | None,
    heading_deg: float | None,
    t_s: float | None,
    params: SearchParams,
) -> tuple[SearchState, float]:
    """(the new state, the turn rate to ask for in deg/s, 0: stand) for one step while lost."""
    if (
        not params.enabled
        or state.done
        or heading_deg is None
        or t_s is None
        or not (math.isfinite(heading_deg) and math.isfinite(t_s))
    ):
        return state, 0.0
    b = bearing_deg if bearing_deg is not None and math.isfinite(bearing_deg) else None
    side = state.side
    if b is not None and abs(b) >= params.min_bearing_deg:
        side = 1 if b > 0 else -1  # new evidence beyond reach: that way (at the start, or it moved)
    if side == 0:
        return state, 0.0
    last = state.heading_deg if state.heading_deg is not None else heading_deg
    turned = state.turned_deg + abs(wrap_deg(heading_deg - last))
    started = state.started_t if state.started_t is not None else t_s
    if (
        turned >= params.max_turn_deg
        or t_s - started >= 1.5 * params.max_turn_deg / params.rate_deg_s
    ):
        return SearchState(done=True), 0.0
    # Until the last evidence is ahead; then the full sweeps look there, standing still.
    ahead = b is None or side * b <= 0.0
    return SearchState(
        side, turned, heading_deg, started
    ), 0.0 if ahead else side * params.rate_deg_s


def search_wheels(
    rvel_deg_s: float,
    act: Actuator,
    front: tuple[SonarReading, ...],
    rear: tuple[SonarReading, ...],
    stop_distance_m: float,
    v_max_mm_s: float,
) -> tuple[float, float]:
    """(left, right) mm/s of the turn in place, as the actuator, the per-wheel limit
    `v_max_mm_s` (as every follow-mode command) and the guard allow it."""
    if rvel_deg_s == 0.0:
        return 0.0, 0.0
    _, rvel = act.within(0, act.turn(rvel_deg_s), v_max_mm_s)
    _, rvel = guard(0, rvel, front, stop_distance_m, rear)
    return act.wheels(0.0, float(rvel))
