"""Item 4 of bench/tracking.py: how much of the time each relay is within 5 m of its own leader.

The relays follow by RSSI, not by distance: they stop on "leader_near" when RSSI^l
reaches threshold_l and drive at the speed law v = -w1 * RSSI^l - w2 in between
(docs/CONTROL.md sections 4-5). So this figure measures the bearing estimator *and* the
stop policy. To tell them apart, every estimator runs under several policies in the
same run:

- "paper": the scenario's own thresholds and the paper's speed law (w1 10, w2 150).
- "gap 3 m": asked to follow 3 m behind. threshold_l is what `relayd calibrate
  path-loss --link leader --hop-m 3` prints for the scenario's radio (the median
  RSSI^l at 3 m, relayd/calibrate/report.py), and the speed law is set so the relay
  drives at its leader's walking speed where it stops and at v_max where the median
  RSSI^l is that of 5 m.
- "within 5 m": asked never to stop more than 5 m behind but with probability 0.1 %:
  threshold_l is what `relayd calibrate path-loss --link leader --hop-m 5 --outage
  0.001` prints as "gap at most 5 m" (the median at 5 m raised by z sigma, as for a hop
  length), i.e. a median gap of 1.3-1.6 m; the same speed law.

Both asked-for policies also release a "leader_near" stop while the front sonars put the
leader at least `GAP_MAX_M` away (`control.leader_gap_max_m`, docs/CONTROL.md 5.3): the
stops a bright spot causes with the leader far. "paper" leaves it off.

The radio is the scenario's own L0, n and sigma (`PathLossFit.known`): a perfect
calibration, so what is left is the shadowing the thresholds must cover. threshold_b
stays the scenario's in every policy: holding the link behind is the relay's duty.
Reported per policy and estimator: the share of trace records within 5 m (mean over
relays and seeds, the worst relay-run), the same over the time the relay was free to
follow (not held by "rear_weak"), and the time beyond 5 m by the relay's reason then.
The corridor is also run with a third relay (the "within 5 m" policy): whether one more
relay shortens the time the chain holds on "rear_weak"; and with the rear link not
required (`CORRIDOR_REAR_FREE`): the tracking round the corners with that duty lifted.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from bench.common import Result
from relayd.calibrate.fit import PathLossFit
from relayd.calibrate.report import Wanted, thresholds
from relayd.config.model import ControlSettings
from relayd.sim.scenario import RelaySpec, Scenario

NAME = "tracking"
WITHIN_M = 5.0
#: (scenario, target share): the convoy in line of sight, the corridor round brick corners.
SCENARIOS: tuple[tuple[str, float], ...] = (("convoy", 0.99), ("corridor", 0.95))
#: Where a third corridor relay starts: behind relay2 (x 0.5), 1 m in front of the command center.
EXTRA_RELAY = RelaySpec(name="relay3", x=-0.5, y=0.0)
#: The "within 5 m" policy's accepted probability of a stop beyond 5 m.
WITHIN_OUTAGE = 0.001
FOLLOW_GAP_M = 3.0
#: `control.leader_gap_max_m` of the asked-for policies: 1.5 m short of 5 m, as a relay
#: released at its leader's designed pace needs against a leader relay catching up
#: (docs/CONTROL.md 5.3 has the measurements).
GAP_MAX_M = 3.5

#: Why a relay beyond 5 m of its leader was there, as its trace records say.
HELD_REAR, HELD_NEAR, DRIVING = "rear_weak", "leader_near", "driving"


@dataclass(frozen=True)
class Share:
    """One relay in one run: the share of time within 5 m, and what it was doing beyond."""

    within: float
    #: The same share over the time it was free to follow: not held by "rear_weak" (its
    #: duty: it stands so the link behind it holds, wherever its leader goes).
    within_free: float
    #: Share of all time spent beyond 5 m, by the relay's reason then.
    beyond: dict[str, float]
    #: Share of all time held by "rear_weak".
    held_rear: float = 0.0


def relay_shares(records: list[dict[str, Any]]) -> list[Share]:
    """Per relay, its `Share` of one simulator run's trace records."""
    out = []
    for i in range(len(records[0]["relays"]) if records else 0):
        rows = [r["relays"][i] for r in records]
        free = [r for r in rows if r["reason"] != HELD_REAR]
        beyond: dict[str, float] = {}
        for r in rows:
            if r["gap_m"] > WITHIN_M:
                beyond[r["reason"]] = beyond.get(r["reason"], 0.0) + 1.0 / len(rows)
        out.append(
            Share(
                sum(r["gap_m"] <= WITHIN_M for r in rows) / len(rows),
                sum(r["gap_m"] <= WITHIN_M for r in free) / len(free) if free else math.nan,
                beyond,
                1.0 - len(free) / len(rows),
            )
        )
    return out


# -- policies ------------------------------------------------------------------------------


def scenario_fit(sc: Scenario) -> PathLossFit:
    """The scenario's radio as a calibration would find it, with no fitting error."""
    r = sc.radio_params()
    return PathLossFit.known(r.l0_dbm, r.exponent, r.shadow_sigma_db)


def speed_law(
    fit: PathLossFit,
    threshold_l_dbm: float,
    leader_mm_s: float,
    v_max_mm_s: float,
    full_at_m: float = WITHIN_M,
) -> tuple[float, float]:
    """(w1, w2) of v = -w1 RSSI^l - w2 through two points: the leader's speed at the
    stopping level (so a relay that may drive keeps up), v_max where the median RSSI^l is
    that of `full_at_m` (so a relay that fell back catches up at full speed)."""
    span_db = threshold_l_dbm - fit.rssi_at(full_at_m)
    if span_db <= 0:
        raise ValueError(
            f"threshold_l {threshold_l_dbm:.1f} dBm is not above the median at {full_at_m:g} m"
        )
    w1 = (v_max_mm_s - leader_mm_s) / span_db
    return w1, -w1 * threshold_l_dbm - leader_mm_s


def follow_control(sc: Scenario, threshold_l_dbm: float) -> dict[str, Any]:
    """[control] overrides for a policy with this threshold_l: the matching speed law, and
    the sonar release of "leader_near" beyond GAP_MAX_M."""
    fit = scenario_fit(sc)
    v_max = float(sc.control.get("v_max_mm_s", ControlSettings().v_max_mm_s))
    w1, w2 = speed_law(fit, threshold_l_dbm, 1000.0 * sc.leader.speed_m_s, v_max)
    return {
        "threshold_l_dbm": round(threshold_l_dbm, 1),
        "w1": round(w1, 1),
        "w2": round(w2, 1),
        "leader_gap_max_m": GAP_MAX_M,
    }


def gap_threshold(sc: Scenario, gap_m: float = FOLLOW_GAP_M) -> float:
    """What `relayd calibrate path-loss --link leader --hop-m GAP` prints for threshold_l."""
    thr = thresholds(scenario_fit(sc), [], Wanted(link="leader", hop_m=gap_m)).chosen
    assert thr is not None  # a hop length was asked
    return thr


def within_threshold(
    sc: Scenario, within_m: float = WITHIN_M, outage: float = WITHIN_OUTAGE
) -> float:
    """What `relayd calibrate path-loss --link leader --hop-m 5 --outage 0.001` prints as "gap at
    most 5 m": no stop beyond `within_m` but with probability `outage`."""
    thr = thresholds(
        scenario_fit(sc), [], Wanted(link="leader", hop_m=within_m, outage=outage)
    ).bound
    assert thr is not None  # a leader link and a hop length were asked
    return thr


@dataclass(frozen=True)
class Policy:
    name: str
    #: [control] overrides for a scenario ({} = the scenario's own).
    control: Callable[[Scenario], dict[str, Any]]
    extra_relay: bool = False


POLICIES: tuple[Policy, ...] = (
    Policy("paper", lambda sc: {}),
    Policy(f"gap {FOLLOW_GAP_M:g} m", lambda sc: follow_control(sc, gap_threshold(sc))),
    Policy(f"within {WITHIN_M:g} m", lambda sc: follow_control(sc, within_threshold(sc))),
)
CORRIDOR_PLUS_ONE = Policy(
    f"within {WITHIN_M:g} m, 3 relays", POLICIES[2].control, extra_relay=True
)
#: The corridor's relays hold on "rear_weak" for half of the walk: the chain cannot span it
#: with every relay within 5 m of the next. This policy asks what the tracking alone does
#: round the brick corners (non-line-of-sight) with that duty lifted (`rear_link =
#: "ignore"`), as the paper lifted it for its convoy (threshold_b -60 "to be free from the
#: distance constraint"): the relays then follow the person the whole way.
CORRIDOR_REAR_FREE = Policy(
    f"within {WITHIN_M:g} m, rear link not required",
    lambda sc: {**POLICIES[2].control(sc), "rear_link": "ignore"},
)


def policy_scenario(scenario: str, policy: Policy, scan: dict[str, object]) -> Scenario:
    from relayd.sim.scenario import load_scenario

    sc = load_scenario(scenario)
    update: dict[str, Any] = {
        "scan": {**sc.scan, **scan},
        "control": {**sc.control, **policy.control(sc)},
    }
    if policy.extra_relay:
        update |= {"relay": [*sc.relay, EXTRA_RELAY], "relays": len(sc.relay) + 1}
    return sc.model_copy(update=update)


# -- runs ------------------------------------------------------------------------------------


async def _sim(sc: Scenario, seed: int, seconds: float | None) -> list[Share]:
    from relayd.sim.runner import SimRunner

    result = await SimRunner(sc, speed=None, seed=seed, seconds=seconds).run()
    return relay_shares(result.records)


def sim_share(sc: Scenario, seeds: int, seconds: float | None = None) -> list[Share]:
    """Per relay and seed (1..seeds), the `Share` of one scenario."""
    from relayd.runtime import vtime
    from relayd.runtime.logsetup import StdStream, setup_logging

    setup_logging("error", "console", StdStream("stderr"))  # the daemons' info lines cost time
    shares: list[Share] = []
    for seed in range(1, seeds + 1):
        shares += vtime.run(_sim(sc, seed, seconds))
    return shares


def _mean(xs: Sequence[float]) -> float:
    xs = [x for x in xs if math.isfinite(x)]
    return sum(xs) / len(xs) if xs else math.nan


def rows(
    scenario: str,
    target: float,
    policy: Policy,
    cfg: tuple[str, str],
    seeds: int,
    seconds: float | None,
) -> list[Result]:
    """The two table rows of one (scenario, policy, estimator): within 5 m, and within while free."""
    label = f"{cfg[0]}/{cfg[1]}"
    sc = policy_scenario(scenario, policy, {"estimator": cfg[0], "window": cfg[1]})
    shares = sim_share(sc, seeds, seconds)
    mean = _mean([x.within for x in shares])
    worst = min((x.within for x in shares), default=math.nan)
    free = _mean([x.within_free for x in shares])
    held = _mean([x.held_rear for x in shares])
    reasons = sorted(
        {k for x in shares for k in x.beyond},
        key=lambda k: -sum(x.beyond.get(k, 0.0) for x in shares),
    )
    beyond = ", ".join(
        f"{k} {100 * _mean([x.beyond.get(k, 0.0) for x in shares]):.1f} %" for k in reasons
    )
    c = sc.control
    law = (
        f"threshold_l {c['threshold_l_dbm']:g} dBm (median gap {scenario_fit(sc).distance_at(c['threshold_l_dbm']):.1f} m)"
        f", w1 {c['w1']:g}, w2 {c['w2']:g}, sonar release at {c['leader_gap_max_m']:g} m"
        if "w1" in c
        else "the scenario's thresholds, w1 10, w2 150"
    )
    where = f"{scenario} ({policy.name})"
    return [
        Result(
            NAME,
            f"{where}: share of time within 5 m of its leader (mean over relays and seeds), {label}",
            100.0 * mean,
            "%",
            f">= {100 * target:g} %",
            mean >= target,
            f"{seeds} seeds x {sc.relays} relays; worst relay-run {100 * worst:.1f} %; "
            f"beyond 5 m: {beyond or 'never'}; {law}",
        ),
        Result(
            NAME,
            f"{where}: the same while free to follow (not held by rear_weak), {label}",
            100.0 * free,
            "%",
            "",
            None,
            f"held on rear_weak {100 * held:.1f} % of the time",
        ),
    ]


def sim_rows(
    configs: Sequence[tuple[str, str]],
    *,
    quick: bool,
    seeds: int,
    scenarios: Sequence[str] | None = None,
    progress: Callable[[str], None] = lambda s: None,
) -> list[Result]:
    """Item 4: every scenario x policy x estimator, then the corridor with one relay more
    and with the rear link not required.

    Each row runs the first and the last of `configs` (the paper's WCA and the default):
    lobe/full adds nothing here that the other two do not show, and 10 seeds of 16 rows
    take 10-15 minutes on an idle 2-core machine (40 loaded).
    """
    seconds = 20.0 if quick else None
    pair = (configs[0], configs[-1]) if len(configs) > 1 else tuple(configs)
    out: list[Result] = []
    for scenario, target in SCENARIOS:
        if scenarios is not None and scenario not in scenarios:
            continue
        for policy in (
            *POLICIES,
            *((CORRIDOR_PLUS_ONE, CORRIDOR_REAR_FREE) if scenario == "corridor" else ()),
        ):
            for cfg in pair:
                progress(f"   item 4: {scenario}, {policy.name}, {cfg[0]}/{cfg[1]}")
                out += rows(scenario, target, policy, cfg, seeds, seconds)
    return out
