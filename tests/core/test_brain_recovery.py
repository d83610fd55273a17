"""Recovery through the brain: the seam, the full-range widen, stale inputs, enabled = false."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from drivers.airos.model import LinkQuality
from drivers.arcos.sip import Sip
from drivers.wifi.records import RssiSample
from relayd.config.model import Settings
from relayd.config.params import brain_params
from relayd.core.brain import PANTILT, Brain
from relayd.core.events import (
    Action,
    Decision,
    DeviceEvent,
    DeviceStatus,
    LinkEvent,
    LinkSide,
    RecoveryReport,
    RssiEvent,
    ScanDone,
    ScanPlan,
    ScanReady,
    ScanSampleEvent,
    SipEvent,
)
from relayd.core.recovery.state import Phase
from relayd.core.vocab import DriveState


@dataclass
class Relay:
    """A brain and a scripted robot on a line: x grows while the wheels drive forward."""

    brain: Brain
    t: float = 0.0
    x_mm: float = 0.0
    rssi_fresh: bool = True
    rear_dbm: float = -50.0
    theta_deg: float = 0.0
    log: list[Action] = field(default_factory=list)

    def feed(self, ev: object) -> list[Action]:
        out = self.brain.handle(ev)  # type: ignore[arg-type]
        self.log.extend(out)
        return out

    def step(self, seconds: float) -> None:
        end = self.t + seconds
        while self.t < end - 1e-9:
            out = self.brain.last_output
            if out is not None:
                self.x_mm += (out.left_mm_s + out.right_mm_s) / 2.0 * 0.1
            s = Sip(
                t=self.t,
                x_mm=self.x_mm,
                y_mm=0.0,
                theta_deg=self.theta_deg,
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
            if self.rssi_fresh:
                self.feed(RssiEvent(self.t, RssiSample(self.t, -50.0, True)))
            if round(self.t * 10) % 10 == 0:
                q = LinkQuality(
                    t=self.t,
                    signal_dbm=self.rear_dbm,
                    rssi=None,
                    noise_dbm=None,
                    ccq_pct=None,
                    tx_mbps=None,
                    rx_mbps=None,
                )
                self.feed(LinkEvent(self.t, LinkSide.REAR, q))
            self.feed(SipEvent(self.t, s, (5000,) * 16))
            self.t = round(self.t + 0.1, 9)

    def scan(self, level_dbm: float) -> list[Action]:
        for a in (-60.0, -30.0, 0.0, 30.0, 60.0):
            self.feed(ScanSampleEvent(self.t, a, level_dbm - abs(a) / 10.0))
        return self.feed(ScanDone(self.t, self.t - 1.0, 5))

    @property
    def wheels(self) -> tuple[float, float]:
        out = self.brain.last_output
        assert out is not None
        return out.left_mm_s, out.right_mm_s


def relay(enabled: bool, **control: float) -> Relay:
    cfg = Settings.model_validate(
        {
            "recovery": {"enabled": enabled},
            "scan": {"samples": 5, "width_deg": 120},
            "control": control,
        }
    )
    r = Relay(Brain(brain_params(cfg)))
    r.feed(DeviceEvent(0.0, PANTILT, DeviceStatus.UP))
    # Follow for 6 s: the leader fading from -40 dBm (laying crumbs), the robot driving.
    for k in range(6):
        r.scan(-40.0 - 3 * k)
        r.step(1.0)
    assert r.brain.last_output is not None and r.brain.last_output.state is DriveState.DRIVING
    assert r.x_mm > 500.0
    return r


def lose_leader(r: Relay) -> None:
    for _ in range(3):
        r.scan(-100.0)
        r.step(0.5)
    assert r.brain.leader_lost


def test_enabled_false_stands_still_when_the_leader_is_lost_as_before() -> None:
    r = relay(False)
    lose_leader(r)
    r.step(5.0)
    assert r.wheels == (0.0, 0.0)
    assert r.brain.last_output is not None and r.brain.last_output.reason == "leader_lost"
    assert not any(isinstance(a, RecoveryReport) for a in r.log)


def test_leader_lost_widens_then_retraces_then_resumes_following() -> None:
    r = relay(True)
    lose_leader(r)
    x_lost = r.x_mm
    # Widen first: the next plan spans the servo's range; wheels stay at zero until that scan ends.
    plan = next(a for a in r.feed(ScanReady(r.t)) if isinstance(a, ScanPlan))
    assert (min(plan.angles_deg), max(plan.angles_deg)) == (
        pytest.approx(-90.0),
        pytest.approx(90.0),
    )
    r.step(1.0)
    assert r.wheels == (0.0, 0.0) and r.brain.recovery.phase is Phase.WIDEN
    r.scan(-100.0)
    r.step(2.0)
    assert r.brain.recovery.phase is Phase.RETRACE
    assert r.wheels[0] < 0 and r.wheels[1] < 0
    assert r.x_mm < x_lost
    # The RSSI stream stops: wheels at zero within the stale limit, the controller's reason shown.
    r.rssi_fresh = False
    r.step(1.0)
    assert r.wheels == (0.0, 0.0)
    assert r.brain.last_output is not None and r.brain.last_output.reason == "rssi_stale"
    r.rssi_fresh = True
    r.scan(-100.0)  # sweeps complete again too (no scan for 2 periods is stale as well)
    r.step(0.5)
    assert r.wheels[0] < 0, r.brain.last_output
    # Heard again: follow at once.
    r.scan(-50.0)
    r.step(0.3)
    assert r.brain.recovery.phase is Phase.IDLE and r.brain.recovery.last_outcome == "found"
    assert r.wheels[0] > 0 and r.wheels[1] > 0
    phases = [str(a.view.phase) for a in r.log if isinstance(a, RecoveryReport)]
    assert "widen" in phases and "retrace" in phases and phases[-1] == "idle"
    states = {a.state for a in r.log if isinstance(a, Decision)}
    assert DriveState.RECOVERING in states


def test_v_max_bounds_every_wheel_of_a_retrace_that_turns() -> None:
    """Recovery adds its turn to a speed already at v_max: at a first drive's v_max of 120
    a wheel once got 180 mm/s. v_max bounds every stage's command (docs/DEPLOY.md 7)."""
    r = relay(True, v_max_mm_s=120.0)
    lose_leader(r)
    r.feed(ScanReady(r.t))
    r.step(1.0)
    r.scan(-100.0)
    r.theta_deg = 20.0  # the crumbs behind are now 20 deg off the rear axis: it must turn
    r.step(2.0)
    assert r.brain.recovery.phase is Phase.RETRACE
    left, right = r.wheels
    # Bounded as every command is (relayd/core/control/actuator.py `within`): the turn is
    # kept, the translation shrunk first.
    assert left != right and min(left, right) < 0, (left, right)
    wheels = [w for a in r.log if isinstance(a, Decision) for w in (a.left_mm_s, a.right_mm_s)]
    assert max(abs(w) for w in wheels) <= 120.0 + 1e-6


def test_rear_link_lost_backs_up_and_stops_when_restored() -> None:
    r = relay(True)
    x0 = r.x_mm
    r.rear_dbm = -90.0
    for _ in range(3):
        r.scan(-40.0)  # the leader still far: the controller alone would drive on
        r.step(1.0)
    assert r.brain.recovery.phase is Phase.BACKUP
    assert r.wheels[0] < 0 and r.x_mm < x0, r.brain.last_output
    r.rear_dbm = -55.0
    r.scan(-40.0)
    r.step(1.1)
    assert r.brain.recovery.last_outcome == "restored"
    assert r.wheels[0] >= 0


def test_a_recovery_bug_stops_the_wheels_and_says_so(monkeypatch: pytest.MonkeyPatch) -> None:
    r = relay(True)

    def broken(*_: object) -> None:
        raise ZeroDivisionError

    monkeypatch.setattr("relayd.core.brain.recovery_step", broken)
    r.step(0.2)
    assert r.wheels == (0.0, 0.0)
    out = r.brain.last_output
    assert (
        out is not None
        and out.state is DriveState.FAULT
        and out.reason == "recovery_error: ZeroDivisionError"
    )


def test_recovery_config_is_strict_and_reaches_the_brain() -> None:
    from relayd.config.load import parse_settings
    from relayd.config.model import ConfigError

    rear = {"rear": {"url": "http://10.0.0.2", "password_env": "X"}}
    for bad in (
        {"enabled": "off"},
        {"max_time_s": float("inf")},
        {"widen_scans": 1.5},
        {"speed": 1},
    ):
        with pytest.raises(ConfigError) as e:
            parse_settings({"ap": rear, "recovery": bad})
        assert all(m.startswith("recovery.") for m in e.value.errors), e.value.errors
    cfg = parse_settings(
        {
            "ap": rear,
            "recovery": {"enabled": True, "max_distance_m": 5},
            "control": {"v_max_mm_s": 120, "lost_rssi_dbm": -80},
        }
    )
    p = brain_params(cfg).recovery
    assert p.enabled and p.max_distance_m == 5.0 and p.lost_rssi_dbm == -80.0
    assert p.retrace_speed_mm_s == p.backup_speed_mm_s == 120.0  # never above v_max
    assert p.control.rear_link_required and p.control.rear_timeout_s == 3.0
    assert not brain_params(parse_settings({"ap": rear})).recovery.enabled


def test_relayd_status_prints_the_recovery_line() -> None:
    from relayd.cli.status import format_recovery

    running = {
        "enabled": True,
        "phase": "backup",
        "kind": "rear",
        "episodes": 2,
        "elapsed_s": 7.0,
        "distance_m": 0.8,
        "max_distance_m": 8.0,
        "max_time_s": 60.0,
        "trail_crumbs": 31,
        "last_outcome": "found",
    }
    assert (
        format_recovery(running)
        == "backup (link behind), 7 s of 60 s, 0.8 m of 8.0 m; 2 episode(s), trail 31 crumbs"
    )
    idle = {**running, "phase": "idle", "kind": None, "elapsed_s": None, "distance_m": None}
    assert format_recovery(idle) == "idle, last found; 2 episode(s), trail 31 crumbs"
