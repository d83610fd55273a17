"""The relay brain: one pure state machine from events to actions (sans-IO, like h11).

`Brain.handle(event) -> list[Action]` is the whole decision core of a relay: it keeps
what the robot knows (last SIP, sonar ring, RSSI freshness, RSSI^b, the mode and the
operator's command), runs the fail-safes and the pure controller
(`relayd.core.control.law.control_step`) on every SIP and every timer tick, and hands the
scans to its scan memory (`relayd.core.scan.memory`: each finished scan's estimate, the
bearing memory, leader-lost, the next sweep). It does no I/O and reads no clock: the
time is in each event, so the same events give the same actions, on a robot, in the
simulator and in a test.

What is left here is the routing and the memory of one state machine: every concern
with logic of its own lives in its own pure module (the scans, the controller, the
estimator, the tracking filter and its scan windows, recovery, the rear-link model, the
step back out of a shadow), each the only writer of its own memory.

Decisions:
- Stale RSSI is judged on the sample stream: no fresh sample for `rssi_timeout_s`
  (the daemon sets max(0.5 s, 5 sample periods)) stops the wheels with reason
  "rssi_stale", whatever the scan settings. A second rule covers a scan that stops
  completing while samples still flow (a servo that answers but never finishes a
  sweep): no completed scan for `scan_timeout_s` (2 nominal scan periods) once a
  bearing exists stops them with reason "scan_stale".
- A robot that reports itself down (session ended, silent) counts as having no SIP
  until the next SIP, so the wheels go to zero at the next step, not at the SIP
  timeout.
- Only the step a SIP caused carries that SIP's time on its wheel command
  (`WheelCommand.sip_t`): the control latency is measured on those alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from drivers.airos.model import Station
from relayd.core.avoid.ring import rear_readings
from relayd.core.control.law import (
    ControlInputs,
    ControlMemory,
    ControlOutput,
    ControlParams,
    control_step,
)
from relayd.core.control.rangecue import known_front, leader_floor_m
from relayd.core.events import (
    Action,
    Decision,
    DeviceEvent,
    DeviceStatus,
    DriveCommand,
    Event,
    LinkEvent,
    LinkModelView,
    LinkSide,
    ModeCommand,
    RearLink,
    RecoveryReport,
    RssiEvent,
    ScanDone,
    ScanReady,
    ScanSampleEvent,
    ServoPosition,
    Shutdown,
    SipEvent,
    Tick,
    WheelCommand,
)
from relayd.core.link.model import LinkModel, LinkPolicyParams, LinkSample
from relayd.core.link.retreat import RetreatMemory, held_limit, record_poll, retreat_step
from relayd.core.recovery.machine import (
    RecoveryInputs,
    RecoveryMemory,
    RecoveryOutput,
    RecoveryParams,
    RecoveryView,
    recovery_step,
    recovery_view,
)
from relayd.core.scan.estimator import EstimatorParams, front_readings
from relayd.core.scan.leader import LeaderParams
from relayd.core.scan.memory import ScanMemory
from relayd.core.scan.plan import ScanParams
from relayd.core.trail.keeper import TrailKeeper, TrailParams
from relayd.runtime.state import DriveState, Mode

SONAR_COUNT = 16
#: Device names the brain listens to in `DeviceEvent`s.
ROBOT, PANTILT = "robot", "pantilt"


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
    #: The leader's trail and the pursuit along it (relayd/core/trail, issue 26).
    trail: TrailParams = field(default_factory=TrailParams)


class Brain:
    """Events in, actions out. Not thread-safe, not async: call `handle` in event order."""

    def __init__(self, params: BrainParams, *, mode: Mode = Mode.FOLLOW) -> None:
        self.params = params
        self._mode = Mode(mode)
        self._manual: tuple[float, float, float] | None = None
        self._halted = False
        # What the base said.
        self._sip_t: float | None = None
        self._heading: float | None = None
        self._robot_down = False
        self._sonar: list[int | None] = [None] * SONAR_COUNT
        #: Odometry pose of the latest SIP (mm, mm, deg): the obstacle escape's progress
        #: watchdog and limits (relayd/core/avoid/escape.py) and the recovery's breadcrumbs.
        self._pose: tuple[float, float, float] | None = None
        #: ... and at the last rear poll the link model learned from (how far it moved between polls).
        self._rear_pose: tuple[float, float, float] | None = None
        # RSSI and scans.
        self._rssi_fresh_t: float | None = None
        self._servo_ok = not params.has_scanner
        #: The sweep in progress, the bearing memory of the scans, leader-lost (relayd/core/scan/memory.py).
        self.scans = ScanMemory(params.scan, params.estimator, params.leader)
        # The link behind.
        self._rear_dbm: float | None = None
        self._rear_t: float | None = None
        self._rear_shown: float | None = None
        # The rear-link model learns in both policies (fixed: advice shown on /status only).
        self.link_model = LinkModel(params.link)
        self._control = self._with_rear_limit()
        # The controller's memory and last word.
        self._memory = ControlMemory()
        self.last_output: ControlOutput | None = None
        # Breadcrumbs and the recovery episode (relayd.core.recovery.machine).
        self._rear_polls = 0
        self.recovery = RecoveryMemory()
        self.retreat = (
            RetreatMemory()
        )  # stepping back out of a shadow (relayd.core.link.retreat, adaptive only)
        self._recovery_shown: RecoveryView | None = None
        #: The leader's estimated position and trail (relayd/core/trail), fed by each scan.
        self.trail = TrailKeeper(params.trail)

    # -- read-only views (the API's shell checks a drive command against the mode) ------

    @property
    def mode(self) -> Mode:
        return self._mode

    @property
    def leader_lost(self) -> bool:
        return self.scans.leader_lost

    @property
    def servo_ok(self) -> bool:
        return self._servo_ok

    # -- the one entry point ------------------------------------------------------------

    def handle(self, event: Event) -> list[Action]:
        match event:
            case SipEvent():
                return self._on_sip(event)
            case Tick():
                return self._rear_view(event.t) + self._step(event.t, None)
            case RssiEvent():
                s = event.sample
                if s.fresh and s.rssi_dbm is not None and math.isfinite(s.rssi_dbm):
                    self._rssi_fresh_t = s.t
                return []
            case ScanReady():
                return self.scans.ready(
                    event.t, self._heading, self._mode is Mode.FOLLOW, self._servo_ok
                )
            case ScanSampleEvent():
                self.scans.sample(event, self._heading)
                return []
            case ScanDone():
                count = self.scans.count
                actions = self.scans.done(event, self._heading, self._sonar)
                if self.scans.count != count:
                    self._trail_scan(event.t)
                return actions
            case LinkEvent():
                return self._on_link(event)
            case DeviceEvent():
                return self._on_device(event)
            case ModeCommand():
                self._mode = Mode(event.mode)
                self._manual = None
                return self._step(event.t, None)
            case DriveCommand():
                if self._mode is not Mode.MANUAL or not (
                    math.isfinite(event.left_mm_s) and math.isfinite(event.right_mm_s)
                ):
                    return []  # the API's shell refuses these before they get here
                self._manual = (float(event.left_mm_s), float(event.right_mm_s), event.t)
                return self._step(event.t, None)
            case Shutdown():
                self._halted = True
                return self._step(event.t, None)
            case ServoPosition():
                return []
        return []

    # -- inputs ---------------------------------------------------------------------------

    def _on_sip(self, ev: SipEvent) -> list[Action]:
        self._sip_t = ev.t
        self._heading = ev.sip.theta_deg
        self._pose = (ev.sip.x_mm, ev.sip.y_mm, ev.sip.theta_deg)
        self.trail.own_pose(ev.t, self._pose)
        self._robot_down = False
        if len(ev.sonar_mm) == SONAR_COUNT:
            self._sonar = list(ev.sonar_mm)
        else:
            for index, range_mm in ev.sip.sonar:
                if 0 <= index < SONAR_COUNT:
                    self._sonar[index] = range_mm
        return self._step(ev.t, ev.t)

    def _on_device(self, ev: DeviceEvent) -> list[Action]:
        up = ev.status is DeviceStatus.UP
        if ev.device == ROBOT:
            self._robot_down = not up
            return self._step(ev.t, None)
        if ev.device == PANTILT:
            was_ok, self._servo_ok = self._servo_ok, up
            actions = self._step(ev.t, None)
            if up and not was_ok:  # the scanner may have been waiting for the servo
                actions.extend(self.scans.servo_up(ev.t, self._heading, self._mode is Mode.FOLLOW))
            return actions
        return []

    def _on_link(self, ev: LinkEvent) -> list[Action]:
        if ev.side is not LinkSide.REAR:
            return []
        q, mac = ev.quality, self.params.rear_station_mac
        peer: Station | None
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
        else:
            # A rear radio in station mode has no station list: its own signal is the link's.
            peer = q.best_station
            value = peer.signal_dbm if peer is not None else q.signal_dbm
        self._rear_dbm, self._rear_t = value, ev.t
        self._rear_polls += 1
        return self._rear_view(ev.t) + self._learn_rear(ev, value, peer)

    def _learn_rear(
        self, ev: LinkEvent, rssi_dbm: float | None, peer: Station | None
    ) -> list[Action]:
        """Feed the rear-link model one poll; in adaptive mode its limit becomes the controller's."""
        if rssi_dbm is None:
            return []
        q = ev.quality
        tx, rx, ccq = (
            (peer.tx_mbps, peer.rx_mbps, peer.ccq_pct)
            if peer is not None
            else (q.tx_mbps, q.rx_mbps, q.ccq_pct)
        )
        moved = None
        if self._pose is not None and self._rear_pose is not None:
            moved = (
                math.hypot(self._pose[0] - self._rear_pose[0], self._pose[1] - self._rear_pose[1])
                / 1000.0
            )
        sample = LinkSample(q.t if math.isfinite(q.t) else ev.t, rssi_dbm, tx, rx, ccq, moved)
        if not self.link_model.observe(sample, ev.t):
            return []
        self._rear_pose = self._pose
        delivered = self.link_model.last_delivered_mbps
        self.retreat = record_poll(
            self.retreat,
            self._pose,
            rssi_dbm,
            delivered is not None and delivered >= self.params.link.target_hop_mbps,
        )
        self._control = self._with_rear_limit()
        return [LinkModelView(self._in_force().threshold_b_dbm, self.link_model.status(ev.t))]

    def _with_rear_limit(self) -> ControlParams:
        if not self.params.link.adaptive:
            return self.params.control
        return replace(self.params.control, threshold_b_dbm=self.link_model.threshold_dbm)

    def _in_force(self) -> ControlParams:
        """The controller's params: the rear limit, raised while holding after a retreat (relayd.core.link.retreat)."""
        return held_limit(self._control, self.retreat, self.params.link.bounds_dbm[1])

    def _rear_view(self, now: float) -> list[Action]:
        """RSSI^b as /status may show it: not a value the controller already refuses as stale."""
        value = self._rear_dbm
        if self._rear_t is None or now - self._rear_t > self.params.control.rear_timeout_s:
            value = None
        if value == self._rear_shown:
            return []
        self._rear_shown = value
        return [RearLink(value)]

    def _trail_scan(self, now: float) -> None:
        """A finished scan into the leader estimate and its trail (issue 26)."""
        bearing = self.scans.bearing_now(now, self._heading)
        sd = self.scans.model.sd_deg(now, self._heading)
        floor = (
            leader_floor_m(known_front(self._sonar), bearing, sd) if bearing is not None else None
        )
        self.trail.scan(now, self._pose, bearing, sd, self.scans.rssi_leader_dbm, floor)

    # -- the control step -----------------------------------------------------------------

    def inputs(self, now: float) -> ControlInputs:
        p = self.params.control
        sip_age = None if self._sip_t is None else now - self._sip_t
        if self._robot_down and sip_age is not None:
            sip_age = max(sip_age, p.sip_timeout_s + 1e-6)
        heading = self._heading
        manual_l = manual_r = manual_age = None
        if self._manual is not None:
            manual_l, manual_r, t = self._manual
            manual_age = now - t
        bearing = self.scans.bearing_now(now, heading)
        floor = (
            leader_floor_m(known_front(self._sonar), bearing, self.scans.model.sd_deg(now, heading))
            if p.leader_gap_max_m > 0
            else None
        )
        pursuit = (
            self.trail.steer(now, self._pose, front_readings(self._sonar))
            if self.params.trail.pursuit == "trail"
            else None
        )
        return ControlInputs(
            mode=self._mode,
            sip_age_s=sip_age,
            rssi_age_s=None if self._rssi_fresh_t is None else now - self._rssi_fresh_t,
            scan_servo_ok=self._servo_ok,
            bearing_deg=bearing,
            prev_bearing_deg=self.scans.prev_bearing_now(heading),
            rssi_leader_dbm=self.scans.rssi_leader_dbm,
            rssi_behind_dbm=self._rear_dbm,
            rear_age_s=None if self._rear_t is None else now - self._rear_t,
            front_sonar=front_readings(self._sonar),
            leader_lost=self.scans.lost(now, heading, self._mode is Mode.FOLLOW),
            manual_left_mm_s=manual_l,
            manual_right_mm_s=manual_r,
            manual_age_s=manual_age,
            t_s=now,
            odom=self._pose,
            rear_sonar=rear_readings(self._sonar),
            leader_floor_m=floor,
            search_bearing_deg=self.scans.model.search_bearing(now, heading),
            trail_steer_deg=None if pursuit is None else pursuit.steer_deg,
            trail_caught_up=pursuit is not None and pursuit.caught_up,
            trail_remaining_m=None if pursuit is None else self.trail.remaining_m(self._pose),
        )

    def _decide(self, now: float) -> ControlOutput:
        situation = self.last_output.situation if self.last_output is not None else 0
        if self._halted:
            return ControlOutput(0.0, 0.0, DriveState.STOPPED, "shutdown", situation, self._memory)
        try:
            ci = self.inputs(now)
            out = control_step(ci, self._in_force(), self._memory)
            out, self.retreat = retreat_step(
                ci,
                tuple(self._sonar),
                out,
                self._control,
                self.retreat,
                enabled=self.params.link.adaptive,
            )
        except Exception as exc:  # noqa: BLE001 - a bug or bad data in the brain stops the robot
            return ControlOutput(
                0.0,
                0.0,
                DriveState.FAULT,
                f"controller_error: {type(exc).__name__}",
                situation,
                self._memory,
            )
        out = self._recover(now, out)
        if (out.left_mm_s or out.right_mm_s) and self.scans.stale(now, self._mode is Mode.FOLLOW):
            return ControlOutput(
                0.0, 0.0, DriveState.FAULT, "scan_stale", out.situation, out.memory
            )
        return out

    def _recover(self, now: float, out: ControlOutput) -> ControlOutput:
        """The recovery seam: an episode's command replaces the follow controller's (never a fault)."""
        rp = self.params.recovery
        if not rp.enabled:
            return out
        try:
            res = self._recovery_step(now, rp, (out.left_mm_s + out.right_mm_s) / 2.0)
        except Exception as exc:  # noqa: BLE001 - a bug or bad data in recovery stops the robot
            return ControlOutput(
                0.0,
                0.0,
                DriveState.FAULT,
                f"recovery_error: {type(exc).__name__}",
                out.situation,
                out.memory,
            )
        self.recovery = res.memory
        cmd = res.command
        if cmd is None or out.state is DriveState.FAULT:
            return out
        return ControlOutput(
            cmd.left_mm_s, cmd.right_mm_s, cmd.state, cmd.reason, out.situation, out.memory
        )

    def _recovery_step(self, now: float, rp: RecoveryParams, forward_mm_s: float) -> RecoveryOutput:
        return recovery_step(
            RecoveryInputs(
                following=self._mode is Mode.FOLLOW and not self._halted,
                pose=self._pose,
                sip_age_s=None if self._sip_t is None or self._robot_down else now - self._sip_t,
                rssi_age_s=None if self._rssi_fresh_t is None else now - self._rssi_fresh_t,
                scan_age_s=None if self.scans.last_scan_t is None else now - self.scans.last_scan_t,
                rear_age_s=None if self._rear_t is None else now - self._rear_t,
                leader_lost=self.leader_lost,
                rssi_leader_dbm=self.scans.rssi_leader_dbm,
                rssi_behind_dbm=self._rear_dbm,
                scan_count=self.scans.count,
                sonar_mm=tuple(self._sonar),
                now_s=now,
                rear_polls=self._rear_polls,
                forward_mm_s=forward_mm_s,
            ),
            rp,
            self.recovery,
        )

    def _recovery_report(self, now: float) -> list[Action]:
        if not self.params.recovery.enabled:
            return []
        view = recovery_view(self.recovery, self.params.recovery, now)
        if view == self._recovery_shown:
            return []
        self._recovery_shown = view
        return [RecoveryReport(view)]

    def _step(self, now: float, sip_t: float | None) -> list[Action]:
        out = self._decide(now)
        self._memory = out.memory
        prev, self.last_output = self.last_output, out
        actions: list[Action] = []
        if not self._halted:
            if out.left_mm_s == 0.0 and out.right_mm_s == 0.0:
                # The urgent stop goes out on the transition to zero; while stopped, the
                # driver keeps reflecting zero, so the serial line is not flooded.
                if prev is None or prev.left_mm_s != 0.0 or prev.right_mm_s != 0.0:
                    actions.append(WheelCommand(0.0, 0.0, True, sip_t))
            else:
                actions.append(WheelCommand(out.left_mm_s, out.right_mm_s, False, sip_t))
        changed = prev is None or prev.state is not out.state or prev.reason != out.reason
        actions.append(
            Decision(
                now,
                out.left_mm_s,
                out.right_mm_s,
                out.state,
                out.reason,
                out.situation,
                self._mode,
                changed,
            )
        )
        actions.extend(self._recovery_report(now))
        return actions
