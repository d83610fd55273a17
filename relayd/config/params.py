"""The brain's parameters, built from the config models in one place.

`ControlParams` and `EstimatorParams` (the pure modules' own frozen dataclasses) take
every field whose name is a key of the config's `[control]` or `[scan]` section
straight from it (the escape's `AvoidParams` and the `Actuator` from `[avoidance]`), so a new tunable is written twice (the config model and the
dataclass), never a third time here. Only the fields derived from several settings
(timeouts, the rear-link switch) are computed below, each with its reason.
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

from pydantic import BaseModel

from relayd.config.model import Settings, load_pattern_file
from relayd.core.avoid.state import AvoidParams
from relayd.core.control.actuator import Actuator
from relayd.core.control.law import ControlParams
from relayd.core.control.search import SearchParams
from relayd.core.link.model import LinkPolicyParams
from relayd.core.params import BrainParams
from relayd.core.plan.navigator import NavParams
from relayd.core.recovery.state import RecoveryParams
from relayd.core.scan.estimator import EstimatorParams
from relayd.core.scan.leader import LeaderParams
from relayd.core.scan.plan import ScanParams
from relayd.core.scan.window import WindowParams
from relayd.core.trail.align import Frame
from relayd.core.trail.estimate import EstimateParams, RangeModel
from relayd.core.trail.feed import FeedParams
from relayd.core.trail.keeper import TrailParams

P = TypeVar("P")

#: RSSI freshness on the sample stream: never judged over less than this (s) ...
RSSI_STALE_MIN_S = 0.5
#: ... nor over fewer than this many sample periods.
RSSI_STALE_SAMPLES = 5
#: "No completed scan for 2 scan periods" never fires sooner than this (s): a real sweep
#: also waits for servo replies and the link antenna, which the nominal period leaves
#: out, and a servo that stops answering must be reported as itself ("scan_servo",
#: after the driver's reply timeout), not as a scan that did not finish.
SCAN_STALE_MIN_S = 2.0
#: The search turn's evidence of a leader out of the servo's reach counts for this many
#: nominal scan periods: the loss itself takes 3 scans without a usable lobe, so evidence
#: from before the loss is at most that old when the search starts; one period more lets
#: the turn's own sweeps renew it (docs/CONTROL.md 6.1).
EVIDENCE_SCANS = 4


def _from_sections(cls: type[P], *sections: BaseModel, **derived: Any) -> P:
    """An instance of the dataclass `cls` whose fields come from the sections, by name."""
    values: dict[str, Any] = {}
    dumped = [section.model_dump() for section in sections]
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        for doc in dumped:
            if f.name in doc:
                values[f.name] = doc[f.name]
                break
    values.update(derived)
    return cls(**values)


def scan_period_nominal_s(
    width_deg: float, speed_deg_s: float, samples: int, settle_s: float, sample_hz: float, mode: str
) -> float:
    """A sweep's expected duration: slew time of the window plus the time at each sample."""
    slew = width_deg / speed_deg_s
    if mode == "continuous":
        return slew + 1.0 / sample_hz
    return slew + samples * (settle_s + 1.0 / sample_hz)


def nominal_scan_period_s(settings: Settings) -> float:
    s = settings.scan
    return scan_period_nominal_s(
        s.width_deg,
        settings.pantilt.speed_deg_s,
        s.samples,
        s.settle_s,
        settings.wifi.sample_hz,
        s.mode,
    )


def rssi_timeout_s(sample_hz: float) -> float:
    """No fresh sample for max(0.5 s, 5 sample periods) means the RSSI is stale."""
    return max(RSSI_STALE_MIN_S, RSSI_STALE_SAMPLES / sample_hz)


def control_params(settings: Settings) -> ControlParams:
    c = settings.control
    rear_poll_s = settings.ap.rear.poll_s if settings.ap.rear is not None else 1.0
    return _from_sections(
        ControlParams,
        c,
        rear_link_required=c.rear_link == "require",
        sip_timeout_s=settings.robot.lost_after_s,
        rssi_timeout_s=rssi_timeout_s(settings.wifi.sample_hz),
        rear_timeout_s=c.rear_stale_polls * rear_poll_s,
        # The escape's limits and turn rates ([avoidance]); its stop distance and
        # threshold_o are [control]'s, set by the controller.
        avoid=_from_sections(AvoidParams, settings.avoidance),
        actuator=_from_sections(Actuator, settings.avoidance),
        search=SearchParams(enabled=c.search_turn, rate_deg_s=c.search_turn_deg_s),
    )


def estimator_params(settings: Settings) -> EstimatorParams:
    # gamma (the WCA's) is a [scan] key; the obstacle keys are [control]'s.
    return _from_sections(EstimatorParams, settings.scan, settings.control)


def link_policy_params(settings: Settings) -> LinkPolicyParams:
    """The rear-link model's settings: its staleness limit is the controller's."""
    c = settings.control
    rear_poll_s = settings.ap.rear.poll_s if settings.ap.rear is not None else 1.0
    return LinkPolicyParams(
        adaptive=c.link_policy == "adaptive",
        target_hop_mbps=c.target_hop_mbps,
        outage=c.outage_probability,
        bounds_dbm=(c.threshold_b_min_dbm, c.threshold_b_max_dbm),
        fallback_dbm=c.threshold_b_dbm,
        mac_efficiency=c.mac_efficiency,
        half_life_samples=c.link_half_life_polls,
        stale_s=c.rear_stale_polls * rear_poll_s,
    )


def recovery_params(
    settings: Settings, control: ControlParams, scan_timeout_s: float | None
) -> RecoveryParams:
    # [recovery]'s own keys, then the thresholds and staleness limits the controller uses.
    # The reverse speeds never exceed v_max: a first drive with a low v_max stays slow.
    r = settings.recovery
    return _from_sections(
        RecoveryParams,
        r,
        settings.control,
        retrace_speed_mm_s=min(r.retrace_speed_mm_s, control.v_max_mm_s),
        backup_speed_mm_s=min(r.backup_speed_mm_s, control.v_max_mm_s),
        control=control,
        scan_timeout_s=scan_timeout_s,
    )


def brain_params(settings: Settings) -> BrainParams:
    pt, s = settings.pantilt, settings.scan
    scanning = pt.enabled and settings.wifi.enabled
    rear = settings.ap.rear
    control = control_params(settings)
    scan_timeout_s = (
        max(SCAN_STALE_MIN_S, 2.0 * nominal_scan_period_s(settings)) if scanning else None
    )
    return BrainParams(
        control=control,
        estimator=estimator_params(settings),
        scan=ScanParams(
            scan_channel=pt.scan_channel,
            link_channel=pt.link_channel,
            samples=s.samples,
            width_deg=s.width_deg,
            limits_deg=(float(pt.limits_deg[0]), float(pt.limits_deg[1])),
            lost_rssi_dbm=settings.control.lost_rssi_dbm,
            # The second stale rule: no completed scan for two nominal scan periods.
            scan_timeout_s=scan_timeout_s,
        ),
        leader=LeaderParams(
            estimator=s.estimator,
            window=s.window,
            # Validated when the settings were (ScanSettings), read again here: the brain
            # gets the table, the config keeps the path.
            pattern=load_pattern_file(s.pattern_file) if s.pattern_file is not None else None,
            learn_pattern=s.learn_pattern,
            adaptive=WindowParams(
                # The adaptive window's steps fit the step-mode scanner's clock; a continuous
                # sweep samples at the RSSI rate wherever the servo is.
                servo_deg_s=pt.speed_deg_s if s.mode == "step" else None,
                settle_s=s.settle_s,
                sample_period_s=1.0 / settings.wifi.sample_hz if s.mode == "step" else None,
            ),
            evidence_min_rssi_dbm=settings.control.lost_rssi_dbm,
            evidence_max_age_s=EVIDENCE_SCANS * nominal_scan_period_s(settings),
        ),
        recovery=recovery_params(settings, control, scan_timeout_s),
        has_scanner=scanning,
        rear_station_mac=rear.station_mac if rear is not None else None,
        link=link_policy_params(settings),
        trail=trail_params(settings),
        nav=NavParams(enabled=settings.control.detour),
    )


def trail_params(settings: Settings) -> TrailParams:
    """The leader's trail (relayd/core/trail): the pursuit and the path-loss model."""
    c = settings.control
    model = RangeModel(c.pathloss_l0_dbm, c.pathloss_exponent, c.pathloss_sigma_db)
    # The leader relay's own path, where one is configured (its origin is the frame's prior).
    origin = c.leader_origin if c.leader_url is not None else None
    feed = FeedParams(
        prior=None if origin is None else Frame(*origin),
        stale_s=c.leader_stale_s,
    )
    return TrailParams(pursuit=c.pursuit, estimate=EstimateParams(range_model=model), feed=feed)
