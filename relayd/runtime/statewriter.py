"""The one writer of `RelayState`: the brain's decisions and the events' device data.

The daemon hands every event and the actions the brain returned for it to
`StateWriter.apply`; nothing else assigns a `RelayState` field (device health is read
from the drivers at snapshot time, see `relayd.runtime.health`). The drive-state log line is
written here too, one per change, so the brain stays free of I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import structlog

from relayd.core.events import (
    Action,
    Decision,
    DeviceEvent,
    DeviceStatus,
    Event,
    LinkEvent,
    LinkModelView,
    RearLink,
    RecoveryReport,
    ScanResult,
    ServoPosition,
    SipEvent,
    Tick,
)
from relayd.runtime.state import LinkInfo, RelayState

log = structlog.get_logger(__name__)


class MetricsSink(Protocol):
    def sip_received(self) -> None: ...
    def observe_scan_period(self, seconds: float) -> None: ...


class StateWriter:
    """Applies events and actions to the state, in the order the bus delivers them."""

    def __init__(
        self, state: RelayState, metrics: MetricsSink | None = None, link_channel: int | None = None
    ) -> None:
        self.state = state
        self._metrics = metrics
        self._link_channel = link_channel

    def apply(self, event: Event, actions: Sequence[Action]) -> None:
        self.on_event(event)
        for action in actions:
            self.on_action(action)

    def on_event(self, event: Event) -> None:
        st = self.state
        match event:
            case SipEvent(sip=sip):
                st.x_mm, st.y_mm, st.theta_deg = sip.x_mm, sip.y_mm, sip.theta_deg
                st.battery_v = sip.battery_v
                st.motors_enabled = sip.motors_enabled
                st.sonar_mm = list(event.sonar_mm)
                if self._metrics is not None:
                    self._metrics.sip_received()
            case LinkEvent(quality=q):
                st.links[str(event.side)] = LinkInfo(
                    signal_dbm=q.signal_dbm,
                    rssi=q.rssi,
                    noise_dbm=q.noise_dbm,
                    ccq_pct=q.ccq_pct,
                    tx_mbps=q.tx_mbps,
                    rx_mbps=q.rx_mbps,
                    t=event.t,
                )
            case ServoPosition() if event.channel == self._link_channel:
                st.link_bearing_deg = event.angle_deg
            case DeviceEvent(device="robot", status=DeviceStatus.UP) if event.detail:
                st.robot_name = event.detail
            case Tick():
                # /healthz and the watchdog judge the timer, not SIP-driven steps: a wedged
                # timer means silence would no longer stop the robot.
                st.loop_tick_t = event.t
            case _:
                pass

    def on_action(self, action: Action) -> None:
        st = self.state
        match action:
            case Decision():
                st.wheels_left_mm_s = action.left_mm_s
                st.wheels_right_mm_s = action.right_mm_s
                st.situation = action.situation
                if action.mode is not st.mode:
                    log.info("mode_changed", old=str(st.mode), new=str(action.mode))
                    st.mode = action.mode
                    st.touch()
                if action.changed:
                    log.info(
                        "drive_state",
                        state=str(action.state),
                        reason=action.reason,
                        left_mm_s=round(action.left_mm_s, 1),
                        right_mm_s=round(action.right_mm_s, 1),
                    )
                    st.state = action.state
                    st.reason = action.reason
                    st.touch()
            case ScanResult(record=rec):
                st.last_scan = rec
                st.scan_count += 1
                st.bearing_deg = action.estimate.bearing_deg
                sd = action.estimate.bearing_sd_deg
                st.bearing_sd_deg = None if sd is None else round(sd, 2)
                st.rssi_leader_dbm = action.estimate.rssi_leader_dbm
                st.touch()
                if self._metrics is not None and rec.period_s is not None:
                    self._metrics.observe_scan_period(rec.period_s)
            case RearLink():
                st.rssi_behind_dbm = action.rssi_behind_dbm
                st.touch()
            case LinkModelView():
                st.thresholds["threshold_b_dbm"] = round(action.threshold_b_dbm, 2)
                st.link_model = action.model
            case RecoveryReport(view=v):
                if st.recovery is None or st.recovery.phase != v.phase:
                    log.info(
                        "recovery",
                        phase=str(v.phase),
                        kind=None if v.kind is None else str(v.kind),
                        episode=v.episodes,
                        outcome=v.last_outcome,
                        distance_m=v.distance_m,
                    )
                st.recovery = v
                st.touch()
            case _:
                pass
