"""Stepping back out of a shadow through the brain (relayd/core/link/retreat.py at its seam): an
adaptive relay that drives past a shadow edge steps back to where its hop met the target
and holds there; a fixed one stands where it stopped; stale input stops a move."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from drivers.airos.model import LinkQuality, Station
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
    LinkModelView,
    LinkSide,
    RssiEvent,
    ScanDone,
    ScanSampleEvent,
    SipEvent,
)
from relayd.core.link.retreat import BELOW_POLLS, HOLD_MARGIN_DB

EDGE_MM = 3000.0
CLEAR = (-60.0, 54.0)  # RSSI^b, PHY rate: 27 Mbit/s delivered, the target met
SHADOW = (-79.0, 6.0)  # 3 Mbit/s delivered: below the 10 Mbit/s target


@dataclass
class Relay:
    """A brain and a scripted robot on a line; the hop behind falls into a shadow past EDGE_MM."""

    brain: Brain
    t: float = 0.0
    x_mm: float = 0.0
    fresh: bool = True
    shadow: tuple[float, float] = SHADOW
    log: list[Action] = field(default_factory=list)
    xs: list[float] = field(default_factory=list)
    #: (time, x, RSSI^b) of every rear poll in the shadow, and (time, reason) of every decision.
    shadow_polls: list[tuple[float, float, float]] = field(default_factory=list)

    def feed(self, ev: object) -> None:
        self.log.extend(self.brain.handle(ev))  # type: ignore[arg-type]

    def step(self, seconds: float) -> None:
        end = self.t + seconds
        while self.t < end - 1e-9:
            out = self.brain.last_output
            if out is not None:
                self.x_mm += (out.left_mm_s + out.right_mm_s) / 2.0 * 0.1
            self.xs.append(self.x_mm)
            if self.fresh:
                self.feed(RssiEvent(self.t, RssiSample(self.t, -50.0, True)))
            if round(self.t * 10) % 10 == 0:
                dbm, rate = self.shadow if self.x_mm > EDGE_MM else CLEAR
                if self.x_mm > EDGE_MM:
                    self.shadow_polls.append((self.t, self.x_mm, dbm))
                sta = Station(
                    mac="00:11:22:33:44:55",
                    signal_dbm=dbm,
                    ccq_pct=100.0,
                    tx_mbps=rate,
                    rx_mbps=rate,
                )
                q = LinkQuality(
                    t=self.t,
                    signal_dbm=None,
                    rssi=None,
                    noise_dbm=-95.0,
                    ccq_pct=None,
                    tx_mbps=None,
                    rx_mbps=None,
                    stations=(sta,),
                    mode="ap",
                )
                self.feed(LinkEvent(self.t, LinkSide.REAR, q))
            s = Sip(
                t=self.t,
                x_mm=self.x_mm,
                y_mm=0.0,
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
            self.feed(SipEvent(self.t, s, (5000,) * 16))
            self.t = round(self.t + 0.1, 9)

    def scan(self) -> None:
        for a in (-60.0, -30.0, 0.0, 30.0, 60.0):
            self.feed(ScanSampleEvent(self.t, a, -45.0 - abs(a) / 10.0))
        self.feed(ScanDone(self.t, self.t - 1.0, 5))

    def run(self, seconds: float) -> None:
        for _ in range(int(seconds)):
            self.scan()
            self.step(1.0)


def relay(policy: str, shadow: tuple[float, float] = SHADOW) -> Relay:
    cfg = Settings.model_validate(
        {
            "scan": {"samples": 5, "width_deg": 120},
            "control": {
                "link_policy": policy,
                "threshold_b_dbm": -70.0,
                "threshold_b_min_dbm": -80.0,
                "threshold_b_max_dbm": -50.0,
                "threshold_l_dbm": -30.0,
            },
        }
    )
    r = Relay(Brain(brain_params(cfg)), shadow=shadow)
    r.feed(DeviceEvent(0.0, PANTILT, DeviceStatus.UP))
    return r


def test_adaptive_relay_steps_back_out_of_the_shadow_and_holds() -> None:
    r = relay("adaptive")
    r.run(40)
    out = r.brain.last_output
    assert out is not None
    deepest = max(r.xs)
    assert deepest > EDGE_MM  # it did drive into the shadow (the poll there came too late)
    assert r.x_mm <= EDGE_MM  # ... and stands where the hop met the target
    assert EDGE_MM - r.x_mm < 600.0  # a step back, not a retreat home
    assert deepest - r.x_mm <= 3000.0 + 50.0
    assert r.brain.retreat.retreats >= 1 and r.brain.retreat.floor_dbm == CLEAR[0] + HOLD_MARGIN_DB
    assert out.left_mm_s == out.right_mm_s == 0.0
    views = [a for a in r.log if isinstance(a, LinkModelView)]
    assert views[-1].threshold_b_dbm == pytest.approx(
        CLEAR[0] + HOLD_MARGIN_DB
    )  # /status shows the hold
    reasons = {a.reason for a in r.log if hasattr(a, "reason")}
    assert "retreat" in reasons


def first_retreat_t(r: Relay) -> float:
    return next(a.t for a in r.log if isinstance(a, Decision) and a.reason == "retreat")


def test_a_sudden_drop_steps_back_on_the_first_poll_past_the_edge() -> None:
    """19 dB within one poll: a shadow edge; the move starts on the step after that poll."""
    r = relay("adaptive")
    r.run(40)
    first_poll_t = r.shadow_polls[0][0]
    assert first_retreat_t(r) - first_poll_t <= 0.2


def test_a_gradual_drop_waits_for_polls_below_standing() -> None:
    """4 dB below the polls before (within fading) and under the target: the relay stands for
    its polls below before it steps back, as without the edge rule."""
    r = relay("adaptive", shadow=(-64.0, 18.0))  # 8.55 Mbit/s delivered at CCQ 95 %, 9 at 100 %
    r.run(40)
    assert r.brain.retreat.retreats >= 1
    assert first_retreat_t(r) - r.shadow_polls[0][0] >= BELOW_POLLS - 1e-6


def test_fixed_relay_never_backs_up() -> None:
    r = relay("fixed")
    r.run(40)
    assert max(r.xs) > EDGE_MM
    assert all(b >= a - 1e-6 for a, b in zip(r.xs, r.xs[1:], strict=False))  # x never falls
    assert r.brain.retreat.retreats == 0


def test_a_stale_rssi_stream_stops_a_move_at_once() -> None:
    r = relay("adaptive")
    for _ in range(60):
        r.scan()
        r.step(0.5)
        if r.brain.retreat.target is not None:
            break
    assert r.brain.retreat.target is not None, "no move started"
    r.fresh = False
    r.step(1.0)
    out = r.brain.last_output
    assert out is not None and out.left_mm_s == out.right_mm_s == 0.0
    assert r.brain.retreat.target is None
