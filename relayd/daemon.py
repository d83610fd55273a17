"""The relayd daemon: builds every driver and task from a Settings object and runs them.

`relayd run` and the simulator use this same class, so a simulated relay runs exactly
the code a robot runs. Start-up order: secrets resolved (a missing one is a config
error, before any device is touched), drivers constructed, tasks started under the
supervisor, API bound, then READY to systemd. Devices may still be connecting when
READY is sent; /status says so.

Shutdown (SIGTERM/SIGINT cancel `run()`): the control tick stops and the wheels are
zeroed at once, the robot driver disables the motors and sends CLOSE, the servo and
poll tasks are cancelled, the API closes. The robot's safe stop is bounded so the
whole sequence fits in the 0.5 s the spec allows.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import os
from collections.abc import Mapping, Sequence
from typing import Any

import structlog

from drivers.airos.model import LinkQuality
from drivers.clock import REAL_CLOCK, Clock
from relayd.config import ConfigError, Settings, resolve_secret, secret_refs
from relayd.config_checks import api_bind_error
from relayd.control import ControlLoop
from relayd.controller import ControlParams
from relayd.estimator import EstimatorParams, ScanEstimate
from relayd.scanner import RssiMonitor, Scanner, scan_period_nominal_s
from relayd.state import LinkInfo, Mode, RelayState
from relayd.supervisor import Supervisor

log = structlog.get_logger(__name__)

#: Wall-clock budget for the robot's safe stop (wheels 0, ENABLE 0, CLOSE) on shutdown.
SAFE_STOP_BUDGET_S = 0.3


def control_params(settings: Settings) -> ControlParams:
    c, s, w, pt = settings.control, settings.scan, settings.wifi, settings.pantilt
    scan_period = scan_period_nominal_s(s.width_deg, pt.speed_deg_s, s.samples, s.settle_s, w.sample_hz, s.mode)
    rear_poll = settings.ap.rear.poll_s if settings.ap.rear is not None else 1.0
    return ControlParams(
        kp=c.kp, kd=c.kd, w1=c.w1, w2=c.w2, v_max_mm_s=c.v_max_mm_s,
        threshold_l_dbm=c.threshold_l_dbm, threshold_b_dbm=c.threshold_b_dbm,
        hysteresis_db=c.hysteresis_db, rear_link_required=c.rear_link == "require",
        threshold_o_m=c.threshold_o_m, stop_distance_m=c.stop_distance_m,
        detect_range_m=c.detect_range_m, gamma_o_m=c.gamma_o_m,
        sip_timeout_s=settings.robot.lost_after_s,
        # SPEC 2.5: no fresh RSSI for two scan periods.
        rssi_timeout_s=2.0 * scan_period,
        rear_timeout_s=c.rear_stale_polls * rear_poll,
        manual_deadman_s=c.manual_deadman_s,
        escape=c.escape,
    )


def estimator_params(settings: Settings) -> EstimatorParams:
    c = settings.control
    return EstimatorParams(
        gamma=settings.scan.gamma, threshold_o_m=c.threshold_o_m, detect_range_m=c.detect_range_m,
        alpha_db=c.alpha_db, beta_per_m=c.beta_per_m, gamma_o_m=c.gamma_o_m,
    )


def behind_signal(quality: LinkQuality, station_mac: str | None) -> float | None:
    """RSSI^b from the rear AP: the configured station, else the strongest one heard.

    A rear radio in station mode has no station list; its own signal is then the
    link's, unless a particular station was asked for.
    """
    if station_mac is not None:
        return quality.station_signal_dbm(station_mac)
    best = quality.best_station_signal_dbm
    return best if best is not None else quality.signal_dbm


class Daemon:
    """One relay's daemon. `await run()` until cancelled; cancellation is the safe shutdown."""

    def __init__(self, settings: Settings, *, clock: Clock = REAL_CLOCK,
                 env: Mapping[str, str] | None = None, notifier: Any = None) -> None:
        self.settings = settings
        self.clock = clock
        env = os.environ if env is None else env
        # Resolve every secret first: a missing one must stop us before a device moves.
        refs = secret_refs(settings)
        self._ap_passwords: dict[str, str] = {}
        for side in ("rear", "front"):
            ref = refs.get(f"ap.{side}")
            if ref is not None:
                secret = resolve_secret(ref, env)
                assert secret is not None
                self._ap_passwords[side] = secret
        token_ref = refs.get("api")
        self._token = resolve_secret(token_ref, env) \
            if token_ref is not None and _configured(settings.api, env) else None

        c = settings.control
        self.state = RelayState(started_t=clock.now(), mode=Mode(c.mode),
                                display_name=settings.robot.display_name)
        self.state.thresholds = {
            "threshold_l_dbm": c.threshold_l_dbm, "threshold_b_dbm": c.threshold_b_dbm,
            "hysteresis_db": c.hysteresis_db, "lost_rssi_dbm": c.lost_rssi_dbm,
            "threshold_o_m": c.threshold_o_m, "v_max_mm_s": c.v_max_mm_s,
        }
        self.api_port: int | None = None
        self.notifier = notifier
        self.supervisor = Supervisor(self.state, clock)
        self.robot: Any = None
        self.pantilt: Any = None
        self.monitor: RssiMonitor | None = None
        self.scanner: Scanner | None = None
        self.pollers: dict[str, Any] = {}
        self.metrics: Any = None
        self._runner: Any = None
        self._build()

    # -- construction ---------------------------------------------------------------

    def _build(self) -> None:
        s, clock, state = self.settings, self.clock, self.state
        from relayd.metrics import Metrics

        self.metrics = Metrics(state, clock)
        if s.robot.enabled:
            from drivers.arcos import ArcosRobot

            self.robot = ArcosRobot(s.robot.port, s.robot.baud, clock=clock,
                                    subclass_override=s.robot.subclass,
                                    lost_after_s=s.robot.lost_after_s, enable_motors=True)
            self.robot.add_listener(self._on_sip)
            # SPEC 6's control latency: SIP bytes in to the wheel command it caused written.
            self.robot.on_command_latency = self.metrics.observe_control_latency
            self.supervisor.add("robot", self.robot.run, device="robot")
        if s.pantilt.enabled:
            from drivers.pantilt import ServoCalibration, make_pantilt

            limits = (float(s.pantilt.limits_deg[0]), float(s.pantilt.limits_deg[1]))

            def calibration(pulse_us: Sequence[float]) -> ServoCalibration:
                lo, mid, hi = (float(p) for p in pulse_us)
                return ServoCalibration((lo, mid, hi), limits)

            self.pantilt = make_pantilt(
                s.pantilt.protocol, s.pantilt.port, s.pantilt.baud,
                {
                    s.pantilt.scan_channel: calibration(s.pantilt.scan_pulse_us),
                    s.pantilt.link_channel: calibration(s.pantilt.link_pulse_us),
                },
                clock=clock,
            )
            self.supervisor.add("pantilt", self.pantilt.run, device="pantilt")
        if s.wifi.enabled:
            from drivers.wifi import make_source

            source = make_source(s.wifi.source, s.wifi.interface, path=s.wifi.procfs_path, clock=clock)
            self.monitor = RssiMonitor(source, s.wifi.sample_hz, state, clock)
            self.supervisor.add("wifi", self.monitor.run, device="wifi")
        for side, password in self._ap_passwords.items():
            from drivers.airos import AirOsPoller

            ap = getattr(s.ap, side)
            poller = AirOsPoller(ap.url, ap.username, password, poll_s=ap.poll_s,
                                 legacy_tls=ap.legacy_tls, timeout_s=ap.timeout_s, clock=clock,
                                 on_update=functools.partial(self._on_link, side))
            self.pollers[side] = poller
            self.supervisor.add(f"ap.{side}", poller.run, device=f"ap.{side}")
        if self.pantilt is not None and self.monitor is not None:
            self.scanner = Scanner(
                pantilt=self.pantilt, monitor=self.monitor, state=state, clock=clock,
                scan_channel=s.pantilt.scan_channel, link_channel=s.pantilt.link_channel,
                samples=s.scan.samples, width_deg=s.scan.width_deg,
                limits_deg=(float(s.pantilt.limits_deg[0]), float(s.pantilt.limits_deg[1])),
                speed_deg_s=s.pantilt.speed_deg_s, settle_s=s.scan.settle_s, mode=s.scan.mode,
                params=estimator_params(s), lost_rssi_dbm=s.control.lost_rssi_dbm,
                heading_deg=self._heading, sonar_mm=self._sonar,
                on_scan=self._on_scan,
            )
            self.supervisor.add("scanner", self.scanner.run, device="pantilt")
        self.control = ControlLoop(
            robot=self.robot, scanner=self.scanner, monitor=self.monitor, state=state,
            params=control_params(s), clock=clock, rear_rssi=self._rear_rssi,
            on_latency=self.metrics.observe_control_step,
        )
        self.supervisor.add("control", self.control.run)
        self.supervisor.add("health", self._health_loop)

    # -- data in ------------------------------------------------------------------------

    def _on_scan(self, estimate: ScanEstimate, now: float) -> None:
        if self.scanner is not None and self.scanner.last_period_s is not None:
            self.metrics.observe_scan_period(self.scanner.last_period_s)

    def _heading(self) -> float | None:
        sip = getattr(self.robot, "last_sip", None)
        return None if sip is None else float(sip.theta_deg)

    def _sonar(self) -> list[int | None]:
        if self.robot is None:
            return [None] * 16
        return list(self.robot.sonar.ranges_mm)

    def _on_sip(self, sip: Any) -> None:
        st = self.state
        st.x_mm, st.y_mm, st.theta_deg = sip.x_mm, sip.y_mm, sip.theta_deg
        st.battery_v = sip.battery_v
        st.motors_enabled = sip.motors_enabled
        st.sonar_mm = list(self.robot.sonar.ranges_mm)
        health = st.device("robot")
        health.connected = True
        health.last_data_t = sip.t
        self.metrics.sip_received()

    def _on_link(self, side: str, quality: LinkQuality) -> None:
        st = self.state
        st.links[side] = LinkInfo(
            signal_dbm=quality.signal_dbm, rssi=quality.rssi, noise_dbm=quality.noise_dbm,
            ccq_pct=quality.ccq_pct, tx_mbps=quality.tx_mbps, rx_mbps=quality.rx_mbps,
            t=self.clock.now(),
        )
        if side == "rear":
            ap = self.settings.ap.rear
            st.rssi_behind_dbm = behind_signal(quality, ap.station_mac if ap is not None else None)
        health = st.device(f"ap.{side}")
        health.connected = True
        health.last_data_t = self.clock.now()

    def _rear_rssi(self) -> tuple[float | None, float | None]:
        link = self.state.links.get("rear")
        if link is None or self.state.rssi_behind_dbm is None:
            return None, None
        return self.state.rssi_behind_dbm, link.t

    async def _health_loop(self) -> None:
        """Copy driver counters into the state for /status and /metrics, twice a second."""
        st = self.state
        rear_timeout_s = control_params(self.settings).rear_timeout_s
        while True:
            rear = st.links.get("rear")
            if st.rssi_behind_dbm is not None and (
                    rear is None or rear.t is None or self.clock.now() - rear.t > rear_timeout_s):
                # /status must not show a value the controller already refuses as stale.
                st.rssi_behind_dbm = None
                st.touch()
            if self.robot is not None:
                h = st.device("robot")
                h.connected = bool(self.robot.connected) and not bool(self.robot.stale)
                counters = self.robot.counters
                h.errors = int(sum(v for k, v in counters.items() if k.endswith(("errors", "resyncs"))))
                h.reconnects = int(counters.get("reconnects", 0))
                h.last_error = self.robot.last_error
                ident = self.robot.identity
                if ident is not None:
                    st.robot_name = ident.name
            if self.pantilt is not None:
                h = st.device("pantilt")
                h.connected = bool(self.pantilt.connected) and (self.scanner is None or self.scanner.servo_ok)
                pc = self.pantilt.counters
                h.errors = int(pc.get("timeouts", 0)) + int(pc.get("errors", 0))
                h.reconnects = int(pc.get("reconnects", 0))
                h.last_error = self.pantilt.last_error or h.last_error
                if self.pantilt.last_reply_t is not None:
                    h.last_data_t = self.pantilt.last_reply_t
            for side, poller in self.pollers.items():
                h = st.device(f"ap.{side}")
                h.connected = getattr(poller, "state", "") == "ok"
                pc = getattr(poller, "counters", {})
                h.errors = int(pc.get("errors", 0))
                h.reconnects = int(pc.get("relogins", 0))
                h.last_error = getattr(poller, "last_error", None)
            if self.notifier is not None and st.loop_tick_t is not None \
                    and self.clock.now() - st.loop_tick_t < 1.0:
                # Pet the watchdog only while the control loop really ticks.
                self.notifier.watchdog()
            await self.clock.sleep(0.5)

    # -- lifecycle ----------------------------------------------------------------------

    async def start(self) -> None:
        s = self.settings
        if s.api.enabled:
            from relayd.api import make_app, start_api

            app = make_app(self.state, self.control, clock=self.clock, token=self._token,
                           metrics=self.metrics, healthz_max_age_s=max(1.0, 5 * 0.1))
            # Bound before any device is touched: a wrong bind or a taken port is a
            # config error (exit 2 naming the key), not a robot that is already enabled.
            try:
                self._runner, self.api_port = await start_api(app, s.api.bind, s.api.port)
            except OSError as exc:
                raise ConfigError([api_bind_error(s.api.bind, s.api.port, exc)]) from None
            log.info("api_control", enabled=self._token is not None,
                     note=None if self._token else "no token configured: POST endpoints answer 403")
        self.supervisor.start()
        if self.notifier is not None:
            self.notifier.ready()
            self.notifier.status("running; devices connecting")

    async def run(self) -> None:
        try:
            await self.start()
            await asyncio.Event().wait()
        finally:
            await self.shutdown()

    async def shutdown(self) -> None:
        if self.notifier is not None:
            self.notifier.stopping()
        log.info("shutting_down")
        # The robot's run() returns after its safe stop below: not a failure to restart.
        self.supervisor.begin_stop()
        # The controller first, synchronously: a SIP handled during the safe stop must not
        # put a non-zero VEL between the stop's VEL 0 and its ENABLE 0.
        self.control.halt()
        if self.robot is not None:
            self.robot.stop()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self.robot.shutdown(), SAFE_STOP_BUDGET_S)
        await self.supervisor.stop(timeout_s=0.2)
        if self.pantilt is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self.pantilt.close(), 0.1)
        if self._runner is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._runner.cleanup(), 0.2)
            self._runner = None
        log.info("stopped")


def _configured(api: Any, env: Mapping[str, str]) -> bool:
    """A token is optional: with none configured the control endpoints answer 403."""
    if api.token_file:
        return True
    return bool(api.token_env and env.get(api.token_env))
