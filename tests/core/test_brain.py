"""The sans-IO brain: events in, actions out, time only from the events.

A small scripted world feeds it SIPs at 10 Hz, RSSI samples at the configured rate,
rear-AP polls and finished scans, exactly as the shells would, and looks at the
actions: wheel commands (and what caused them), scan plans, the link servo target.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.airos.model import LinkQuality
from drivers.arcos.sip import Sip
from drivers.wifi.records import RssiSample
from relayd.config.model import Settings
from relayd.config.params import brain_params, nominal_scan_period_s
from relayd.core.brain import PANTILT, Brain
from relayd.core.events import (
    Action,
    Decision,
    DeviceEvent,
    DeviceStatus,
    LinkEvent,
    LinkSide,
    ModeCommand,
    RssiEvent,
    ScanDone,
    ScanPlan,
    ScanReady,
    ScanResult,
    ScanSampleEvent,
    ServoTarget,
    SipEvent,
    Tick,
    WheelCommand,
)
from relayd.core.link.model import LinkModel
from relayd.core.params import BrainParams
from relayd.core.vocab import Mode
from tests.support import ManualClock

SIP_S = 0.1


def sip(t: float, theta_deg: float = 0.0) -> SipEvent:
    s = Sip(
        t=t,
        x_mm=0.0,
        y_mm=0.0,
        theta_deg=theta_deg,
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
    return SipEvent(t, s, (None,) * 16)


def rear(t: float, dbm: float = -40.0) -> LinkEvent:
    q = LinkQuality(
        t=t, signal_dbm=dbm, rssi=None, noise_dbm=None, ccq_pct=None, tx_mbps=None, rx_mbps=None
    )
    return LinkEvent(t, LinkSide.REAR, q)


def config(**scan: object) -> Settings:
    return Settings.model_validate(
        {"scan": scan, "wifi": {"sample_hz": scan.pop("sample_hz", 20.0)}}
    )


@dataclass
class Script:
    brain: Brain
    t: float = 100.0
    log: list[tuple[float, Action]] = field(default_factory=list)

    def feed(self, event: object) -> list[Action]:
        actions = self.brain.handle(event)  # type: ignore[arg-type]
        self.log.extend((self.t, a) for a in actions)
        return actions

    def scan(
        self, leader_deg: float = 20.0, level_dbm: float = -50.0, angles: tuple[float, ...] = ()
    ) -> list[Action]:
        """A whole sweep's samples (a Yagi hearing a leader at leader_deg), then its end."""
        for a in angles or (-30.0, -10.0, 10.0, 30.0, 50.0):
            self.feed(ScanSampleEvent(self.t, a, level_dbm - abs(a - leader_deg) / 3.0))
        return self.feed(ScanDone(self.t, self.t - 1.0, 5))

    def run(
        self,
        seconds: float,
        *,
        rssi_hz: float | None,
        rssi_until: float | None = None,
        scan_s: float | None = None,
    ) -> None:
        """SIPs every 100 ms, rear polls every second, RSSI samples at rssi_hz (until
        rssi_until) and, while samples flow, a finished scan every scan_s."""
        end = self.t + seconds
        next_rssi = self.t
        next_rear = self.t
        next_scan = self.t + (scan_s or 0.0)
        while self.t < end - 1e-9:
            if rssi_hz is not None and (rssi_until is None or self.t < rssi_until):
                while next_rssi <= self.t + 1e-9:
                    self.feed(RssiEvent(next_rssi, RssiSample(next_rssi, -50.0, True)))
                    next_rssi += 1.0 / rssi_hz
                if scan_s is not None and next_scan <= self.t + 1e-9:
                    self.scan()
                    next_scan = self.t + scan_s
            if next_rear <= self.t + 1e-9:
                self.feed(rear(self.t))
                next_rear += 1.0
            self.feed(sip(self.t))
            self.t = round(self.t + SIP_S, 9)

    def wheels(self) -> list[tuple[float, WheelCommand]]:
        return [(t, a) for t, a in self.log if isinstance(a, WheelCommand)]


def driving_script(cfg: Settings) -> Script:
    s = Script(Brain(brain_params(cfg)))
    s.feed(DeviceEvent(s.t, PANTILT, DeviceStatus.UP))
    s.run(0.5, rssi_hz=cfg.wifi.sample_hz)
    s.scan()
    s.run(0.5, rssi_hz=cfg.wifi.sample_hz, scan_s=nominal_scan_period_s(cfg))
    last = s.brain.last_output
    assert last is not None and last.reason == "driving", last
    return s


# ---------------------------------------------------------------- stale RSSI ----------


@settings(max_examples=25, deadline=None)
@given(
    samples=st.integers(3, 361),
    settle_s=st.floats(0.0, 2.0),
    width_deg=st.floats(10.0, 360.0),
    sample_hz=st.sampled_from([2.0, 5.0, 10.0, 20.0, 50.0]),
    mode=st.sampled_from(["step", "continuous"]),
)
def test_wheels_stop_soon_after_the_rssi_source_freezes_whatever_the_scan(
    samples: int, settle_s: float, width_deg: float, sample_hz: float, mode: str
) -> None:
    """Stale after max(0.5 s, 5 sample periods) without a fresh sample, then one SIP period at most.

    For any source at 5 Hz or faster that is within 1 s of the freeze, whatever the scan.
    """
    cfg = config(
        samples=samples, settle_s=settle_s, width_deg=width_deg, mode=mode, sample_hz=sample_hz
    )
    s = driving_script(cfg)
    frozen_t = s.t
    s.run(4.0, rssi_hz=sample_hz, rssi_until=frozen_t, scan_s=nominal_scan_period_s(cfg))
    stops = [(t, w) for t, w in s.wheels() if w.stop and t >= frozen_t]
    assert stops, "the wheels never stopped"
    stop_t = stops[0][0]
    limit_s = max(0.5, 5.0 / sample_hz)
    assert stop_t - frozen_t <= limit_s + SIP_S + 1e-6
    if sample_hz >= 5.0:
        assert stop_t - frozen_t <= 1.0 + 1e-6
    out = s.brain.last_output
    assert out is not None and out.reason == "rssi_stale"


def test_slow_scan_settings_still_stop_within_one_second() -> None:
    """The defaults made 'stale' 2 nominal scan periods (7 s); slow settings made it minutes."""
    cfg = config(samples=361, settle_s=1.0, width_deg=360.0)
    assert brain_params(cfg).control.rssi_timeout_s <= 1.0
    s = driving_script(cfg)
    frozen_t = s.t
    s.run(2.0, rssi_hz=20.0, rssi_until=frozen_t)
    stop_t = next(t for t, w in s.wheels() if w.stop and t >= frozen_t)
    assert stop_t - frozen_t <= 1.0


def test_a_scan_that_stops_completing_stops_the_wheels_too() -> None:
    cfg = config(samples=5, width_deg=60.0, settle_s=0.0)
    params = brain_params(cfg)
    limit = params.scan.scan_timeout_s
    assert limit is not None
    s = driving_script(cfg)
    scan_t = max(a.record.t for _, a in s.log if isinstance(a, ScanResult))
    s.run(limit + 1.0, rssi_hz=20.0)  # samples keep flowing, no sweep ends
    out = s.brain.last_output
    assert (
        out is not None
        and out.reason == "scan_stale"
        and (out.left_mm_s, out.right_mm_s) == (0.0, 0.0)
    )
    stop_t = next(t for t, w in s.wheels() if w.stop and t > scan_t)
    assert limit < stop_t - scan_t <= limit + SIP_S + 1e-6
    s.scan()  # a sweep completes again: driving resumes by itself
    s.run(0.2, rssi_hz=20.0)
    assert s.brain.last_output is not None and s.brain.last_output.reason == "driving"


# ---------------------------------------------------------------- what caused a wheel command


def test_only_sip_caused_commands_carry_a_sip_time() -> None:
    s = driving_script(config())
    caused = [(t, w) for t, w in s.wheels() if w.sip_t is not None]
    assert caused and all(w.sip_t == t for t, w in caused)
    # A tick while driving: a command, but no SIP behind it.
    out = s.feed(Tick(s.t))
    cmds = [a for a in out if isinstance(a, WheelCommand)]
    assert cmds and all(c.sip_t is None for c in cmds)
    # The operator: a mode change stops the wheels, caused by no SIP.
    out = s.feed(ModeCommand(s.t, Mode.HOLD))
    stop = [a for a in out if isinstance(a, WheelCommand)]
    assert stop == [WheelCommand(0.0, 0.0, True, None)]


def test_the_shell_counts_driver_latency_only_for_sip_caused_commands() -> None:
    """The defect: the driver times "SIP bytes in -> next motion command written" and cannot
    tell what caused the command, so a timer's command was counted against the last SIP
    (means of 86-383 ms while driving straight). The shell knows the cause."""
    from relayd.runtime.control import ControlShell

    class Robot:
        """Writes each new wish at once and reports what the ARCOS driver would: the time
        since the last SIP's bytes arrived."""

        connected, stale = True, False
        on_command_latency: Callable[[float], None] | None = None

        class sonar:
            ranges_mm = (None,) * 16

        def __init__(self, clock: ManualClock) -> None:
            self.clock = clock
            self.last_sip_rx = 0.0

        def add_listener(self, cb: object) -> Callable[[], None]:
            return lambda: None

        def _written(self) -> None:
            if self.on_command_latency is not None:
                self.on_command_latency(self.clock.t - self.last_sip_rx)

        def stop(self) -> None:
            self._written()

        def set_wheels(self, left_mm_s: float, right_mm_s: float) -> None:
            self._written()

    clock = ManualClock(10.0)
    robot = Robot(clock)
    latencies: list[float] = []
    shell = ControlShell(
        bus=None,
        brain=Brain(brain_params(config())),
        robot=robot,  # type: ignore[arg-type]
        clock=clock,
        on_latency=latencies.append,
    )
    robot.last_sip_rx = clock.t = 10.0
    clock.t = 10.0004
    shell.execute(WheelCommand(100.0, 120.0, False, 10.0))  # the SIP decoded at 10.0 caused it
    assert latencies == [pytest.approx(0.0004)]
    clock.t = 10.08
    shell.execute(WheelCommand(100.0, 130.0, False, None))  # a tick's: 80 ms after that SIP
    shell.execute(WheelCommand(0.0, 0.0, True, None))  # the operator's stop
    assert latencies == [pytest.approx(0.0004)]
    # A SIP-caused command whose driver figure belongs to an older SIP (its own
    # command was never written) is dropped, not counted against this SIP.
    clock.t = 10.2
    shell.execute(WheelCommand(90.0, 90.0, False, 10.2 - 0.0003))
    assert latencies == [pytest.approx(0.0004)] and shell.latency_dropped == 1


# ---------------------------------------------------------------- scans and the bearing memory


@pytest.mark.parametrize("estimator", ["wca", "lobe"])
def test_a_finished_scan_points_the_link_antenna_and_plans_around_the_bearing(
    estimator: str,
) -> None:
    cfg = config(samples=7, width_deg=60.0, estimator=estimator, window="full")
    s = Script(Brain(brain_params(cfg)))
    # The scanner is ready before the servo answers: the plan waits for the servo.
    assert s.feed(ScanReady(s.t)) == []
    first = s.feed(DeviceEvent(s.t, PANTILT, DeviceStatus.UP))
    plan0 = next(a for a in first if isinstance(a, ScanPlan))
    assert plan0.angles_deg[0] == pytest.approx(-30.0) and plan0.angles_deg[-1] == pytest.approx(
        30.0
    )
    s.feed(sip(s.t, theta_deg=0.0))
    actions = s.scan(leader_deg=20.0)
    result = next(a for a in actions if isinstance(a, ScanResult))
    target = next(a for a in actions if isinstance(a, ServoTarget))
    assert 10.0 < result.estimate.bearing_deg < 30.0
    assert (
        target.channel == cfg.pantilt.link_channel
        and target.angle_deg == result.estimate.bearing_deg
    )
    # The robot turns 15 degrees left before the next sweep starts: its window follows
    # the leader into the new frame (planned when the scanner is ready, not at the scan's end).
    s.feed(sip(s.t, theta_deg=15.0))
    plan = next(a for a in s.feed(ScanReady(s.t)) if isinstance(a, ScanPlan))
    centre = (plan.angles_deg[0] + plan.angles_deg[-1]) / 2.0
    assert centre == pytest.approx(result.estimate.bearing_deg - 15.0)
    assert plan.angles_deg[0] > plan.angles_deg[-1]  # sweeps alternate direction
    s.feed(ScanSampleEvent(s.t, 0.0, -60.0))
    assert not any(
        isinstance(a, ScanResult) for a in s.feed(ScanDone(s.t, s.t, 1))
    )  # too few samples


def test_leader_lost_after_three_weak_scans_widens_the_window() -> None:
    cfg = config(samples=7, width_deg=60.0)
    s = Script(Brain(brain_params(cfg)))
    s.feed(DeviceEvent(s.t, PANTILT, DeviceStatus.UP))
    for _ in range(3):
        s.scan(level_dbm=-100.0)
    assert s.brain.leader_lost
    plan = next(a for a in s.feed(ScanReady(s.t)) if isinstance(a, ScanPlan))
    lo, hi = sorted((plan.angles_deg[0], plan.angles_deg[-1]))
    assert (lo, hi) == (pytest.approx(-90.0), pytest.approx(90.0))
    s.run(0.3, rssi_hz=20.0)
    assert s.brain.last_output is not None and s.brain.last_output.reason == "leader_lost"


def test_same_events_same_actions() -> None:
    def go() -> list[tuple[float, Action]]:
        s = driving_script(config(samples=5, width_deg=60.0))
        s.run(2.0, rssi_hz=20.0, rssi_until=s.t + 1.0)
        return s.log

    a, b = go(), go()
    assert a == b
    assert any(isinstance(x, Decision) and x.reason == "rssi_stale" for _, x in a)
    assert all(not isinstance(x, Decision) or math.isfinite(x.left_mm_s) for _, x in a)


def test_the_rooms_memories_are_read_only_and_set_up_through_their_seams() -> None:
    params = BrainParams()
    model = LinkModel(params.link)
    brain = Brain(params, link_model=model)
    assert brain.link_model is model  # given at the start, kept
    with pytest.raises(AttributeError):
        brain.rear.model = LinkModel(params.link)  # type: ignore[misc]
    with pytest.raises(AttributeError):
        brain.scans.prev_bearing_deg = 1.0  # type: ignore[misc]
    brain.scans.remember(15.0, 0.0, -60.0)
    brain.scans.remember(20.0, 5.0, -50.0)  # as a finished scan: the last becomes the one before
    scans = brain.scans
    assert (scans.prev_bearing_deg, scans.prev_heading_deg) == (15.0, 0.0)
    assert (scans.bearing_deg, scans.bearing_heading_deg, scans.rssi_leader_dbm) == (
        20.0,
        5.0,
        -50.0,
    )
    assert scans.count == 0 and scans.last_scan_t is None  # no scan was taken
