"""Everything the brain is configured with, in one frozen value (relayd.config.params builds it)."""

from __future__ import annotations

from dataclasses import dataclass, field

from relayd.core.control.law import ControlParams
from relayd.core.link.model import LinkPolicyParams
from relayd.core.plan.navigator import NavParams
from relayd.core.recovery.state import RecoveryParams
from relayd.core.scan.estimator import EstimatorParams
from relayd.core.scan.leader import LeaderParams
from relayd.core.scan.plan import ScanParams
from relayd.core.trail.keeper import TrailParams


@dataclass(frozen=True, slots=True)
class BrainParams:
    """Everything the brain is configured with (built from the config by `relayd.config.params`)."""

    control: ControlParams = field(default_factory=ControlParams)
    estimator: EstimatorParams = field(default_factory=EstimatorParams)
    scan: ScanParams = field(default_factory=ScanParams)
    #: Which bearing estimator and scan window (`relayd.core.scan.leader`); built from the config, whose
    #: default is "lobe"/"adaptive" (this bare default, "wca"/"full", is the paper's).
    leader: LeaderParams = field(default_factory=LeaderParams)
    #: A scan servo is configured: until it answers, follow mode stops on "scan_servo".
    has_scanner: bool = True
    #: RSSI^b from this station of the rear AP; None: the strongest station heard.
    rear_station_mac: str | None = None
    #: The rear-link model; with `adaptive` its threshold replaces control.threshold_b_dbm.
    link: LinkPolicyParams = field(default_factory=LinkPolicyParams)
    #: Self-healing of broken links (relayd.core.recovery.machine); disabled by default.
    recovery: RecoveryParams = field(default_factory=RecoveryParams)
    #: The leader's trail and the pursuit along it (relayd/core/trail; docs/CONTROL.md 7.1).
    trail: TrailParams = field(default_factory=TrailParams)
    #: The sonar map and the detours round what it shows (relayd/core/plan).
    nav: NavParams = field(default_factory=lambda: NavParams(enabled=False))
