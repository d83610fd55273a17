"""The rear-link model (relayd/core/link/model.py): unit and property tests, and its seam in the brain."""

from __future__ import annotations

import json
import math
import random
from statistics import NormalDist

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.airos.model import LinkQuality, Station
from relayd.core.brain import Brain, BrainParams
from relayd.core.control.law import ControlParams
from relayd.core.events import LinkEvent, LinkModelView, LinkSide
from relayd.core.link.model import LinkModel, LinkPolicyParams, LinkSample
from relayd.core.link.rates import RATE_TABLES
from relayd.sim.radio import phy_rate_mbps

BOUNDS = (-80.0, -50.0)


def params(**kw: object) -> LinkPolicyParams:
    base: dict[str, object] = {"adaptive": True, "fallback_dbm": -66.0, "bounds_dbm": BOUNDS}
    base.update(kw)
    return LinkPolicyParams(**base)  # type: ignore[arg-type]


def drive_away(
    model: LinkModel,
    *,
    penalty_db: float,
    fade_sd_db: float,
    seed: int,
    n: int = 300,
    start_dbm: float = -55.0,
    end_dbm: float = -80.0,
) -> None:
    """A relay backing away from its rear node: the mean falls, RSSI^b fades around it, and the
    radio's rate follows the mean minus a multipath penalty (the simulator's 802.11g table)."""
    rng = random.Random(seed)
    for i in range(n):
        mean = start_dbm + (end_dbm - start_dbm) * i / n
        rssi = round(mean + rng.gauss(0.0, fade_sd_db))
        rate = phy_rate_mbps(mean - penalty_db)
        model.observe(LinkSample(float(i), rssi, rate, rate, 95.0), float(i))


def test_starts_at_the_configured_threshold_and_holds_it_until_it_has_learned() -> None:
    m = LinkModel(params())
    assert m.threshold_dbm == pytest.approx(-66.0, abs=0.05)
    for i in range(5):  # fewer than min_samples
        m.observe(LinkSample(float(i), -75.0, 54.0, 54.0, 100.0), float(i))
    assert m.threshold_dbm == pytest.approx(-66.0, abs=0.05)


def test_configured_threshold_outside_the_bounds_starts_clamped() -> None:
    assert LinkModel(params(fallback_dbm=-40.0)).threshold_dbm == pytest.approx(-50.0, abs=0.05)


@pytest.mark.parametrize("seed", range(5))
def test_relaxes_in_open_space_and_tightens_under_fading_and_multipath(seed: int) -> None:
    # 10 Mbit/s at 0.5 x 95 % CCQ needs the 24 Mbit/s rate: -74 dBm local mean.
    # A long memory: this test is about the curve, not the forgetting.
    open_hall, corridor = (
        LinkModel(params(half_life_samples=60.0)),
        LinkModel(params(half_life_samples=60.0)),
    )
    drive_away(open_hall, penalty_db=0.0, fade_sd_db=1.0, seed=seed)
    drive_away(corridor, penalty_db=6.0, fade_sd_db=3.0, seed=seed)
    assert open_hall.threshold_dbm < -70.0  # looser than the configured -66
    assert corridor.threshold_dbm > -65.5  # tighter (the true 10 % point: -68 + 1.28 x 3 = -64.2)
    mu_open, s_open = open_hall.estimate()
    mu_cor, s_cor = corridor.estimate()
    assert mu_open == pytest.approx(-74.0, abs=1.5)
    assert mu_cor == pytest.approx(-68.0, abs=2.5)  # fewer informative polls remembered
    assert mu_cor > mu_open + 3.0
    assert s_cor > s_open


@settings(max_examples=25, deadline=None)
@given(
    mu=st.floats(-76.0, -56.0),
    s=st.sampled_from([1.0, 2.0, 4.0]),
    outage=st.sampled_from([0.05, 0.1, 0.2]),
    seed=st.integers(0, 10_000),
)
def test_converges_to_the_true_outage_quantile(
    mu: float, s: float, outage: float, seed: int
) -> None:
    """Synthetic polls with P(ok | r) = Phi((r - mu) / s), RSSI^b spread over the region that
    matters: the limit ends near mu + z(1 - outage) s, the RSSI^b that meets the outage.
    The rates are on no 802.11 ladder (100 or 1 Mbit/s), so each poll is a bare yes/no."""
    rng = random.Random(seed)
    m = LinkModel(params(outage=outage, half_life_samples=400.0))
    for i in range(600):
        r = rng.uniform(mu - 3 * s - 2, mu + 3 * s + 2)
        ok = rng.random() < NormalDist(mu, s).cdf(r)
        rate = 100.0 if ok else 1.0
        m.observe(LinkSample(float(i), r, rate, rate, 100.0), float(i))
    want = min(max(mu + NormalDist().inv_cdf(1 - outage) * s, BOUNDS[0]), BOUNDS[1])
    assert m.threshold_dbm == pytest.approx(want, abs=1.0 + 0.3 * s)


@settings(max_examples=20, deadline=None)
@given(
    penalty=st.floats(-6.0, 10.0),
    fade=st.sampled_from([0.5, 1.0, 2.0]),
    seed=st.integers(0, 10_000),
    phy=st.sampled_from(["802.11g", "802.11n-1x1"]),
)
def test_converges_on_the_rate_ladder(penalty: float, fade: float, seed: int, phy: str) -> None:
    """A relay driving away whose radio picks its rate from the local mean minus a penalty:
    every rate step it passes says where the target's step is, so mu ends at the target
    rate's sensitivity plus the penalty, and the limit a little above it (never below)."""
    table = RATE_TABLES[phy]
    rng = random.Random(seed)
    m = LinkModel(params(half_life_samples=60.0))
    for i in range(300):
        mean = -50.0 - 35.0 * i / 300
        rate = phy_rate_mbps(mean - penalty, table)
        m.observe(
            LinkSample(float(i), round(mean + rng.gauss(0.0, fade)), rate, rate, 95.0), float(i)
        )
    edge = -74.0 + penalty  # 24 (or 26) Mbit/s x 95 % x 0.5 >= 10 Mbit/s; 18 (19.5) falls short
    mu, _s = m.estimate()
    assert mu == pytest.approx(edge, abs=1.0 + fade)
    assert edge - 0.5 <= m.threshold_dbm <= edge + 2.0 + 2.0 * fade


def test_a_poll_on_a_ladder_says_which_band_rssi_was_in() -> None:
    band = LinkModel._band
    p = params()
    assert band(LinkSample(0.0, -60.0, 24.0, 36.0, 95.0), p) == (0.0, 4.0)  # the target's own step
    assert band(LinkSample(0.0, -60.0, 54.0, 54.0, 95.0), p) == (
        9.0,
        math.inf,
    )  # the fastest: no top
    assert band(LinkSample(0.0, -60.0, 18.0, 18.0, 95.0), p) == (-3.0, 0.0)  # one step short
    assert band(LinkSample(0.0, -60.0, 39.0, 39.0, 60.0), p) == (
        0.0,
        4.0,
    )  # n, low CCQ: 39 is the target
    assert (
        band(LinkSample(0.0, -60.0, 130.0, 130.0, 95.0), p) is None
    )  # two streams: a bare verdict
    assert band(LinkSample(0.0, -60.0, 54.0, 54.0, 10.0), p) is None  # no rate meets it at 10 % CCQ


def test_polls_count_by_the_ground_covered() -> None:
    assert LinkSample(0, -60, 54, 54, 95, None).weight() == 1.0
    assert LinkSample(0, -60, 54, 54, 95, 0.4).weight() == 1.0
    assert LinkSample(0, -60, 54, 54, 95, 0.1).weight() == pytest.approx(0.5)
    assert LinkSample(0, -60, 54, 54, 95, 0.0).weight() == pytest.approx(0.05)
    assert LinkSample(0, -60, 54, 54, 95, math.nan).weight() == 1.0


@settings(max_examples=40, deadline=None)
@given(
    penalty=st.floats(-4.0, 8.0),
    seed=st.integers(0, 10_000),
    stand_at=st.floats(-76.0, -62.0),
    polls=st.integers(1, 300),
    fade=st.sampled_from([0.5, 1.5, 3.0]),
)
def test_never_relaxes_standing_still(
    penalty: float, seed: int, stand_at: float, polls: int, fade: float
) -> None:
    """Polls taken standing still may tighten the limit, never relax it: however long the
    relay stands where the hop meets the target (or does not), the limit in force only rises."""
    rng = random.Random(seed)
    m = LinkModel(params())
    t = 0.0
    for i in range(120):  # the drive out to the spot
        mean = -55.0 + (stand_at + 55.0) * i / 120
        rate = phy_rate_mbps(mean - penalty)
        t += 1.0
        m.observe(LinkSample(t, round(mean + rng.gauss(0.0, fade)), rate, rate, 95.0, 0.3), t)
    rate = phy_rate_mbps(stand_at - penalty)
    before = m.threshold_dbm
    for _ in range(polls):
        t += 1.0
        m.observe(LinkSample(t, round(stand_at + rng.gauss(0.0, fade)), rate, rate, 95.0, 0.0), t)
        assert m.threshold_dbm >= before
        before = m.threshold_dbm


LADDER_RATES = sorted({rate for table in RATE_TABLES.values() for _sens, rate in table})
#: Poll histories: time step, RSSI^b, a rate (none, any, or one on an 802.11 ladder), CCQ.
samples = st.lists(
    st.tuples(
        st.floats(0.0, 5.0),
        st.floats(-110.0, -10.0),
        st.one_of(st.none(), st.floats(0.0, 300.0), st.sampled_from(LADDER_RATES)),
        st.one_of(st.none(), st.floats(0.0, 100.0)),
    ),
    max_size=60,
)


@settings(max_examples=60, deadline=None)
@given(history=samples, lo=st.floats(-95.0, -60.0), width=st.floats(1.0, 40.0))
def test_bounded(
    history: list[tuple[float, float, float | None, float | None]], lo: float, width: float
) -> None:
    m = LinkModel(params(bounds_dbm=(lo, lo + width), fallback_dbm=lo + width / 2, min_samples=1.0))
    t = 0.0
    for dt, r, rate, ccq in history:
        t += dt
        m.observe(LinkSample(t, r, rate, rate, ccq, dt / 5.0), t)  # standing (dt 0) to a metre
        assert lo <= m.threshold_dbm <= lo + width
        assert math.isfinite(m.status(t).mu_dbm)


@settings(max_examples=60, deadline=None)
@given(
    history=samples,
    late=st.lists(
        st.tuples(st.floats(3.01, 100.0), st.floats(-110.0, -10.0), st.floats(0.0, 300.0)),
        min_size=1,
        max_size=20,
    ),
    gap=st.floats(0.0, 1000.0),
)
def test_never_relaxes_on_stale_data(
    history: list[tuple[float, float, float | None, float | None]],
    late: list[tuple[float, float, float]],
    gap: float,
) -> None:
    """Polls older than the stale limit when they arrive, or not newer than the last one,
    change nothing; and with no fresh poll the limit holds however long it waits."""
    m = LinkModel(params(min_samples=1.0, stale_s=3.0))
    t = 0.0
    for dt, r, rate, ccq in history:
        t += dt
        m.observe(LinkSample(t, r, rate, rate, ccq), t)
    before = m.threshold_dbm
    now = t + gap
    for age, r, rate in late:
        assert not m.observe(LinkSample(now - age, r, rate, rate, 100.0), now)
        assert m.threshold_dbm == before
    if m.last_t is not None:  # a repeat of the last poll's time is not news either
        assert not m.observe(LinkSample(m.last_t, -40.0, 300.0, 300.0, 100.0), m.last_t)
    assert m.threshold_dbm == before
    assert m.status(now + 10.0).stale


def test_unusable_polls_are_counted_not_learned() -> None:
    m = LinkModel(params(min_samples=1.0))
    assert not m.observe(LinkSample(1.0, -70.0, None, None, 90.0), 1.0)
    assert not m.observe(LinkSample(2.0, math.nan, 54.0, 54.0, 90.0), 2.0)
    assert m.unusable == 2 and m.accepted == 0


def test_delivered_rate_uses_the_slower_direction_and_ccq() -> None:
    assert LinkSample(0, -60, 54.0, 24.0, 50.0).delivered_mbps(0.5) == pytest.approx(6.0)
    assert LinkSample(0, -60, None, 24.0, None).delivered_mbps(0.5) == pytest.approx(12.0)


def test_bad_params_are_refused() -> None:
    with pytest.raises(ValueError):
        LinkPolicyParams(bounds_dbm=(-50.0, -80.0))
    with pytest.raises(ValueError):
        LinkPolicyParams(outage=0.7)


# -- the seam in the brain --------------------------------------------------------------


def rear_poll(t: float, signal_dbm: float, rate: float) -> LinkEvent:
    sta = Station(
        mac="00:11:22:33:44:55", signal_dbm=signal_dbm, ccq_pct=95.0, tx_mbps=rate, rx_mbps=rate
    )
    q = LinkQuality(
        t=t,
        signal_dbm=None,
        rssi=None,
        noise_dbm=-95.0,
        ccq_pct=None,
        tx_mbps=None,
        rx_mbps=None,
        stations=(sta,),
        mode="ap",
    )
    return LinkEvent(t, LinkSide.REAR, q)


@pytest.mark.parametrize("adaptive", [False, True])
def test_brain_sets_the_controllers_rear_limit_only_when_adaptive(adaptive: bool) -> None:
    brain = Brain(
        BrainParams(
            control=ControlParams(threshold_b_dbm=-66.0),
            link=params(adaptive=adaptive, min_samples=5.0),
        )
    )
    views = []
    rng = random.Random(3)
    for i in range(200):
        mean = -55.0 - 20.0 * i / 200
        rate = phy_rate_mbps(mean)
        views += [
            a
            for a in brain.handle(rear_poll(float(i), round(mean + rng.gauss(0, 1.0)), rate))
            if isinstance(a, LinkModelView)
        ]
    assert views and views[-1].model.policy == ("adaptive" if adaptive else "fixed")
    learned = brain.link_model.threshold_dbm
    assert learned < -70.0  # a clean hop: the model would relax
    in_force = brain.rear.control.threshold_b_dbm
    assert in_force == (pytest.approx(learned) if adaptive else -66.0)
    assert views[-1].threshold_b_dbm == in_force


def test_brain_tells_the_model_how_far_the_relay_moved_between_rear_polls() -> None:
    from drivers.arcos.sip import Sip
    from relayd.core.events import SipEvent

    seen: list[LinkSample] = []

    class Spy(LinkModel):
        def observe(self, sample: LinkSample, now: float) -> bool:
            seen.append(sample)
            return super().observe(sample, now)

    bp = BrainParams(control=ControlParams(threshold_b_dbm=-66.0), link=params(min_samples=1.0))
    brain = Brain(bp, link_model=Spy(bp.link))
    for i, x_mm in enumerate((0.0, 300.0, 300.0)):
        sip = Sip(
            t=float(i),
            x_mm=x_mm,
            y_mm=400.0 * i,
            theta_deg=0.0,
            left_mm_s=0.0,
            right_mm_s=0.0,
            battery_v=13.0,
            motors_enabled=True,
            estop=False,
            stall_left=False,
            stall_right=False,
            moving=False,
            sonar=(),
        )
        brain.handle(SipEvent(float(i), sip, ()))
        brain.handle(rear_poll(float(i) + 0.5, -60.0, 54.0))
    assert [s.moved_m for s in seen] == [None, pytest.approx(0.5), pytest.approx(0.4)]


def test_status_shows_the_limit_in_force_and_the_model() -> None:
    from relayd.api.status import Status
    from relayd.runtime.state import RelayState
    from relayd.runtime.statewriter import StateWriter

    brain = Brain(
        BrainParams(control=ControlParams(threshold_b_dbm=-66.0), link=params(min_samples=3.0))
    )
    state = RelayState()
    state.thresholds = {"threshold_b_dbm": -66.0}
    writer = StateWriter(state)
    for i in range(10):
        ev = rear_poll(float(i), -60.0, 54.0)
        writer.apply(ev, brain.handle(ev))
    doc = state.snapshot(10.0)
    Status.model_validate_json(json.dumps(doc), strict=True)  # as the API serves it; no extra keys
    assert doc["link_model"]["policy"] == "adaptive" and doc["link_model"]["samples"] == 10
    assert doc["thresholds"]["threshold_b_dbm"] == doc["link_model"]["threshold_b_dbm"]


# -- its settings -------------------------------------------------------------------------

REAR_AP = {"rear": {"url": "http://192.0.2.1", "password_env": "PW"}}


def _config_errors(control: dict[str, object]) -> list[str]:
    from relayd.config.load import parse_settings
    from relayd.config.model import ConfigError

    with pytest.raises(ConfigError) as ei:
        parse_settings({"ap": REAR_AP, "control": control})
    return ei.value.errors


def test_link_policy_settings_are_strict_and_checked_together() -> None:
    from relayd.config.load import parse_settings
    from relayd.config.params import brain_params

    assert any(
        e.startswith("control.link_policy") for e in _config_errors({"link_policy": "adaptve"})
    )
    assert any(
        e.startswith("control.outage_probability")
        for e in _config_errors({"outage_probability": 0.5})
    )
    assert any(
        e.startswith("control.target_hop_mbps") for e in _config_errors({"target_hop_mbps": "10"})
    )
    assert any(
        e.startswith("control.threshold_b_min_dbm")
        for e in _config_errors({"threshold_b_min_dbm": -50, "threshold_b_max_dbm": -60})
    )
    adaptive = {"link_policy": "adaptive"}
    assert any(
        e.startswith("control.threshold_b_dbm")
        for e in _config_errors({**adaptive, "threshold_b_dbm": -45, "threshold_l_dbm": -30})
    )
    assert any(
        e.startswith("control.threshold_b_max_dbm")
        for e in _config_errors({**adaptive, "threshold_l_dbm": -52})
    )
    from relayd.config.model import ConfigError

    with pytest.raises(ConfigError) as ei:
        parse_settings({"control": {**adaptive, "rear_link": "ignore"}})
    assert any(e.startswith("control.link_policy") for e in ei.value.errors)
    # Fixed mode keeps the paper's -40 dBm with the default bounds; the model only advises.
    fixed = parse_settings({"ap": REAR_AP, "control": {"threshold_b_dbm": -40}})
    assert brain_params(fixed).link.adaptive is False
    s = parse_settings(
        {
            "ap": REAR_AP,
            "control": {
                **adaptive,
                "target_hop_mbps": 20,
                "outage_probability": 0.05,
                "threshold_b_min_dbm": -75,
                "threshold_b_max_dbm": -55,
            },
        }
    )
    lp = brain_params(s).link
    assert (lp.adaptive, lp.target_hop_mbps, lp.outage, lp.bounds_dbm, lp.fallback_dbm) == (
        True,
        20,
        0.05,
        (-75, -55),
        -60,
    )
    assert lp.stale_s == pytest.approx(3.0)  # rear_stale_polls x the rear AP's poll period


def test_relayd_status_prints_the_model() -> None:
    from relayd.cli.status import format_status

    m = LinkModel(params(min_samples=1.0))
    m.observe(LinkSample(1.0, -60.0, 54.0, 54.0, 95.0), 1.0)
    text = format_status(
        {
            "thresholds": {"threshold_b_dbm": m.threshold_dbm},
            "rssi_behind_dbm": -60.0,
            "link_model": m.status(1.0).to_json(),
        }
    )
    line = next(row for row in text.splitlines() if row.startswith("rear limit model"))
    assert "in force" in line and "mu" in line and "1 polls" in line


def test_recovery_judges_restored_against_the_limit_the_controller_drives_by(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """In adaptive mode the brain's rear limit is learned; recovery's "restored" check takes
    the same value, not the configured one (one rear limit; docs/CONTROL.md section 9)."""
    import relayd.core.brain as brain_module
    from relayd.core.events import ModeCommand, Tick
    from relayd.core.recovery.state import RecoveryParams
    from relayd.core.vocab import Mode

    seen: list[float] = []
    real = brain_module.recovery_step

    def spy(inp, p, m):  # type: ignore[no-untyped-def]
        seen.append(p.control.threshold_b_dbm)
        return real(inp, p, m)

    monkeypatch.setattr(brain_module, "recovery_step", spy)
    brain = Brain(
        BrainParams(
            control=ControlParams(threshold_b_dbm=-66.0),
            link=params(adaptive=True, min_samples=5.0),
            recovery=RecoveryParams(enabled=True, control=ControlParams(threshold_b_dbm=-66.0)),
            has_scanner=False,
        )
    )
    rng = random.Random(3)
    for i in range(200):
        mean = -55.0 - 20.0 * i / 200
        brain.handle(rear_poll(float(i), round(mean + rng.gauss(0, 1.0)), phy_rate_mbps(mean)))
    learned = brain.rear.control.threshold_b_dbm
    assert learned < -70.0  # the model relaxed the limit: the two now differ
    brain.handle(ModeCommand(200.0, Mode.FOLLOW))
    brain.handle(Tick(200.1))
    assert seen, "recovery never ran"
    assert seen[-1] == pytest.approx(learned)
