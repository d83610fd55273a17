"""One relay's fake devices on this machine, wired to a one-leader world.

`FakeRig` starts a fake P3-AT and a fake Maestro on real pseudo-terminals, a
/proc/net/wireless-format file and two fake airOS radios on loopback, and ties them
together with the smallest world that exercises the whole daemon: a leader at a point
on the floor. Every `tick_s` it reads where the fake robot is and where the fake scan
servo points, and writes the RSSI the Yagi would hear (log-distance path loss plus the
Yagi's cos^2 pattern), so a real relayd sweeping the servo finds the leader's bearing
and drives towards it. The rear radio reports a settable RSSI^b.

Tests, benchmarks and `relayd fake rig` use it; `config_doc()` is the config a
`relayd run` (in-process `Daemon` or subprocess) needs to drive it. Knobs for
fault injection are plain attributes: `rssi_frozen` stops the RSSI file updating,
`leader_xy_m` moves the leader, `rear.set_link(...)` changes RSSI^b, and the fakes'
own switches (`robot.silent`, `robot.hang_up()`, `maestro.hang_up()`, ...) do the rest.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import secrets
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

from drivers.airos.fake import FakeAirOs
from drivers.arcos.fake import FakeRobot
from drivers.pantilt.fake import FakeMaestro
from drivers.transport.clock import REAL_CLOCK, Clock
from drivers.wifi.fake import ProcfsWriter
from relayd.config.model import Settings
from relayd.config.tomlwriter import dump_toml
from relayd.sim.radio import yagi_gain_db

#: Servo calibration shared by the fake and the generated config.
PULSE_US = (1000.0, 1500.0, 2000.0)
AP_PASSWORD_ENV = "RELAYD_RIG_AP_PASSWORD"
API_TOKEN_ENV = "RELAYD_RIG_API_TOKEN"


def pulse_to_deg(pulse_us: float) -> float:
    lo, mid, hi = PULSE_US
    if pulse_us >= mid:
        return (pulse_us - mid) / (hi - mid) * 90.0
    return (pulse_us - mid) / (mid - lo) * 90.0


class FakeRig:
    """Fake robot, servo controller, RSSI file and airOS radios for one relay, plus a leader."""

    def __init__(
        self,
        work: str | Path,
        *,
        clock: Clock = REAL_CLOCK,
        leader_xy_m: tuple[float, float] = (6.0, 2.0),
        rssi_1m_dbm: float = -30.0,
        path_loss_exp: float = 2.0,
        rear_signal_dbm: float = -55.0,
        tick_s: float = 0.02,
        name: str = "relay1",
        links: Literal["pty", "memory"] = "pty",
    ) -> None:
        self.work = Path(work)
        #: "pty": the base and the servo controller on pseudo-terminals (what `relayd run`
        #: in another process needs); "memory": on in-process memory:// links, for a
        #: daemon in this process, on virtual time (`relayd.runtime.vtime`).
        self.links = links
        self.clock = clock
        self.leader_xy_m = leader_xy_m
        self.rssi_1m_dbm = rssi_1m_dbm
        self.path_loss_exp = path_loss_exp
        self.tick_s = tick_s
        self.name = name
        #: While True the RSSI file is left as it is: the source goes stale.
        self.rssi_frozen = False
        self.ap_password = secrets.token_urlsafe(12)
        self.api_token = secrets.token_urlsafe(16)
        self.robot = FakeRobot(name=name, clock=clock)
        self.maestro = FakeMaestro(clock=clock, initial_us=PULSE_US[1])
        self.procfs = ProcfsWriter(self.work / f"{name}-wireless", "wlan1")
        self.rear = FakeAirOs("ubnt", self.ap_password, clock=clock)
        self.front = FakeAirOs("ubnt", self.ap_password, clock=clock)
        self._rear_signal_dbm = rear_signal_dbm
        self.robot_port: str | None = None
        self.servo_port: str | None = None
        self.rear_url: str | None = None
        self.front_url: str | None = None
        self._task: asyncio.Task[None] | None = None

    # -- the world -----------------------------------------------------------------------

    @property
    def scan_deg(self) -> float:
        return pulse_to_deg(self.maestro.position_us(0))

    @property
    def link_deg(self) -> float:
        return pulse_to_deg(self.maestro.position_us(1))

    def leader_distance_m(self) -> float:
        lx, ly = self.leader_xy_m
        return math.hypot(lx - self.robot.x_mm / 1000.0, ly - self.robot.y_mm / 1000.0)

    def true_bearing_deg(self) -> float:
        """The leader's direction in the robot frame (CCW positive), -180..180."""
        lx, ly = self.leader_xy_m
        world = math.degrees(
            math.atan2(ly - self.robot.y_mm / 1000.0, lx - self.robot.x_mm / 1000.0)
        )
        return math.remainder(world - self.robot.theta_deg, 360.0)

    def rssi_dbm(self, scan_deg: float | None = None) -> float:
        """What the Yagi hears pointing at `scan_deg` (robot frame): path loss + pattern."""
        d = max(0.3, self.leader_distance_m())
        angle = self.scan_deg if scan_deg is None else scan_deg
        path = self.rssi_1m_dbm - 10.0 * self.path_loss_exp * math.log10(d)
        return path + yagi_gain_db(angle - self.true_bearing_deg())

    def set_rear_signal(self, signal_dbm: float) -> None:
        self._rear_signal_dbm = signal_dbm
        self.rear.set_link(signal_dbm, ccq_pct=90.0, tx_mbps=54.0, rx_mbps=54.0)

    def _tick(self) -> None:
        if not self.rssi_frozen:
            self.procfs.write(self.rssi_dbm())

    async def _world(self) -> None:
        while True:
            self._tick()
            await self.clock.sleep(self.tick_s)

    # -- life cycle ------------------------------------------------------------------------

    async def start(self) -> FakeRig:
        self.work.mkdir(parents=True, exist_ok=True)
        if self.links == "memory":
            tag = f"rig{id(self):x}-{self.name}"
            self.robot_port = self.robot.serve_memory(f"{tag}-base")
            self.servo_port = self.maestro.serve_memory(f"{tag}-servo")
        else:
            self.robot_port = self.robot.serve_pty(str(self.work / f"{self.name}-base"))
            self.servo_port = self.maestro.serve_pty(str(self.work / f"{self.name}-servo"))
        await self.robot.start()
        self.rear_url = await self.rear.start()
        self.front_url = await self.front.start()
        self.set_rear_signal(self._rear_signal_dbm)
        self.front.set_link(-50.0, ccq_pct=95.0, tx_mbps=54.0, rx_mbps=54.0)
        self._tick()
        self._task = asyncio.create_task(self._world(), name="rig-world")
        return self

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        for ap in (self.rear, self.front):
            with contextlib.suppress(Exception):
                await ap.stop()
        with contextlib.suppress(Exception):
            await self.robot.stop()
        with contextlib.suppress(Exception):
            self.maestro.close()

    async def __aenter__(self) -> FakeRig:
        return await self.start()

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # -- the daemon's side -----------------------------------------------------------------

    @property
    def env(self) -> dict[str, str]:
        """Environment holding the secrets the generated config names."""
        return {AP_PASSWORD_ENV: self.ap_password, API_TOKEN_ENV: self.api_token}

    def config_doc(
        self,
        *,
        api_bind: str = "127.0.0.1",
        api_port: int = 0,
        control: Mapping[str, Any] | None = None,
        scan: Mapping[str, Any] | None = None,
        **sections: Mapping[str, Any],
    ) -> dict[str, Any]:
        """The config (config/relayd.toml's sections and keys) of a relayd driving these fakes; overrides merge per section."""
        if self.robot_port is None or self.rear_url is None:
            raise RuntimeError("start() the rig first")
        doc: dict[str, Any] = {
            "robot": {"port": self.robot_port, "baud": 9600},
            "pantilt": {
                "port": self.servo_port,
                "protocol": "maestro",
                "scan_channel": 0,
                "link_channel": 1,
                "scan_pulse_us": [int(p) for p in PULSE_US],
                "link_pulse_us": [int(p) for p in PULSE_US],
            },
            "wifi": {
                "source": "procfs",
                "interface": "wlan1",
                "procfs_path": str(self.procfs.path),
                "sample_hz": 20,
            },
            "ap": {
                "rear": {
                    "url": self.rear_url,
                    "username": "ubnt",
                    "password_env": AP_PASSWORD_ENV,
                    "poll_s": 0.5,
                },
                "front": {
                    "url": self.front_url,
                    "username": "ubnt",
                    "password_env": AP_PASSWORD_ENV,
                    "poll_s": 0.5,
                },
            },
            "scan": dict(scan or {}),
            "control": dict(control or {}),
            "api": {"bind": api_bind, "port": api_port, "token_env": API_TOKEN_ENV},
            "log": {"level": "info", "format": "console"},
        }
        for name, overrides in sections.items():
            if name not in doc and name in Settings.model_fields:
                doc[name] = {}  # a section the rig leaves at its defaults (e.g. record)
            if name not in doc:
                raise KeyError(f"no config section {name!r}")
            if name == "ap":
                for side, ap in overrides.items():
                    doc["ap"][side].update(ap)
            else:
                doc[name].update(overrides)
        return doc

    def write_config(
        self, path: str | Path | None = None, *, secrets_in_files: bool = False, **kw: Any
    ) -> Path:
        """Write `config_doc(**kw)` as TOML (default: `<work>/<name>.toml`).

        With `secrets_in_files` the AP password and API token go into 0600 files next
        to it and the config names them (`password_file`, `token_file`), so a plain
        `relayd run -c` works without the rig's environment.
        """
        p = Path(path) if path is not None else self.work / f"{self.name}.toml"
        doc = self.config_doc(**kw)
        if secrets_in_files:
            pw_file = _secret_file(p.with_name(f"{self.name}-ap-password"), self.ap_password)
            token_file = _secret_file(p.with_name(f"{self.name}-api-token"), self.api_token)
            for side in ("rear", "front"):
                ap = doc["ap"][side]
                ap.pop("password_env", None)
                ap["password_file"] = str(pw_file)
            doc["api"].pop("token_env", None)
            doc["api"]["token_file"] = str(token_file)
        p.write_text(dump_toml(doc), encoding="utf-8")
        return p


def _secret_file(path: Path, secret: str) -> Path:
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(secret + "\n")
    return path
