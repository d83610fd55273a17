"""The relayd daemon: builds every driver and task from a Settings object and runs them.

`relayd run` and the simulator use this same class, so a simulated relay runs exactly
the code a robot runs. Start-up order: secrets resolved (a missing one is a config
error, before any device is touched), drivers constructed, tasks started under the
supervisor, API bound, then READY to systemd. Devices may still be connecting when
READY is sent; /status says so.

Shutdown (any catchable fatal signal cancels `run()`, as does a task dying beyond its
keeper): the control tick stops and the wheels are
zeroed at once, the robot driver disables the motors and sends CLOSE, the servo and
poll tasks are cancelled, the API closes. The robot's safe stop is bounded so the
whole sequence fits in 0.5 s (docs/CONTROL.md 6, "Shutdown").
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import structlog

from drivers.airos import AirOsClient, AirOsPoller
from drivers.airos.model import LinkQuality
from drivers.arcos import ArcosRobot
from drivers.pantilt import PanTilt
from drivers.transport.clock import REAL_CLOCK, Clock
from drivers.transport.health import DeviceHealth
from drivers.transport.link import held_ports
from drivers.wifi import RssiSource
from relayd.config.checks import api_bind_error
from relayd.config.model import (
    ApiSettings,
    ConfigError,
    Settings,
    check_api_token,
    resolve_secret,
    secret_refs,
)
from relayd.config.params import brain_params, control_params, estimator_params
from relayd.core.brain import Brain
from relayd.core.events import (
    Action,
    Event,
    LinkEvent,
    LinkSide,
    ScanPlan,
    ServoTarget,
    WheelCommand,
)
from relayd.core.vocab import Mode
from relayd.record import off_status
from relayd.runtime.bus import Bus
from relayd.runtime.control import ControlShell
from relayd.runtime.fdbudget import FdBudget
from relayd.runtime.health import device_health
from relayd.runtime.leaderfeed import LeaderFeedTask, PathClient
from relayd.runtime.metrics import Metrics
from relayd.runtime.scanner import RssiMonitor, Scanner
from relayd.runtime.state import RelayState
from relayd.runtime.statewriter import StateWriter
from relayd.runtime.supervisor import Supervisor

if TYPE_CHECKING:
    from relayd.api.server import ApiServer
    from relayd.record.live import LiveServer
    from relayd.record.recorder import Recorder

__all__ = ["Daemon", "DeviceOverrides", "control_params", "estimator_params"]

log = structlog.get_logger(__name__)

#: Wall-clock budget for the robot's safe stop (wheels 0, ENABLE 0, CLOSE) on shutdown.
SAFE_STOP_BUDGET_S = 0.3
#: The control tick (clock s): runs the fail-safes when no SIP arrives.
TICK_S = 0.1
#: How often the systemd watchdog is petted while the control loop ticks (clock s).
WATCHDOG_PET_S = 0.5


@dataclass(frozen=True, slots=True)
class DeviceOverrides:
    """In-process stand-ins for devices without a `memory://` link (the simulator on virtual time).

    `rssi_source` replaces the configured RSSI source; `airos_clients[side]` replaces
    that poller's HTTP client (same interface, see relayd.sim.inproc); `leader_path`
    replaces the leader feed's HTTP client (the leader relay's daemon in this process).
    """

    rssi_source: RssiSource | None = None
    airos_clients: Mapping[str, AirOsClient] = field(default_factory=dict)
    leader_path: PathClient | None = None


class Notifier(Protocol):
    """What the daemon tells systemd (relayd.runtime.sdnotify.SdNotifier implements it)."""

    def ready(self) -> None: ...
    def status(self, text: str) -> None: ...
    def watchdog(self) -> None: ...
    def stopping(self) -> None: ...


class Daemon:
    """One relay's daemon. `await run()` until cancelled; cancellation is the safe shutdown."""

    def __init__(
        self,
        settings: Settings,
        *,
        clock: Clock = REAL_CLOCK,
        env: Mapping[str, str] | None = None,
        notifier: Notifier | None = None,
        devices: DeviceOverrides | None = None,
    ) -> None:
        self.settings = settings
        self.clock = clock
        self._devices = devices or DeviceOverrides()
        env = os.environ if env is None else env
        # Resolve every secret first: a missing one must stop us before a device moves.
        refs = secret_refs(settings)
        self._ap_passwords: dict[str, str] = {}
        for side in ("rear", "front"):
            ref = refs.get(f"ap.{side}")
            if ref is not None:
                secret = resolve_secret(ref, env)  # raises ConfigError when configured but missing
                if secret is not None:
                    self._ap_passwords[side] = secret
        token_ref = refs.get("api")
        self._token = (
            resolve_secret(token_ref, env)
            if token_ref is not None and _configured(settings.api, env)
            else None
        )
        if self._token is not None and token_ref is not None:
            check_api_token(token_ref, self._token)
        from relayd.config.tls import tls_context

        self._tls = tls_context(settings.api)

        c = settings.control
        self.state = RelayState(
            started_t=clock.now(), mode=Mode(c.mode), display_name=settings.robot.display_name
        )
        self.state.thresholds = {
            "threshold_l_dbm": c.threshold_l_dbm,
            "threshold_b_dbm": c.threshold_b_dbm,
            "hysteresis_db": c.hysteresis_db,
            "lost_rssi_dbm": c.lost_rssi_dbm,
            "threshold_o_m": c.threshold_o_m,
            "v_max_mm_s": c.v_max_mm_s,
        }
        self.api_port: int | None = None
        self.notifier = notifier
        self.supervisor = Supervisor(self.state, clock, on_fault=self._on_task_fault)
        self.metrics = Metrics(self.state, clock)
        self.brain = Brain(brain_params(settings), mode=Mode(c.mode))
        self.bus: Bus[Event, Action] = Bus()
        self.writer = StateWriter(
            self.state, self.metrics, link_channel=settings.pantilt.link_channel
        )
        self.robot: ArcosRobot | None = None
        self.pantilt: PanTilt | None = None
        self.source: RssiSource | None = None
        self.monitor: RssiMonitor | None = None
        self.scanner: Scanner | None = None
        self.pollers: dict[str, AirOsPoller] = {}
        self._runner: ApiServer | None = None
        self._last_pet: float | None = None
        self.recorder: Recorder | None = None
        self._record_task: asyncio.Task[None] | None = None
        # The recorder and the live view (and their MCAP writer) are imported only when
        # configured: a daemon without them does not carry them in memory.
        if settings.record.enabled:
            from relayd.record.recorder import Recorder

            # One bus subscriber (docs/RECORDING.md); never on the control path.
            self.recorder = Recorder(
                self.bus,
                settings,
                clock,
                identity=lambda: None if self.robot is None else self.robot.identity,
            )
        self.state.trail_source = self.brain.trail_json
        self.state.pattern_source = self.brain.scans.pattern_learned
        self.state.path_source = self.brain.trail.path_json
        self.state.recording_source = (
            self.recorder.status if self.recorder is not None else off_status
        )
        # One descriptor account for every listener (the API, the live view): together
        # they leave the devices their reserve (relayd/runtime/fdbudget.py).
        self.fds = FdBudget.for_process()
        self.live: LiveServer | None = None
        self._live_task: asyncio.Task[None] | None = None
        if settings.foxglove.enabled:
            from relayd.record.live import LiveServer

            # The live Foxglove view: one more bus subscriber, never on the control path.
            self.live = LiveServer(self.bus, settings, clock, budget=self.fds)
            self.state.health_sources["foxglove"] = self.live.health
        self._build()
        self.bus.connect(self.brain.handle, self._on_actions)

    # -- construction ---------------------------------------------------------------

    def _build(self) -> None:
        s, clock, state = self.settings, self.clock, self.state
        if s.robot.enabled:
            robot = self.robot = ArcosRobot(
                s.robot.port,
                s.robot.baud,
                clock=clock,
                subclass_override=s.robot.subclass,
                lost_after_s=s.robot.lost_after_s,
                enable_motors=True,
            )
            state.health_sources["robot"] = lambda: device_health(robot)
            self.supervisor.add("robot", robot.run, device="robot")
        if s.pantilt.enabled:
            from drivers.pantilt import ServoCalibration, make_pantilt

            limits = (float(s.pantilt.limits_deg[0]), float(s.pantilt.limits_deg[1]))

            def calibration(pulse_us: Sequence[float]) -> ServoCalibration:
                lo, mid, hi = (float(p) for p in pulse_us)
                return ServoCalibration((lo, mid, hi), limits)

            self.pantilt = make_pantilt(
                s.pantilt.protocol,
                s.pantilt.port,
                s.pantilt.baud,
                {
                    s.pantilt.scan_channel: calibration(s.pantilt.scan_pulse_us),
                    s.pantilt.link_channel: calibration(s.pantilt.link_pulse_us),
                },
                clock=clock,
            )
            self.supervisor.add("pantilt", self.pantilt.run, device="pantilt")
        if s.wifi.enabled:
            from drivers.wifi import make_source

            source = self.source = self._devices.rssi_source or make_source(
                s.wifi.source, s.wifi.interface, path=s.wifi.procfs_path, clock=clock
            )
            monitor = self.monitor = RssiMonitor(source, s.wifi.sample_hz, self.bus, clock)
            state.health_sources["wifi"] = lambda: device_health(
                source, last_data_t=monitor.last_fresh_t
            )
            self.supervisor.add("wifi", monitor.run, device="wifi")
        for side, password in self._ap_passwords.items():
            ap = s.ap.rear if side == "rear" else s.ap.front
            if ap is None:
                continue
            poller = AirOsPoller(
                ap.url,
                ap.username,
                password,
                poll_s=ap.poll_s,
                legacy_tls=ap.legacy_tls,
                timeout_s=ap.timeout_s,
                clock=clock,
                on_update=functools.partial(self._on_link, LinkSide(side)),
            )
            client = self._devices.airos_clients.get(side)
            if client is not None:
                poller.client = client
            self.pollers[side] = poller
            state.health_sources[f"ap.{side}"] = functools.partial(device_health, poller)
            self.supervisor.add(f"ap.{side}", poller.run, device=f"ap.{side}")
        self.leader_feed: LeaderFeedTask | None = None
        if s.control.leader_url is not None:
            # A relay following a relay: the leader's own path (docs/CONTROL.md 7.1).
            feed = self.leader_feed = LeaderFeedTask(
                s.control.leader_url,
                poll_s=s.control.leader_poll_s,
                clock=clock,
                publish=self.bus.publish,
                client=self._devices.leader_path,
            )
            state.health_sources["leader_feed"] = functools.partial(device_health, feed)
            self.supervisor.add("leader_feed", feed.run, device="leader_feed")
        pantilt = self.pantilt
        if pantilt is not None and self.monitor is not None:
            scanner = self.scanner = Scanner(
                pantilt=pantilt,
                monitor=self.monitor,
                bus=self.bus,
                clock=clock,
                scan_channel=s.pantilt.scan_channel,
                link_channel=s.pantilt.link_channel,
                limits_deg=(float(s.pantilt.limits_deg[0]), float(s.pantilt.limits_deg[1])),
                speed_deg_s=s.pantilt.speed_deg_s,
                settle_s=s.scan.settle_s,
                mode=s.scan.mode,
                on_servo_change=lambda: self.control.check_devices(),
            )
            self.supervisor.add("scanner", scanner.run, device="pantilt")
        if pantilt is not None:
            scanner_ = self.scanner
            state.health_sources["pantilt"] = lambda: device_health(
                pantilt,
                usable=scanner_ is None or scanner_.servo_ok,
                extra_errors=0 if scanner_ is None else scanner_.link_errors,
            )
        robot_ = self.robot
        health: dict[str, Callable[[], DeviceHealth]] = {}
        if self.robot is not None:
            health["robot"] = self.robot.health
        if self.pantilt is not None:
            health["pantilt"] = self.pantilt.health
        if self.source is not None:
            health["wifi"] = self.source.health
        for side, poller in self.pollers.items():
            health[f"ap.{side}"] = poller.health
        self.control = ControlShell(
            bus=self.bus,
            brain=self.brain,
            robot=robot_,
            clock=clock,
            tick_s=TICK_S,
            on_latency=self.metrics.observe_control_latency,
            on_step=self.metrics.observe_control_step,
            servo_up=None
            if self.scanner is None
            else (lambda: self.scanner is not None and self.scanner.servo_ok),
            robot_name=lambda: (
                None if robot_ is None or robot_.identity is None else robot_.identity.name
            ),
            on_tick=self._on_tick,
            health=health,
        )
        self.supervisor.add("control", self.control.run)

    # -- the route: events in, actions out ----------------------------------------------

    def _on_actions(self, event: Event, actions: Sequence[Action]) -> None:
        """Carry out the brain's actions for one event; never raises into the publisher."""
        self.writer.on_event(event)
        for action in actions:
            try:
                match action:
                    case WheelCommand():
                        self.control.execute(action)
                    case ScanPlan():
                        if self.scanner is not None:
                            self.scanner.plan(action)
                    case ServoTarget():
                        if self.scanner is not None:
                            self.scanner.point_link(action)
                    case _:
                        self.writer.on_action(action)
            except Exception:
                log.exception("action_failed", action=type(action).__name__)

    def _on_task_fault(self, device: str, message: str) -> None:
        self.control.report_fault(device, message)

    def _on_link(self, side: LinkSide, quality: LinkQuality) -> None:
        self.bus.publish(LinkEvent(self.clock.now(), side, quality))

    def _on_tick(self, now: float) -> None:
        """Pet the watchdog only while the control loop really ticks."""
        if self.notifier is not None and (
            self._last_pet is None or now - self._last_pet >= WATCHDOG_PET_S
        ):
            self._last_pet = now
            self.notifier.watchdog()

    # -- lifecycle ----------------------------------------------------------------------

    async def start(self) -> None:
        s = self.settings
        # A port another process holds is a start error (exit 2) before anything is
        # touched, not a wait: the driver would retry it and take the robot over the
        # moment the other relayd stopped.
        ports = [("robot.port", s.robot.port, s.robot.enabled)]
        ports.append(("pantilt.port", s.pantilt.port, s.pantilt.enabled))
        if held := held_ports([(key, url) for key, url, on in ports if on]):
            raise ConfigError(held)
        if s.api.enabled:
            from relayd.api import make_app, start_api
            from relayd.api.guard import GuardedServer

            app = make_app(
                self.state,
                self.control,
                clock=self.clock,
                token=self._token,
                metrics=self.metrics,
                healthz_max_age_s=max(1.0, 5 * 0.1),
                allowed_hosts=tuple(s.api.allowed_hosts),
            )
            # Bound before any device is touched: a wrong bind or a taken port is a
            # config error (exit 2 naming the key), not a robot that is already enabled.
            try:
                self._runner, self.api_port = await start_api(
                    app,
                    s.api.bind,
                    s.api.port,
                    ssl_context=self._tls,
                    guard=GuardedServer(budget=self.fds),
                )
            except OSError as exc:
                raise ConfigError([api_bind_error(s.api.bind, s.api.port, exc)]) from None
            log.info(
                "api_control",
                enabled=self._token is not None,
                note=None if self._token else "no token configured: POST endpoints answer 403",
            )
        if self.live is not None:
            from relayd.record.live import BindError

            # Bound before any device too: a taken port is a config error, not a half-started robot.
            try:
                self.live.start()
            except BindError as exc:
                raise ConfigError(
                    [f"{exc.key}: cannot listen on {s.foxglove.bind}:{s.foxglove.port}: {exc}"]
                ) from None
            self._live_task = asyncio.create_task(self.live.run(), name="relayd:foxglove")
        if self.recorder is not None:
            # Before any device: the first SIP's event is in the file.
            self.recorder.start()
            self._record_task = asyncio.create_task(self.recorder.run(), name="relayd:recorder")
        self.supervisor.start()
        if self.notifier is not None:
            self.notifier.ready()
            self.notifier.status("running; devices connecting")

    async def run(self) -> None:
        """Until cancelled, or until a task dies beyond its keeper (raises TaskDied)."""
        try:
            await self.start()
            await self.supervisor.wait_fatal()
        finally:
            await self.shutdown()

    async def shutdown(self) -> None:
        # Nothing before the robot's safe stop may keep it from running: each step that
        # could fail (a bug, a subscriber raising) is contained.
        if self.notifier is not None:
            with contextlib.suppress(Exception):
                self.notifier.stopping()
        log.info("shutting_down")
        # The robot's run() returns after its safe stop below: not a failure to restart.
        self.supervisor.begin_stop()
        # The controller first, synchronously: a SIP handled during the safe stop must not
        # put a non-zero VEL between the stop's VEL 0 and its ENABLE 0.
        try:
            self.control.halt()
        except Exception:
            log.exception("halt_failed")
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
        if self.live is not None or self._live_task is not None:
            from relayd.record.live import close_soon

            await close_soon(self.live, self._live_task)
        if self.recorder is not None:
            # Last: the Shutdown event and the final wheel stop are in the file.
            await self.recorder.close()
        if self._record_task is not None:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await asyncio.wait_for(self._record_task, 0.5)
        log.info("stopped")


def _configured(api: ApiSettings, env: Mapping[str, str]) -> bool:
    """A token is optional: with none configured the control endpoints answer 403."""
    if api.token_file:
        return True
    return bool(api.token_env and env.get(api.token_env))
