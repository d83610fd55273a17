"""Metrics: per-instance registries, scrape-time state collector, event observations."""

from __future__ import annotations

import math
import re
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st
from prometheus_client import generate_latest
from prometheus_client.parser import text_string_to_metric_families

from drivers.transport.health import DeviceHealth, LinkState
from relayd.core.vocab import DriveState, Mode, Reason
from relayd.runtime.metrics import Metrics
from relayd.runtime.state import LinkInfo, RelayState
from tests.support import ManualClock


def _samples(metrics: Metrics) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    text = generate_latest(metrics.registry).decode()
    out = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return out


def test_two_instances_do_not_collide() -> None:
    clock = ManualClock(10.0)
    a, b = Metrics(RelayState(), clock), Metrics(RelayState(), clock)
    a.sip_received()
    a.sip_received()
    b.sip_received()
    assert _samples(a)[("relayd_sips_received_total", ())] == 2.0
    assert _samples(b)[("relayd_sips_received_total", ())] == 1.0


def test_levels_are_read_at_scrape_time() -> None:
    clock = ManualClock(100.0)
    state = RelayState(started_t=40.0)
    m = Metrics(state, clock)
    before = _samples(m)
    assert ("relayd_rssi_dbm", (("peer", "leader"),)) not in before
    assert before[("relayd_uptime_seconds", ())] == 60.0

    state.rssi_leader_dbm = -47.5
    state.rssi_behind_dbm = -58.0
    state.bearing_deg = -12.0
    state.link_bearing_deg = -10.0
    state.wheels_left_mm_s, state.wheels_right_mm_s = 250.0, -100.0
    state.mode = Mode.MANUAL
    state.state = DriveState.AVOIDING
    state.thresholds = {"threshold_l_dbm": -30.0, "threshold_b_dbm": -60.0}
    state.sonar_mm[3] = 1234
    state.links["front"] = LinkInfo(signal_dbm=-50, ccq_pct=80, tx_mbps=54, rx_mbps=None, t=99.0)
    state.health["base"] = DeviceHealth("base", LinkState.UP, errors=3, last_rx_t=99.5)
    state.loop_tick_t = 99.9
    after = _samples(m)
    assert after[("relayd_rssi_dbm", (("peer", "leader"),))] == -47.5
    assert after[("relayd_rssi_dbm", (("peer", "behind"),))] == -58.0
    assert after[("relayd_rssi_threshold_dbm", (("peer", "behind"),))] == -60.0
    assert after[("relayd_bearing_degrees", (("antenna", "scan"),))] == -12.0
    assert after[("relayd_bearing_degrees", (("antenna", "link"),))] == -10.0
    assert after[("relayd_wheel_speed_meters_per_second", (("wheel", "left"),))] == 0.25
    assert after[("relayd_wheel_speed_meters_per_second", (("wheel", "right"),))] == -0.1
    assert after[("relayd_mode", (("relayd_mode", "manual"),))] == 1.0
    assert after[("relayd_mode", (("relayd_mode", "follow"),))] == 0.0
    assert after[("relayd_drive_state", (("relayd_drive_state", "avoiding"),))] == 1.0
    assert after[("relayd_sonar_range_meters", (("sonar", "3"),))] == 1.234
    assert after[("relayd_link_signal_dbm", (("link", "front"),))] == -50.0
    assert after[("relayd_link_ccq_ratio", (("link", "front"),))] == 0.8
    assert (
        after[("relayd_link_rate_bits_per_second", (("direction", "tx"), ("link", "front")))]
        == 54e6
    )
    assert (
        "relayd_link_rate_bits_per_second",
        (("direction", "rx"), ("link", "front")),
    ) not in after
    assert after[("relayd_device_connected", (("device", "base"),))] == 1.0
    assert after[("relayd_device_errors_total", (("device", "base"),))] == 3.0
    assert after[("relayd_device_data_age_seconds", (("device", "base"),))] == 0.5
    assert math.isclose(after[("relayd_control_loop_last_tick_age_seconds", ())], 0.1)


def test_observations_and_reconnects() -> None:
    state = RelayState()
    m = Metrics(state, ManualClock(0.0))
    m.observe_control_latency(0.0004)
    m.observe_control_latency(0.003)
    m.observe_control_latency(math.nan)  # ignored: a broken timer must not poison the histogram
    m.observe_control_latency(-1.0)
    m.observe_scan_period(1.7)
    # Reconnects are the driver's own count, read through its health source.
    state.health_sources["servo"] = lambda: DeviceHealth("servo", LinkState.UP, reconnects=2)
    s = _samples(m)
    assert s[("relayd_control_latency_seconds_count", ())] == 2.0
    assert s[("relayd_control_latency_seconds_bucket", (("le", "0.0005"),))] == 1.0
    assert s[("relayd_control_latency_seconds_bucket", (("le", "0.005"),))] == 2.0
    assert s[("relayd_scan_period_seconds_count", ())] == 1.0
    assert s[("relayd_device_reconnects_total", (("device", "servo"),))] == 2.0
    assert state.snapshot(0.0)["health"]["servo"]["reconnects"] == 2  # /status shows the same count


_maybe_float = st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=True))


@settings(max_examples=60, deadline=None)
@given(
    rssi_l=_maybe_float,
    rssi_b=_maybe_float,
    bearing=_maybe_float,
    battery=_maybe_float,
    signal=_maybe_float,
    ccq=_maybe_float,
    sonar=st.lists(st.one_of(st.none(), st.integers(0, 10_000)), min_size=16, max_size=16),
)
def test_any_state_scrapes_to_valid_exposition(
    rssi_l: float | None,
    rssi_b: float | None,
    bearing: float | None,
    battery: float | None,
    signal: float | None,
    ccq: float | None,
    sonar: list[int | None],
) -> None:
    state = RelayState()
    state.rssi_leader_dbm, state.rssi_behind_dbm = rssi_l, rssi_b
    state.bearing_deg, state.battery_v = bearing, battery
    state.sonar_mm = sonar
    state.links["rear"] = LinkInfo(signal_dbm=signal, ccq_pct=ccq)
    m = Metrics(state, ManualClock(5.0))
    text = generate_latest(m.registry).decode()
    families = list(text_string_to_metric_families(text))
    assert any(f.name == "relayd_build_info" for f in families)
    for fam in families:
        for sample in fam.samples:
            if fam.name in (
                "relayd_rssi_dbm",
                "relayd_bearing_degrees",
                "relayd_battery_volts",
                "relayd_link_signal_dbm",
                "relayd_link_ccq_ratio",
            ):
                # Unknown or non-finite levels are absent, never exported as NaN.
                assert math.isfinite(sample.value)


def test_drive_info_carries_state_and_reason() -> None:
    """Alerts and the dashboard read the reason from relayd_drive_info; it follows /status."""
    state = RelayState()
    m = Metrics(state, ManualClock(0.0))
    s = _samples(m)
    assert s[("relayd_drive_info", (("reason", "starting"), ("state", "stopped")))] == 1.0
    state.state, state.reason = DriveState.FAULT, "controller_error: ValueError"
    s = _samples(m)
    info = {labels: v for (name, labels), v in s.items() if name == "relayd_drive_info"}
    # One series only: the old reason is gone, so a query never sees two reasons at once.
    assert info == {(("reason", "controller_error: ValueError"), ("state", "fault")): 1.0}
    assert s[("relayd_drive_state", (("relayd_drive_state", "fault"),))] == 1.0


def test_every_reason_reaches_status_and_the_metric_as_its_code() -> None:
    """The metric and /status carry a Reason as its code, and the shipped Prometheus
    files name only codes that are Reasons (a renamed code would silently match nothing)."""
    state = RelayState()
    m = Metrics(state, ManualClock(0.0))
    for reason in Reason:
        state.reason = reason
        labels = [dict(lb) for (name, lb), _ in _samples(m).items() if name == "relayd_drive_info"]
        assert [Reason(lb["reason"]) for lb in labels] == [reason]
        assert Reason(state.snapshot(0.0)["reason"]) is reason
    deploy = Path(__file__).resolve().parents[2] / "deploy" / "prometheus"
    named = {
        code
        for f in deploy.glob("*.yml")
        for code in re.findall(r'reason="([^"]+)"', f.read_text())
    }
    assert named, "the alert tests name no reason: the pattern is out of date"
    assert named <= {r.value for r in Reason}
