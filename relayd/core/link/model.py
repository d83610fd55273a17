"""The adaptive rear-link policy: what the hop behind delivers at which RSSI^b, learned online.

With `control.link_policy = "adaptive"`, each rear-AP poll is a sample of RSSI^b and the
rate the radio delivers; a probit model of meeting `control.target_hop_mbps` gets a grid
posterior with exponential forgetting, read as an ordered probit on the 802.11 rate ladder
(relayd.core.link.rates). The rear limit is the RSSI^b where meeting the target falls to
1 - `control.outage`, clamped to its bounds; with no evidence it is the configured
threshold_b_dbm. docs/CONTROL.md section 5.1 has the model, its prior and its checks.
Pure: each poll carries its time.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from relayd.core.link.rates import ladder_of

#: The spread grid (dB): from a clean line of sight to a deep-fading corridor.
SPREADS_DB: tuple[float, ...] = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)
#: The mu grid step (dB) and how far it reaches beyond the bounds.
MU_STEP_DB = 1.0
MU_BELOW_DB, MU_ABOVE_DB = 20.0, 10.0
#: Prior standard deviation of mu (dB): wide, evidence moves it within a few dozen polls.
PRIOR_SD_DB = 5.0
#: Probability that a poll's verdict is unrelated to its RSSI (a glitch, a burst of traffic).
LAPSE = 0.02
#: How far (dB) the limit may go below the weakest RSSI^b recently seen meeting the target.
EXTRAPOLATE_DB = 1.0
#: A poll counts in full once the relay moved this far since the previous one (m): about
#: one poll's travel at a follower's speed, and several fast-fading lengths at 2.4 GHz.
MOVE_REF_M = 0.2
#: What a poll taken standing still counts for: the node behind may move (so it is news),
#: but mostly it repeats what the last one said about this spot.
STANDING_WEIGHT = 0.05
#: Below this travel (m) since the previous poll the relay stands: such a poll may tighten the limit, never relax it.
STANDING_M = 0.02
#: Cells below this share of the best one are left out of the threshold search.
PRUNE = 1e-4


@dataclass(frozen=True, slots=True)
class LinkPolicyParams:
    """The adaptive rear-limit settings (config `[control]`, docs/CONTROL.md section 5.1)."""

    adaptive: bool = False
    target_hop_mbps: float = 10.0
    #: Accepted probability that the hop delivers less than the target at the stop point.
    outage: float = 0.1
    #: (most relaxed, tightest) threshold_b the model may set, dBm.
    bounds_dbm: tuple[float, float] = (-80.0, -50.0)
    #: The configured threshold_b: the starting point and the value with no evidence.
    fallback_dbm: float = -60.0
    mac_efficiency: float = 0.5
    half_life_samples: float = 20.0
    #: Effective samples before the model's threshold replaces the configured one.
    min_samples: float = 10.0
    #: A sample older than this when it arrives is stale (the rear link's staleness limit).
    stale_s: float = 3.0

    def __post_init__(self) -> None:
        lo, hi = self.bounds_dbm
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(
                f"bounds_dbm must be (low, high) with low < high, got {self.bounds_dbm}"
            )
        if not 0.0 < self.outage < 0.5:
            raise ValueError(f"outage must be in (0, 0.5), got {self.outage}")
        if self.target_hop_mbps <= 0 or self.mac_efficiency <= 0 or self.half_life_samples <= 0:
            raise ValueError("target_hop_mbps, mac_efficiency and half_life_samples must be > 0")


@dataclass(frozen=True, slots=True)
class LinkSample:
    """One rear-AP poll: the signal of the node behind and what the radio reports delivering."""

    t: float
    rssi_dbm: float
    tx_mbps: float | None
    rx_mbps: float | None
    ccq_pct: float | None
    #: How far the relay itself travelled since its previous rear poll (odometry, m);
    #: None when unknown (taken as a moving poll).
    moved_m: float | None = None

    def weight(self) -> float:
        """How much news the poll carries: 1 on the move, STANDING_WEIGHT standing still."""
        if self.moved_m is None or not math.isfinite(self.moved_m):
            return 1.0
        return min(1.0, max(STANDING_WEIGHT, self.moved_m / MOVE_REF_M))

    def delivered_mbps(self, mac_efficiency: float) -> float | None:
        """min(tx, rx) x CCQ x MAC efficiency; None when the radio gave no rate."""
        rates = [
            r for r in (self.tx_mbps, self.rx_mbps) if r is not None and math.isfinite(r) and r >= 0
        ]
        if not rates:
            return None
        ccq = self.ccq_pct
        share = 1.0 if ccq is None or not math.isfinite(ccq) else min(max(ccq, 0.0), 100.0) / 100.0
        return min(rates) * share * mac_efficiency


_SQRT2 = math.sqrt(2.0)
_SQRT_2PI = math.sqrt(2.0 * math.pi)


def _phi(x: float) -> float:
    return 0.5 * math.erfc(-x / _SQRT2)


@dataclass(slots=True)
class LinkModel:
    """The online model of one relay's rear hop. Call `observe` on every rear-AP poll."""

    params: LinkPolicyParams
    mus: tuple[float, ...] = field(init=False)
    _prior: list[float] = field(init=False, repr=False)
    _loglik: list[float] = field(init=False, repr=False)
    #: RSSI^b of the recent polls that met the target (the evidence floor's window).
    _ok_rssi: deque[float | None] = field(init=False, repr=False)
    n_eff: float = 0.0
    accepted: int = 0
    refused_stale: int = 0
    unusable: int = 0
    ok_eff: float = 0.0
    #: Effective samples whose rate sat on a known 802.11 ladder (the rest gave a yes/no verdict only).
    ladder_eff: float = 0.0
    last_t: float | None = None
    last_rssi_dbm: float | None = None
    last_delivered_mbps: float | None = None
    threshold_dbm: float = 0.0

    def __post_init__(self) -> None:
        p = self.params
        lo, hi = p.bounds_dbm
        start, stop = lo - MU_BELOW_DB, hi + MU_ABOVE_DB
        steps = round((stop - start) / MU_STEP_DB)
        self.mus = tuple(start + i * MU_STEP_DB for i in range(steps + 1))
        self._loglik = [0.0] * (len(self.mus) * len(SPREADS_DB))
        self._prior = self._centred_prior()
        self.threshold_dbm = self._clamp(p.fallback_dbm)
        self._ok_rssi = deque(maxlen=max(1, round(p.half_life_samples)))

    # -- set-up ----------------------------------------------------------------------

    def _prior_at(self, centre: float) -> list[float]:
        out: list[float] = []
        for mu in self.mus:
            lp = -0.5 * ((mu - centre) / PRIOR_SD_DB) ** 2
            out.extend(lp for _ in SPREADS_DB)
        return out

    def _centred_prior(self) -> list[float]:
        """A prior whose predictive threshold is the configured one.

        The prior's predictive quantile moves one for one with its centre (the grid
        reaches far beyond the bounds), so one solve at a trial centre gives the shift.
        """
        want = self._clamp(self.params.fallback_dbm)
        trial = (self.params.bounds_dbm[0] + self.params.bounds_dbm[1]) / 2.0
        self._prior = self._prior_at(trial)
        got = self._solve(self.mus[0], self.mus[-1])
        return self._prior_at(trial + want - got)

    def _clamp(self, value: float) -> float:
        lo, hi = self.params.bounds_dbm
        return min(max(value, lo), hi)

    # -- the posterior ---------------------------------------------------------------

    def _weights(self) -> list[tuple[float, float, float]]:
        """(mu, s, weight) of the cells that matter, weights normalised to sum 1."""
        post = [a + b for a, b in zip(self._prior, self._loglik, strict=True)]
        top = max(post)
        cells = []
        total = 0.0
        k = 0
        for mu in self.mus:
            for s in SPREADS_DB:
                w = math.exp(post[k] - top)
                k += 1
                if w >= PRUNE:
                    cells.append((mu, s, w))
                    total += w
        return [(mu, s, w / total) for mu, s, w in cells]

    @staticmethod
    def _predictive(cells: list[tuple[float, float, float]], r: float) -> float:
        return sum(w * _phi((r - mu) / s) for mu, s, w in cells)

    def _solve(self, lo: float, hi: float) -> float:
        """The RSSI^b in [lo, hi] where the predictive P(ok) is 1 - outage (an end if none).

        P(ok | r) rises with r, so the root is unique: safeguarded Newton from the last
        threshold (a few steps, as the threshold moves little per sample), bisection
        whenever a step would leave the bracket.
        """
        cells = self._weights()
        want = 1.0 - self.params.outage
        if self._predictive(cells, lo) >= want:
            return lo
        if self._predictive(cells, hi) < want:
            return hi
        r = min(max(self.threshold_dbm, lo), hi)
        for _ in range(40):
            value, slope = 0.0, 0.0
            for mu, s, w in cells:
                z = (r - mu) / s
                value += w * _phi(z)
                slope += w * math.exp(-0.5 * z * z) / (s * _SQRT_2PI)
            err = value - want
            if err >= 0.0:
                hi = r
            else:
                lo = r
            if abs(err) < 1e-4 or hi - lo < 1e-3:
                break
            step = r - err / slope if slope > 1e-12 else (lo + hi) / 2.0
            r = step if lo < step < hi else (lo + hi) / 2.0
        return r

    # -- the one input ---------------------------------------------------------------

    def observe(self, sample: LinkSample, now: float) -> bool:
        """Learn from one poll at time `now`; False (and no change) if stale or unusable."""
        p = self.params
        fresh = (
            math.isfinite(sample.t)
            and now - sample.t <= p.stale_s
            and (self.last_t is None or sample.t > self.last_t)
        )
        if not fresh:
            self.refused_stale += 1
            return False
        delivered = sample.delivered_mbps(p.mac_efficiency)
        if delivered is None or not math.isfinite(sample.rssi_dbm):
            self.unusable += 1
            return False
        ok = delivered >= p.target_hop_mbps
        r = sample.rssi_dbm
        band = self._band(sample, p)
        w = sample.weight()
        decay = 0.5 ** (w / p.half_life_samples)
        k = 0
        ll = self._loglik
        for mu in self.mus:
            for s in SPREADS_DB:
                if band is None:
                    q = _phi((r - mu) / s)
                    lik = LAPSE / 2.0 + (1.0 - LAPSE) * (q if ok else 1.0 - q)
                else:
                    lo, hi = band
                    q = _phi((r - mu - lo) / s) - (
                        _phi((r - mu - hi) / s) if hi < math.inf else 0.0
                    )
                    lik = LAPSE / 2.0 + (1.0 - LAPSE) * q
                ll[k] = decay * ll[k] + w * math.log(lik)
                k += 1
        self.ladder_eff = decay * self.ladder_eff + (w if band is not None else 0.0)
        self.n_eff = decay * self.n_eff + w
        self.ok_eff = decay * self.ok_eff + (w if ok else 0.0)
        self.accepted += 1
        self.last_t, self.last_rssi_dbm, self.last_delivered_mbps = sample.t, r, delivered
        self._ok_rssi.append(r if ok else None)
        if self.n_eff >= p.min_samples:
            limit = max(self._solve(*p.bounds_dbm), self._clamp(self.evidence_floor_dbm()))
            standing = sample.moved_m is not None and sample.moved_m < STANDING_M
            # A relay standing at its limit learns only about the spot it stands on; relaxing
            # from there would send it on by extrapolation, and it backs up only out of a shadow.
            self.threshold_dbm = max(limit, self.threshold_dbm) if standing else limit
        return True

    @staticmethod
    def _band(sample: LinkSample, p: LinkPolicyParams) -> tuple[float, float] | None:
        """Where on its rate ladder the poll's rate puts RSSI^b - mu, in dB; None off the ladders.

        The radio sent at rate i of a known ladder, so its signal lay between rate i's
        sensitivity and the next faster rate's. Relative to the sensitivity of the slowest
        rate that meets the target at this poll's CCQ (the target's own step, where mu is),
        that is [sens_i - sens_t, sens_(i-1) - sens_t): the band RSSI^b - mu fell in.
        """
        rates = [
            x
            for x in (sample.tx_mbps, sample.rx_mbps)
            if x is not None and math.isfinite(x) and x > 0
        ]
        found = ladder_of(min(rates)) if rates else None
        if found is None:
            return None
        ladder, i = found
        per_mbps = (sample.delivered_mbps(p.mac_efficiency) or 0.0) / ladder[i][1]
        target = None
        for sens, rate in ladder:
            if rate * per_mbps >= p.target_hop_mbps:
                target = sens
        if (
            target is None
        ):  # no rate of this ladder meets the target at this CCQ: the binary verdict says it
            return None
        lo = ladder[i][0] - target
        hi = ladder[i - 1][0] - target if i > 0 else math.inf
        return lo, hi

    def evidence_floor_dbm(self) -> float:
        """The loosest limit the recent evidence supports (see the module docstring)."""
        seen = [r for r in self._ok_rssi if r is not None]
        # No recent poll met the target: the failures already hold the model tight.
        return (min(seen) - EXTRAPOLATE_DB) if seen else -math.inf

    # -- views -----------------------------------------------------------------------

    def estimate(self) -> tuple[float, float]:
        """Posterior means of (mu, s) in dB."""
        cells = self._weights()
        return (sum(w * mu for mu, _s, w in cells), sum(w * s for _mu, s, w in cells))

    def p_ok(self, rssi_dbm: float) -> float:
        """The predictive probability that the hop meets the target at this RSSI^b."""
        return self._predictive(self._weights(), rssi_dbm)

    def stale(self, now: float) -> bool:
        return self.last_t is None or now - self.last_t > self.params.stale_s

    def status(self, now: float) -> LinkModelStatus:
        """The model's state for /status (rounded: a view, not a computation input)."""
        p = self.params
        mu, s = self.estimate()
        last = self.last_rssi_dbm
        return LinkModelStatus(
            policy="adaptive" if p.adaptive else "fixed",
            threshold_b_dbm=round(self.threshold_dbm, 2),
            configured_threshold_b_dbm=p.fallback_dbm,
            bounds_dbm=(p.bounds_dbm[0], p.bounds_dbm[1]),
            target_hop_mbps=p.target_hop_mbps,
            outage=p.outage,
            learning=self.n_eff >= p.min_samples,
            samples=self.accepted,
            effective_samples=round(self.n_eff, 2),
            ok_share=None if self.n_eff <= 0 else round(self.ok_eff / self.n_eff, 3),
            mu_dbm=round(mu, 2),
            spread_db=round(s, 2),
            p_ok_now=None if last is None else round(self.p_ok(last), 3),
            last_rssi_dbm=last,
            last_delivered_mbps=None
            if self.last_delivered_mbps is None
            else round(self.last_delivered_mbps, 2),
            stale=self.stale(now),
            refused_stale=self.refused_stale,
        )


@dataclass(frozen=True, slots=True)
class LinkModelStatus:
    """What /status shows of the model (the `link_model` object)."""

    policy: str
    threshold_b_dbm: float
    configured_threshold_b_dbm: float
    bounds_dbm: tuple[float, float]
    target_hop_mbps: float
    outage: float
    learning: bool
    samples: int
    effective_samples: float
    ok_share: float | None
    mu_dbm: float
    spread_db: float
    p_ok_now: float | None
    last_rssi_dbm: float | None
    last_delivered_mbps: float | None
    stale: bool
    refused_stale: int

    def to_json(self) -> dict[str, Any]:
        out = {f: getattr(self, f) for f in self.__slots__}
        out["bounds_dbm"] = list(self.bounds_dbm)
        return out
