"""A lost relay whose leader is probably behind it turns in place to find it.

The pan servo reaches +-90 deg; a leader the relay has passed (two robots meeting at
a corner, the truth sweeping from ahead to behind in a few seconds) is beyond it, where
no scan can see a lobe. Standing still and widening, as a lost relay otherwise does,
then waits for a leader that may never walk back into view (30 % of a convoy run in
one case). So while the leader is lost and the last evidence of it put it at or
beyond a servo limit (the tracking filter's `search_bearing`: the last lobe fit there,
however unsure, or the strongest sample at a limit when it is at least lost_rssi; at
most a few scan periods old; carried into today's frame) and is
still at least `min_bearing_deg` off the nose, the relay turns in place toward that
side at `rate_deg_s`, the full-range scans running meanwhile, until the evidence is
ahead (then it stands, and the sweeps look there without a turn smearing them), until
the leader is found (no longer lost). New evidence beyond `min_bearing_deg` (a later
scan's fit, however unsure) turns it that way. An episode lasts at most
`max_turn_deg` of odometry heading or the time that takes at `rate_deg_s` plus half
(so a turn the guard keeps refusing ends too); then wheels zero, as before, until the
leader is found again.

Evidence within the sweep gets no turn (the model gives none): the servo's full sweep
covers it, and a turn would only smear those scans and take the relay off its line.
Every command keeps each wheel within v_max, as the follow law's do, and passes
`relayd.core.avoid.ring.guard` (no turn in place without room, as the obstacle escape's turns).
docs/CONTROL.md section 6.1.

Pure: time and heading come in as arguments.
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
