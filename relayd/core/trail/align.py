"""Aligning a leader relay's odometry frame to this relay's own (pure; the robot-leader part).

A robot leader publishes its own odometry poses. To follow its real path, the follower
needs the transform T = (tx, ty, phi) that maps the leader's frame into its own:
p_own = R(phi) p_leader + t. The convoy lines up at the command center, so the start
poses give a prior (`prior`, with its sd); the follower's own bearing observations of
the leader (taken from its pose at the time, world frame) refine it: Gauss-Newton over
the bearing residuals plus the prior, a few iterations. The alignment is rejected when
its bearing residuals' RMS exceeds `max_rms_deg` (an alignment the antenna disagrees
with), or when it needs more than `max_shift_m` / `max_turn_deg` from the prior.
Wired in by relayd/core/trail/feed.py (the leader relay's GET /path, `leader_url`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from relayd.core.geometry import wrap_deg


@dataclass(frozen=True, slots=True)
class Frame:
    """p_own = R(phi) p_leader + (tx, ty); metres and degrees."""

    tx_m: float
    ty_m: float
    phi_deg: float

    def apply(self, xy_m: tuple[float, float]) -> tuple[float, float]:
        c, s = math.cos(math.radians(self.phi_deg)), math.sin(math.radians(self.phi_deg))
        return c * xy_m[0] - s * xy_m[1] + self.tx_m, s * xy_m[0] + c * xy_m[1] + self.ty_m


def frame_between(
    own_origin: tuple[float, float, float], leader_origin: tuple[float, float, float]
) -> Frame:
    """The leader's odometry frame in ours, from where each odometry started on a shared
    map (x_m, y_m, heading_deg; the fleet config's `origin`s): the alignment's prior."""
    c, s = math.cos(math.radians(own_origin[2])), math.sin(math.radians(own_origin[2]))
    dx, dy = leader_origin[0] - own_origin[0], leader_origin[1] - own_origin[1]
    return Frame(c * dx + s * dy, -s * dx + c * dy, wrap_deg(leader_origin[2] - own_origin[2]))


@dataclass(frozen=True, slots=True)
class Sighting:
    """One bearing of the leader from this relay: own position, world-frame bearing, and
    where the leader's feed put itself (its frame) at that time."""

    own_xy_m: tuple[float, float]
    bearing_world_deg: float
    leader_xy_m: tuple[float, float]


@dataclass(frozen=True, slots=True)
class AlignParams:
    prior_sd_m: float = 1.0
    prior_sd_deg: float = 10.0
    bearing_sd_deg: float = 5.0
    max_rms_deg: float = 12.0
    max_shift_m: float = 2.0
    max_turn_deg: float = 30.0
    iterations: int = 10
    #: Sightings nearer than this say little about the frame (a bearing across 0.5 m).
    min_range_m: float = 1.0


@dataclass(frozen=True, slots=True)
class Alignment:
    frame: Frame
    rms_deg: float
    used: int
    accepted: bool
    why: str


def residuals_deg(f: Frame, sightings: Sequence[Sighting]) -> list[float]:
    """Each sighting's bearing minus where the frame puts the leader (deg)."""
    out = []
    for s in sightings:
        x, y = f.apply(s.leader_xy_m)
        want = math.degrees(math.atan2(y - s.own_xy_m[1], x - s.own_xy_m[0]))
        out.append(wrap_deg(s.bearing_world_deg - want))
    return out


def _solve3(a: list[list[float]], b: list[float]) -> list[float] | None:
    """Gaussian elimination with partial pivoting on a 3x3 system."""
    m = [[*row, bi] for row, bi in zip(a, b, strict=True)]
    for c in range(3):
        piv = max(range(c, 3), key=lambda r: abs(m[r][c]))
        if abs(m[piv][c]) < 1e-12:
            return None
        m[c], m[piv] = m[piv], m[c]
        for r in range(3):
            if r != c:
                k = m[r][c] / m[c][c]
                m[r] = [vr - k * vc for vr, vc in zip(m[r], m[c], strict=True)]
    return [m[i][3] / m[i][i] for i in range(3)]


def align(prior: Frame, sightings: Sequence[Sighting], p: AlignParams) -> Alignment:
    """The prior refined by the sightings (see the module docstring)."""
    use = [
        s
        for s in sightings
        if math.dist(prior.apply(s.leader_xy_m), s.own_xy_m) >= p.min_range_m
        and math.isfinite(s.bearing_world_deg)
    ]
    f = prior
    wb = 1.0 / p.bearing_sd_deg**2
    wp_m, wp_deg = 1.0 / p.prior_sd_m**2, 1.0 / p.prior_sd_deg**2
    for _ in range(p.iterations):
        # Normal equations of the bearing residuals (deg) and the prior, by numeric Jacobian.
        h = [[0.0] * 3 for _ in range(3)]
        g = [0.0] * 3
        base = residuals_deg(f, use)
        steps = (1e-4, 1e-4, 1e-3)
        cols = []
        for k, eps in enumerate(steps):
            d = [0.0, 0.0, 0.0]
            d[k] = eps
            moved = Frame(f.tx_m + d[0], f.ty_m + d[1], f.phi_deg + d[2])
            cols.append(
                [(b1 - b0) / eps for b0, b1 in zip(base, residuals_deg(moved, use), strict=True)]
            )
        for i in range(len(use)):
            for a in range(3):
                g[a] += wb * cols[a][i] * base[i]
                for c in range(3):
                    h[a][c] += wb * cols[a][i] * cols[c][i]
        pr = (f.tx_m - prior.tx_m, f.ty_m - prior.ty_m, wrap_deg(f.phi_deg - prior.phi_deg))
        for a, w in enumerate((wp_m, wp_m, wp_deg)):
            h[a][a] += w
            g[a] += w * pr[a]
        # Gauss-Newton on sum w r^2 + the prior: (J'WJ + P) step = J'W r + P (f - prior).
        step = _solve3(h, g)
        if step is None:
            break
        f = Frame(f.tx_m - step[0], f.ty_m - step[1], f.phi_deg - step[2])
        if max(abs(step[0]), abs(step[1])) < 1e-4 and abs(step[2]) < 1e-3:
            break
    res = residuals_deg(f, use)
    rms = math.sqrt(sum(r * r for r in res) / len(res)) if res else math.nan
    shift = math.hypot(f.tx_m - prior.tx_m, f.ty_m - prior.ty_m)
    turn = abs(wrap_deg(f.phi_deg - prior.phi_deg))
    if not use:
        return Alignment(prior, rms, 0, True, "prior")
    if rms > p.max_rms_deg:
        return Alignment(f, rms, len(use), False, "bearings_disagree")
    if shift > p.max_shift_m or turn > p.max_turn_deg:
        return Alignment(f, rms, len(use), False, "too_far_from_prior")
    return Alignment(f, rms, len(use), True, "refined")
