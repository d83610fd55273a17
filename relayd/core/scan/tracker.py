"""The leader's bearing between and across scans: a Kalman filter that knows when it is lost.

Two states, the bearing (deg, robot frame) and its rate, with the odometry heading change
as the control input; each scan's lobe fit (relayd.core.scan.bearing) is a measurement
with its own standard deviation; gated, with a two-level process noise for a turning
leader (docs/CONTROL.md section 10.3 has the model and why a Kalman filter). It promises
a bearing with an honest standard deviation, which the adaptive window and the stop rule
use, or no track: unusable fits count as misses and a run of fits on one side ends a
wrong track. Pure: time comes from the scans.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from relayd.core.geometry import wrap_deg


@dataclass(frozen=True, slots=True)
class TrackerParams:
    """Settings of the bearing filter."""

    #: Process noise: spectral density of the bearing's acceleration (deg^2/s^3), for a
    #: leader holding its course (small: scans average) ...
    accel_q: float = 0.05
    #: ... and for one that manoeuvres, used when an innovation is over `manoeuvre_sigma`.
    manoeuvre_q: float = 20.0
    manoeuvre_sigma: float = 2.5
    #: Odometry heading error, as a fraction of the heading change.
    heading_noise: float = 0.05
    #: A new track's rate uncertainty (deg/s).
    init_rate_sd_deg_s: float = 0.5
    #: A measurement is never trusted beyond this (deg): model mismatch, quantisation.
    min_meas_sd_deg: float = 1.0
    gate_sigma: float = 5.0
    reacquire_after: int = 2
    lost_after_misses: int = 3
    lost_sd_deg: float = 30.0
    confident_sd_deg: float = 8.0
    #: The rate is kept within this (deg/s): a pursuit never turns faster.
    max_rate_deg_s: float = 90.0
    #: The disagreement test: this many scans' normalized innovations, each clipped at
    #: `bias_clip`, summed over sqrt(n) beyond `bias_sigma` (docs/CONTROL.md section 10).
    bias_scans: int = 3
    bias_clip: float = 2.0
    bias_sigma: float = 2.5


@dataclass(frozen=True, slots=True)
class Track:
    """The filter's state at time `t`, in the robot frame of heading `heading_deg`."""

    t: float
    heading_deg: float
    bearing_deg: float
    rate_deg_s: float
    p_bb: float
    p_bw: float
    p_ww: float
    misses: int = 0
    rejects: int = 0
    updates: int = 0
    #: The last scans' normalized innovations (clipped), oldest first: the disagreement test.
    recent_z: tuple[float, ...] = ()

    @property
    def sd_deg(self) -> float:
        return math.sqrt(max(self.p_bb, 0.0))

    @property
    def rate_sd_deg_s(self) -> float:
        return math.sqrt(max(self.p_ww, 0.0))


def _check(**values: float) -> None:
    for name, v in values.items():
        if not math.isfinite(v):
            raise ValueError(f"{name} must be finite, got {v!r}")


def start(
    t: float, heading_deg: float, bearing_deg: float, sd_deg: float, params: TrackerParams
) -> Track:
    """A new track on one measurement: its bearing, no known rate."""
    _check(t=t, heading_deg=heading_deg, bearing_deg=bearing_deg, sd_deg=sd_deg)
    sd = max(sd_deg, params.min_meas_sd_deg)
    return Track(
        t,
        heading_deg,
        wrap_deg(bearing_deg),
        0.0,
        sd * sd,
        0.0,
        params.init_rate_sd_deg_s**2,
        updates=1,
    )


def predict(
    track: Track, t: float, heading_deg: float, params: TrackerParams, accel_q: float | None = None
) -> Track:
    """The track moved to time `t` and the robot frame of `heading_deg` (t before the track's: no time passes)."""
    _check(t=t, heading_deg=heading_deg)
    dt = max(0.0, t - track.t)
    dh = wrap_deg(heading_deg - track.heading_deg)  # odometry headings wrap at +-180
    q = params.accel_q if accel_q is None else accel_q
    b = wrap_deg(track.bearing_deg + track.rate_deg_s * dt - dh)
    p_bb = (
        track.p_bb
        + 2.0 * dt * track.p_bw
        + dt * dt * track.p_ww
        + q * dt**3 / 3.0
        + (params.heading_noise * dh) ** 2
    )
    p_bw = track.p_bw + dt * track.p_ww + q * dt * dt / 2.0
    p_ww = track.p_ww + q * dt
    return replace(
        track,
        t=max(t, track.t),
        heading_deg=heading_deg,
        bearing_deg=b,
        p_bb=p_bb,
        p_bw=p_bw,
        p_ww=p_ww,
    )


def update(
    track: Track,
    t: float,
    heading_deg: float,
    bearing_deg: float,
    sd_deg: float,
    params: TrackerParams,
) -> tuple[Track, bool]:
    """Fuse one measurement (taken at `t` in the frame of `heading_deg`); (new track, accepted)."""
    _check(bearing_deg=bearing_deg, sd_deg=sd_deg)
    if is_lost(track, params):
        return start(t, heading_deg, bearing_deg, sd_deg, params), True
    prior = predict(track, t, heading_deg, params)
    r = max(sd_deg, params.min_meas_sd_deg) ** 2
    innovation = wrap_deg(bearing_deg - prior.bearing_deg)
    s = prior.p_bb + r
    # An unusable fit counts in the test as the least sure usable one would: with its own
    # r, a fit 100 deg off with an sd of 120 says z ~0.8, however many agree on its side.
    z = (
        innovation / math.sqrt(prior.p_bb + min(sd_deg, params.lost_sd_deg) ** 2)
        if sd_deg > params.lost_sd_deg
        else innovation / math.sqrt(s)
    )
    recent = _recent(prior, z, params)
    biased = disagrees(recent, params)
    if biased:
        recent = ()  # one alarm per run of disagreeing scans
    if sd_deg > params.lost_sd_deg:
        # Unusable: time passes, nothing is learnt; but its side counts in the test above.
        lost = params.lost_after_misses if biased else prior.misses + 1
        return replace(prior, misses=max(prior.misses + 1, lost), recent_z=recent), False
    if biased:
        # The prediction is off to one side: predict as for a manoeuvre, and raise the bearing's
        # variance until the newest innovation is one sigma, so the newest fit pulls it over.
        # The rate is kept: a lagging filter (a leader crossing ever faster) needs more of it.
        prior = predict(track, t, heading_deg, params, accel_q=params.manoeuvre_q)
        innovation = wrap_deg(bearing_deg - prior.bearing_deg)
        prior = replace(prior, p_bb=max(prior.p_bb, innovation * innovation - r))
        s = prior.p_bb + r
    elif innovation * innovation > params.manoeuvre_sigma**2 * s:
        # The leader turned or sped up: predict again with the manoeuvring process noise,
        # so the filter follows within a scan or two instead of averaging the turn away.
        prior = predict(track, t, heading_deg, params, accel_q=params.manoeuvre_q)
        innovation = wrap_deg(bearing_deg - prior.bearing_deg)
        s = prior.p_bb + r
    if innovation * innovation > params.gate_sigma**2 * s:
        rejects = prior.rejects + 1
        if rejects >= params.reacquire_after:
            return start(t, heading_deg, bearing_deg, sd_deg, params), True
        # The prediction is this far off: its rate is not to be run on (a leader that
        # jumped, a reflection that set it). Hold the last bearing, forget the rate.
        held = predict(
            replace(track, rate_deg_s=0.0, p_bw=0.0, p_ww=params.init_rate_sd_deg_s**2),
            t,
            heading_deg,
            params,
        )
        return replace(held, rejects=rejects, recent_z=recent), False
    k_b, k_w = prior.p_bb / s, prior.p_bw / s
    b = wrap_deg(prior.bearing_deg + k_b * innovation)
    w = prior.rate_deg_s + k_w * innovation
    w = min(max(w, -params.max_rate_deg_s), params.max_rate_deg_s)
    # Joseph-free form is fine here: 2x2, and the result is re-symmetrised by construction.
    p_bb = (1.0 - k_b) * prior.p_bb
    p_bw = (1.0 - k_b) * prior.p_bw
    p_ww = prior.p_ww - k_w * prior.p_bw
    return replace(
        prior,
        bearing_deg=b,
        rate_deg_s=w,
        p_bb=p_bb,
        p_bw=p_bw,
        p_ww=max(p_ww, 1e-9),
        misses=0,
        rejects=0,
        updates=prior.updates + 1,
        recent_z=recent,
    ), True


def _recent(track: Track, z: float, params: TrackerParams) -> tuple[float, ...]:
    z = min(max(z, -params.bias_clip), params.bias_clip)
    n = max(1, params.bias_scans)
    return (*track.recent_z, z)[-n:]


def disagrees(recent_z: tuple[float, ...], params: TrackerParams) -> bool:
    """The last `bias_scans` normalized innovations say, together, that the prediction is off."""
    n = params.bias_scans
    return (
        n >= 1 and len(recent_z) >= n and abs(sum(recent_z[-n:])) > params.bias_sigma * math.sqrt(n)
    )


def miss(track: Track, t: float, heading_deg: float, params: TrackerParams) -> Track:
    """A scan that showed no usable lobe: time passes, nothing is learnt."""
    prior = predict(track, t, heading_deg, params)
    return replace(prior, misses=prior.misses + 1)


def is_lost(track: Track, params: TrackerParams) -> bool:
    return track.misses >= params.lost_after_misses or track.sd_deg > params.lost_sd_deg


def is_confident(track: Track, params: TrackerParams) -> bool:
    return not is_lost(track, params) and track.sd_deg <= params.confident_sd_deg
