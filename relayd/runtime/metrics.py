"""Prometheus metrics of one relayd instance.

Each `Metrics` owns its own `CollectorRegistry` (no import-time globals), so tests and
the simulator can build many daemons in one process. Event-driven figures (control
latency, scan period, SIP count) are recorded by the tasks through the `observe_*`
methods; everything that is a *level* (bearing, RSSI, wheels, device health) is read
from `RelayState` at scrape time by a custom collector, so it can never drift from what
/status reports.

Units follow the Prometheus naming guide (seconds, metres, ratios) except where the
field's natural unit has no base unit: dBm for radio power and degrees for angles.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from typing import TypeGuard

from prometheus_client import CollectorRegistry, Counter, Histogram
from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    InfoMetricFamily,
    Metric,
    StateSetMetricFamily,
)
from prometheus_client.registry import Collector

from drivers.transport.clock import Clock
from relayd import __version__
from relayd.core.vocab import DriveState, Mode
from relayd.runtime.state import RelayState

#: SIP received -> wheel command written: sub-millisecond on a healthy loop, 2 ms is the target p99.
CONTROL_LATENCY_BUCKETS_S = (
    0.0001,
    0.00025,
    0.0005,
    0.00075,
    0.001,
    0.0015,
    0.002,
    0.003,
    0.005,
    0.01,
    0.025,
    0.05,
    0.1,
    0.25,
)
#: A 25-step sweep at 180 deg/s with a 20 Hz RSSI source takes a couple of seconds.
SCAN_PERIOD_BUCKETS_S = (0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 20.0)


def _finite(value: float | None) -> TypeGuard[float]:
    return value is not None and math.isfinite(value)


class _StateCollector(Collector):
    """Reads `RelayState` at scrape time: levels and per-device health."""

    def __init__(self, state: RelayState, clock: Clock) -> None:
        self._state = state
        self._clock = clock

    def describe(self) -> Iterable[Metric]:
        # Returning nothing keeps registration from calling collect() before the daemon runs.
        return ()

    # Complexity: one metric family after another; each `if` is a value that may be unknown.
    def collect(self) -> Iterator[Metric]:  # noqa: C901
        st = self._state
        now = self._clock.now()

        info = InfoMetricFamily("relayd_build", "relayd build information")
        info.add_metric([], {"version": __version__})
        yield info

        yield GaugeMetricFamily(
            "relayd_uptime_seconds",
            "Seconds since the daemon started",
            value=max(0.0, now - st.started_t),
        )

        mode = StateSetMetricFamily("relayd_mode", "Operating mode (follow/hold/manual)")
        mode.add_metric([], {m.value: st.mode == m for m in Mode})
        yield mode
        drive = StateSetMetricFamily("relayd_drive_state", "What the controller is doing")
        drive.add_metric([], {s.value: st.state == s for s in DriveState})
        yield drive
        # The reason is an open set (e.g. "controller_error: ValueError"), so it is a label of
        # a one-series info metric rather than a state set; alerts and dashboards join on it.
        why = InfoMetricFamily(
            "relayd_drive", "The drive state with its reason, as /status shows them"
        )
        why.add_metric([], {"state": st.state.value, "reason": st.reason})
        yield why
        yield GaugeMetricFamily(
            "relayd_situation",
            "Obstacle situation (0 none, 1 avoid, 2 penalty)",
            value=st.situation,
        )

        if st.loop_tick_t is not None:
            yield GaugeMetricFamily(
                "relayd_control_loop_last_tick_age_seconds",
                "Seconds since the control loop last ticked",
                value=max(0.0, now - st.loop_tick_t),
            )

        bearing = GaugeMetricFamily(
            "relayd_bearing_degrees",
            "Leader bearing, robot frame, counter-clockwise positive",
            labels=["antenna"],
        )
        if _finite(st.bearing_deg):
            bearing.add_metric(["scan"], st.bearing_deg)
        if _finite(st.link_bearing_deg):
            bearing.add_metric(["link"], st.link_bearing_deg)
        yield bearing

        rssi = GaugeMetricFamily(
            "relayd_rssi_dbm",
            "Best RSSI of the last scan (leader) and RSSI of the node behind",
            labels=["peer"],
        )
        if _finite(st.rssi_leader_dbm):
            rssi.add_metric(["leader"], st.rssi_leader_dbm)
        if _finite(st.rssi_behind_dbm):
            rssi.add_metric(["behind"], st.rssi_behind_dbm)
        yield rssi

        thresholds = GaugeMetricFamily(
            "relayd_rssi_threshold_dbm", "Configured stop thresholds", labels=["peer"]
        )
        for key, peer in (("threshold_l_dbm", "leader"), ("threshold_b_dbm", "behind")):
            value = st.thresholds.get(key)
            if _finite(value):
                thresholds.add_metric([peer], float(value))
        yield thresholds

        wheels = GaugeMetricFamily(
            "relayd_wheel_speed_meters_per_second", "Commanded wheel speed", labels=["wheel"]
        )
        wheels.add_metric(["left"], st.wheels_left_mm_s / 1000.0)
        wheels.add_metric(["right"], st.wheels_right_mm_s / 1000.0)
        yield wheels

        if _finite(st.battery_v):
            yield GaugeMetricFamily(
                "relayd_battery_volts", "Base battery voltage", value=st.battery_v
            )
        yield GaugeMetricFamily(
            "relayd_motors_enabled",
            "1 when the base reports its motors enabled",
            value=1.0 if st.motors_enabled else 0.0,
        )

        sonar = GaugeMetricFamily(
            "relayd_sonar_range_meters", "Latest range of each sonar", labels=["sonar"]
        )
        for index, range_mm in enumerate(st.sonar_mm):
            if range_mm is not None:
                sonar.add_metric([str(index)], range_mm / 1000.0)
        yield sonar

        yield CounterMetricFamily("relayd_scans", "Scans finished", value=st.scan_count)

        signal = GaugeMetricFamily("relayd_link_signal_dbm", "airOS radio signal", labels=["link"])
        ccq = GaugeMetricFamily(
            "relayd_link_ccq_ratio", "airOS client connection quality", labels=["link"]
        )
        rate = GaugeMetricFamily(
            "relayd_link_rate_bits_per_second", "airOS PHY rate", labels=["link", "direction"]
        )
        for name, link in st.links.items():
            if _finite(link.signal_dbm):
                signal.add_metric([name], link.signal_dbm)
            if _finite(link.ccq_pct):
                ccq.add_metric([name], link.ccq_pct / 100.0)
            if _finite(link.tx_mbps):
                rate.add_metric([name, "tx"], link.tx_mbps * 1e6)
            if _finite(link.rx_mbps):
                rate.add_metric([name, "rx"], link.rx_mbps * 1e6)
        yield signal
        yield ccq
        yield rate

        connected = GaugeMetricFamily(
            "relayd_device_connected", "1 when the device link is up", labels=["device"]
        )
        errors = CounterMetricFamily(
            "relayd_device_errors", "Errors seen on the device link", labels=["device"]
        )
        reconnects = CounterMetricFamily(
            "relayd_device_reconnects", "Times the device link came back", labels=["device"]
        )
        age = GaugeMetricFamily(
            "relayd_device_data_age_seconds",
            "Seconds since the device last sent data",
            labels=["device"],
        )
        for name, health in st.health_now().items():
            connected.add_metric([name], 1.0 if health.connected else 0.0)
            errors.add_metric([name], health.errors)
            reconnects.add_metric([name], health.reconnects)
            data_age = health.age_s(now)
            if data_age is not None:
                age.add_metric([name], data_age)
        yield connected
        yield errors
        yield reconnects
        yield age


class Metrics:
    """The metrics of one daemon; mount `registry` on /metrics."""

    def __init__(self, state: RelayState, clock: Clock) -> None:
        self.state = state
        self.clock = clock
        self.registry = CollectorRegistry(auto_describe=False)
        self._control_latency = Histogram(
            "relayd_control_latency_seconds",
            "SIP received to wheel command written",
            buckets=CONTROL_LATENCY_BUCKETS_S,
            registry=self.registry,
        )
        self._control_step = Histogram(
            "relayd_control_step_seconds",
            "Controller evaluation on one SIP (inputs gathered, control law, command queued)",
            buckets=CONTROL_LATENCY_BUCKETS_S,
            registry=self.registry,
        )
        self._scan_period = Histogram(
            "relayd_scan_period_seconds",
            "Duration of one scan (servo sweep with RSSI samples)",
            buckets=SCAN_PERIOD_BUCKETS_S,
            registry=self.registry,
        )
        self._sips = Counter(
            "relayd_sips_received",
            "Server information packets received from the base",
            registry=self.registry,
        )
        self.registry.register(_StateCollector(state, clock))

    def observe_control_latency(self, seconds: float) -> None:
        if math.isfinite(seconds) and seconds >= 0:
            self._control_latency.observe(seconds)

    def observe_control_step(self, seconds: float) -> None:
        if math.isfinite(seconds) and seconds >= 0:
            self._control_step.observe(seconds)

    def observe_scan_period(self, seconds: float) -> None:
        if math.isfinite(seconds) and seconds >= 0:
            self._scan_period.observe(seconds)

    def sip_received(self) -> None:
        self._sips.inc()
