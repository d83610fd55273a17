"""The link behind as the brain knows it: RSSI^b, the link model, the retreat, the limit in force.

`RearLinkMemory` is the one writer of that memory; the brain (relayd.core.brain) hands it
each rear-AP poll and asks it for the controller's rear limit. The rear radio's station
list (or, in station mode, its own signal) gives RSSI^b; the same poll, with how far the
relay moved since the last one, is one sample for the rear-link model
(relayd.core.link.model), which learns in both link policies (fixed: advice on /status
only; adaptive: its threshold becomes the controller's threshold_b).
"""

from __future__ import annotations

import math
from dataclasses import replace

from drivers.airos.model import LinkQuality, Station
from relayd.core.control.inputs import ControlInputs, ControlOutput
from relayd.core.control.params import ControlParams
from relayd.core.events import Action, LinkEvent, LinkModelView, RearLink
from relayd.core.link.model import LinkModel, LinkPolicyParams, LinkSample
from relayd.core.link.retreat import RetreatMemory, held_limit, record_poll, retreat_step


def rear_signal(q: LinkQuality, mac: str | None) -> tuple[float | None, Station | None]:
    """RSSI^b and the station it is from: `mac`'s when configured, else the strongest."""
    if mac is not None:
        value = q.station_signal_dbm(mac)
        peer = next(
            (
                s
                for s in q.stations
                if s.mac is not None
                and s.signal_dbm == value
                and s.mac.lower().replace("-", ":") == mac.lower().replace("-", ":")
            ),
            None,
        )
        return value, peer
    # A rear radio in station mode has no station list: its own signal is the link's.
    best = q.best_station
    return (best.signal_dbm if best is not None else q.signal_dbm), best


def link_sample(
    t: float,
    q: LinkQuality,
    rssi_dbm: float,
    peer: Station | None,
    pose: tuple[float, float, float] | None,
    last_pose: tuple[float, float, float] | None,
) -> LinkSample:
    """One poll as the rear-link model's sample (rates from the peer station when known)."""
    tx, rx, ccq = (
        (peer.tx_mbps, peer.rx_mbps, peer.ccq_pct)
        if peer is not None
        else (q.tx_mbps, q.rx_mbps, q.ccq_pct)
    )
    moved = None
    if pose is not None and last_pose is not None:
        moved = math.hypot(pose[0] - last_pose[0], pose[1] - last_pose[1]) / 1000.0
    return LinkSample(q.t if math.isfinite(q.t) else t, rssi_dbm, tx, rx, ccq, moved)


class RearLinkMemory:
    """RSSI^b, its freshness, the rear-link model and the retreat; the limit they put in force."""

    def __init__(
        self,
        control: ControlParams,
        link: LinkPolicyParams,
        station_mac: str | None,
        model: LinkModel | None = None,
    ) -> None:
        """`model`: the rear-link model to learn with, else a new one from `link` (a set-up seam,
        e.g. for a test that watches what the model is told). It is given here or not at all:
        `model` is read-only, so the model the brain starts with is the one it keeps."""
        self._base = control
        self._link = link
        self._mac = station_mac
        self.dbm: float | None = None
        self.t: float | None = None
        self.polls = 0
        self._shown: float | None = None
        #: The pose at the last poll the model learned from (how far it moved between polls).
        self._learned_pose: tuple[float, float, float] | None = None
        self._model = LinkModel(link) if model is None else model
        #: Stepping back out of a shadow (relayd.core.link.retreat, adaptive only).
        self.retreat = RetreatMemory()
        self.control = self._with_limit()

    @property
    def model(self) -> LinkModel:
        """The rear-link model (read-only: it is given, if at all, when the memory is made)."""
        return self._model

    def on_poll(self, ev: LinkEvent, pose: tuple[float, float, float] | None) -> list[Action]:
        """One rear-AP poll: RSSI^b, then what the model learns from it."""
        value, peer = rear_signal(ev.quality, self._mac)
        self.dbm, self.t = value, ev.t
        self.polls += 1
        return self.view(ev.t) + self._learn(ev, value, peer, pose)

    def _learn(
        self,
        ev: LinkEvent,
        rssi_dbm: float | None,
        peer: Station | None,
        pose: tuple[float, float, float] | None,
    ) -> list[Action]:
        """Feed the rear-link model one poll; in adaptive mode its limit becomes the controller's."""
        if rssi_dbm is None:
            return []
        sample = link_sample(ev.t, ev.quality, rssi_dbm, peer, pose, self._learned_pose)
        if not self._model.observe(sample, ev.t):
            return []
        self._learned_pose = pose
        delivered = self._model.last_delivered_mbps
        self.retreat = record_poll(
            self.retreat,
            pose,
            rssi_dbm,
            delivered is not None and delivered >= self._link.target_hop_mbps,
        )
        self.control = self._with_limit()
        return [LinkModelView(self.in_force().threshold_b_dbm, self._model.status(ev.t))]

    def _with_limit(self) -> ControlParams:
        if not self._link.adaptive:
            return self._base
        return replace(self._base, threshold_b_dbm=self._model.threshold_dbm)

    def in_force(self) -> ControlParams:
        """The controller's params: the rear limit, raised while holding after a retreat."""
        return held_limit(self.control, self.retreat, self._link.bounds_dbm[1])

    def retreat_step(
        self, ci: ControlInputs, sonar_mm: tuple[int | None, ...], out: ControlOutput
    ) -> ControlOutput:
        """The retreat's say over the law's command (adaptive only; relayd.core.link.retreat)."""
        out, self.retreat = retreat_step(
            ci, sonar_mm, out, self.control, self.retreat, enabled=self._link.adaptive
        )
        return out

    def view(self, now: float) -> list[Action]:
        """RSSI^b as /status may show it: not a value the controller already refuses as stale."""
        value = self.dbm
        if self.t is None or now - self.t > self._base.rear_timeout_s:
            value = None
        if value == self._shown:
            return []
        self._shown = value
        return [RearLink(value)]
