"""Where is the leader? An EKF of its position in the relay's odometry frame (pure).

State: the leader's position and velocity (x, y, vx, vy in metres and m/s, odometry
frame) with its 4x4 covariance. The velocity decays toward zero with `velocity_tau_s`
(a person walks, stops, turns back: an Ornstein-Uhlenbeck velocity, not a constant one),
driven by white acceleration noise sized so the stationary speed spread is `speed_sd_m_s`.

Measurements, each a scalar EKF update from the relay's own pose (its odometry moves
the baseline, so bearings from two places fix a range the RSSI alone cannot):
- the scan bearing (world frame: heading + bearing), sd from the tracking filter;
- the RSSI through the log-distance model: ln d = (L0 - RSSI) ln10 / (10 n), whose noise
  is Gaussian in ln d (sd sigma ln10 / (10 n)), so it is updated in ln d, not in metres;
- the sonar floor (`rangecue.leader_floor_m`): the leader is at least that far; applied
  only when the estimate is nearer (a one-sided constraint).
A measurement whose normalised innovation exceeds `gate_sigma` is not dropped: its
variance is inflated until it sits on the gate (a wall's 10 dB costs confidence, not the
track). The uncertainty reported is `sigma_m`: the square root of the covariance's
largest eigenvalue; the "2-sigma bound" is 2 sigma_m as a radius (for the long, thin
ellipses a bearing and a range give, the probability inside is between 86 % and 95 %).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from relayd.core.geometry import wrap_rad

Vec = tuple[float, float, float, float]
Mat = tuple[Vec, Vec, Vec, Vec]

LN10 = math.log(10.0)
#: No range below this (m): the path-loss model means nothing inside the antenna's near field.
MIN_RANGE_M = 0.3


@dataclass(frozen=True, slots=True)
class RangeModel:
    """The log-distance path-loss model: RSSI = L0 - 10 n log10(d) + N(0, sigma)."""

    l0_dbm: float = -15.0
    exponent: float = 2.0
    sigma_db: float = 6.0

    def log_range(self, rssi_dbm: float) -> float:
        """ln of the range (m) the model gives this RSSI."""
        return (self.l0_dbm - rssi_dbm) * LN10 / (10.0 * self.exponent)

    def range_m(self, rssi_dbm: float) -> float:
        return max(MIN_RANGE_M, math.exp(self.log_range(rssi_dbm)))

    @property
    def log_sd(self) -> float:
        """sd of ln d that sigma_db means."""
        return self.sigma_db * LN10 / (10.0 * self.exponent)


@dataclass(frozen=True, slots=True)
class EstimateParams:
    range_model: RangeModel = RangeModel()
    #: Stationary spread of the leader's speed (m/s) and how fast a velocity is forgotten.
    speed_sd_m_s: float = 0.8
    velocity_tau_s: float = 2.0
    #: The bearing's sd when the tracking filter gives none (the paper's WCA).
    bearing_sd_deg: float = 8.0
    #: The sonar floor's sd (m) when it constrains the estimate.
    floor_sd_m: float = 0.3
    gate_sigma: float = 3.0
    #: The RSSI's error is shadowing, correlated from one scan to the next while the relay
    #: and the leader move less than its correlation length: each scan's range counts as
    #: 1/range_corr_scans of an independent one (its variance times this).
    range_corr_scans: float = 3.0


@dataclass(frozen=True, slots=True)
class LeaderEstimate:
    t_s: float
    x: Vec
    p: Mat

    @property
    def xy_m(self) -> tuple[float, float]:
        return self.x[0], self.x[1]

    @property
    def sigma_m(self) -> float:
        """sqrt of the position covariance's largest eigenvalue (m)."""
        a, b, c = self.p[0][0], self.p[0][1], self.p[1][1]
        lam = 0.5 * (a + c) + math.sqrt(max(0.0, 0.25 * (a - c) ** 2 + b * b))
        return math.sqrt(max(0.0, lam))

    def within(self, xy_m: tuple[float, float], k: float = 2.0) -> bool:
        """Is this point inside the k-sigma bound (a radius of k sigma_m)?"""
        return math.dist(self.xy_m, xy_m) <= k * self.sigma_m


def _mat(rows: list[list[float]]) -> Mat:
    r = [tuple(row) for row in rows]
    return (r[0], r[1], r[2], r[3])  # type: ignore[return-value]


def _predict(est: LeaderEstimate, t_s: float, prm: EstimateParams) -> LeaderEstimate:
    dt = t_s - est.t_s
    if not dt > 0.0:
        return est
    tau = prm.velocity_tau_s
    a = math.exp(-dt / tau)
    g = tau * (1.0 - a)  # position gained per unit velocity over dt
    f = [[1.0, 0.0, g, 0.0], [0.0, 1.0, 0.0, g], [0.0, 0.0, a, 0.0], [0.0, 0.0, 0.0, a]]
    x = est.x
    nx: Vec = (x[0] + g * x[2], x[1] + g * x[3], a * x[2], a * x[3])
    # Exact discretisation of the OU velocity's noise for one axis (stationary var s2).
    s2 = prm.speed_sd_m_s**2
    qvv = s2 * (1.0 - a * a)
    qpv = s2 * tau * (1.0 - a) ** 2
    qpp = s2 * tau * (2.0 * dt - tau * (1.0 - a) * (3.0 - a))
    q = [[qpp, 0.0, qpv, 0.0], [0.0, qpp, 0.0, qpv], [qpv, 0.0, qvv, 0.0], [0.0, qpv, 0.0, qvv]]
    p = est.p
    fp = [[sum(f[i][k] * p[k][j] for k in range(4)) for j in range(4)] for i in range(4)]
    np_ = [
        [sum(fp[i][k] * f[j][k] for k in range(4)) + q[i][j] for j in range(4)] for i in range(4)
    ]
    return LeaderEstimate(t_s, nx, _mat(np_))


def _update(est: LeaderEstimate, h: Vec, innov: float, r: float, gate: float) -> LeaderEstimate:
    """One scalar EKF update: H = h, innovation innov, measurement variance r (Joseph form)."""
    p = est.p
    ph = [sum(p[i][k] * h[k] for k in range(4)) for i in range(4)]
    s = sum(h[i] * ph[i] for i in range(4)) + r
    if innov * innov > gate * gate * s:
        # An outlier (a wall, a reflection): widen it onto the gate instead of trusting it.
        s = innov * innov / (gate * gate)
        r = s - sum(h[i] * ph[i] for i in range(4))
    k = [ph[i] / s for i in range(4)]
    x: Vec = (
        est.x[0] + k[0] * innov,
        est.x[1] + k[1] * innov,
        est.x[2] + k[2] * innov,
        est.x[3] + k[3] * innov,
    )
    # Joseph form (I - K H) P (I - K H)^T + K r K^T keeps P symmetric and positive.
    a = [[(1.0 if i == j else 0.0) - k[i] * h[j] for j in range(4)] for i in range(4)]
    ap = [[sum(a[i][m] * p[m][j] for m in range(4)) for j in range(4)] for i in range(4)]
    np_ = [
        [sum(ap[i][m] * a[j][m] for m in range(4)) + k[i] * r * k[j] for j in range(4)]
        for i in range(4)
    ]
    sym = [[0.5 * (np_[i][j] + np_[j][i]) for j in range(4)] for i in range(4)]
    return LeaderEstimate(est.t_s, x, _mat(sym))


def start(
    t_s: float,
    relay_xy_m: tuple[float, float],
    bearing_world_deg: float,
    bearing_sd_deg: float | None,
    rssi_dbm: float,
    prm: EstimateParams,
) -> LeaderEstimate:
    """The first estimate: on the bearing at the RSSI's range, its covariance in polar form."""
    rm = prm.range_model
    d = rm.range_m(rssi_dbm)
    b = math.radians(bearing_world_deg)
    sd_b = math.radians(bearing_sd_deg if bearing_sd_deg is not None else prm.bearing_sd_deg)
    # The range's spread in metres: the ln-normal's upper 1-sigma step, not the median's.
    var_r = (d * math.expm1(rm.log_sd)) ** 2
    var_t = (d * sd_b) ** 2
    c, s = math.cos(b), math.sin(b)
    pxx = var_r * c * c + var_t * s * s
    pyy = var_r * s * s + var_t * c * c
    pxy = (var_r - var_t) * c * s
    v2 = prm.speed_sd_m_s**2
    p = _mat([[pxx, pxy, 0.0, 0.0], [pxy, pyy, 0.0, 0.0], [0.0, 0.0, v2, 0.0], [0.0, 0.0, 0.0, v2]])
    x: Vec = (relay_xy_m[0] + d * c, relay_xy_m[1] + d * s, 0.0, 0.0)
    return LeaderEstimate(t_s, x, p)


def observe(
    est: LeaderEstimate | None,
    t_s: float,
    relay_xy_m: tuple[float, float],
    bearing_world_deg: float | None,
    bearing_sd_deg: float | None,
    rssi_dbm: float | None,
    floor_m: float | None,
    prm: EstimateParams,
) -> LeaderEstimate | None:
    """The estimate after one scan seen from relay_xy_m at t_s (None until a scan has both)."""
    if est is None:
        if bearing_world_deg is None or rssi_dbm is None:
            return None
        est = start(t_s, relay_xy_m, bearing_world_deg, bearing_sd_deg, rssi_dbm, prm)
        return _floor(est, relay_xy_m, floor_m, prm)
    est = _predict(est, t_s, prm)
    rx, ry = relay_xy_m
    dx, dy = est.x[0] - rx, est.x[1] - ry
    r2 = max(dx * dx + dy * dy, MIN_RANGE_M**2)
    if bearing_world_deg is not None:
        sd = math.radians(bearing_sd_deg if bearing_sd_deg is not None else prm.bearing_sd_deg)
        innov = wrap_rad(math.radians(bearing_world_deg) - math.atan2(dy, dx))
        est = _update(est, (-dy / r2, dx / r2, 0.0, 0.0), innov, sd * sd, prm.gate_sigma)
        dx, dy = est.x[0] - rx, est.x[1] - ry
        r2 = max(dx * dx + dy * dy, MIN_RANGE_M**2)
    if rssi_dbm is not None:
        rm = prm.range_model
        innov = rm.log_range(rssi_dbm) - 0.5 * math.log(r2)
        est = _update(
            est,
            (dx / r2, dy / r2, 0.0, 0.0),
            innov,
            rm.log_sd**2 * prm.range_corr_scans,
            prm.gate_sigma,
        )
    return _floor(est, relay_xy_m, floor_m, prm)


def _floor(
    est: LeaderEstimate, relay_xy_m: tuple[float, float], floor_m: float | None, prm: EstimateParams
) -> LeaderEstimate:
    """The sonar floor, one-sided: only an estimate nearer than it is pushed out."""
    if floor_m is None or not math.isfinite(floor_m):
        return est
    dx, dy = est.x[0] - relay_xy_m[0], est.x[1] - relay_xy_m[1]
    r = max(math.hypot(dx, dy), MIN_RANGE_M)
    if r >= floor_m:
        return est
    return _update(est, (dx / r, dy / r, 0.0, 0.0), floor_m - r, prm.floor_sd_m**2, math.inf)
