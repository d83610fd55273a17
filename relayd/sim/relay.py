"""One simulated relay: its fake devices, the config its daemon reads, and its bring-up.

`start_relay` builds what a robot would have (a FakeRobot whose sonar and collisions
the world answers, a FakeMaestro, the Yagi's RSSI and two FakeAirOs radios), serves
them in-process on a virtual-time loop or over ptys, a procfs-format file and HTTP in
real time, writes that relay's config document (`relay_settings`, config/relayd.toml's
sections and keys) and makes the `relayd.daemon.Daemon` that `relayd run` would. The
runner (relayd/sim/runner.py) starts the daemons and ticks the world around them.
"""

from __future__ import annotations

import asyncio
import secrets
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from drivers.transport.clock import Clock
from relayd.sim.scenario import Scenario
from relayd.sim.world import World

if TYPE_CHECKING:
    from drivers.airos.fake import FakeAirOs
    from drivers.arcos.fake import FakeRobot
    from drivers.pantilt.fake import FakeMaestro
    from drivers.wifi.fake import ProcfsWriter
    from relayd.daemon import Daemon
    from relayd.sim.inproc import MemoryRssi

#: Pulse widths at -90 / 0 / +90 degrees in the generated config (the example config's default).
PULSE_US = (1000.0, 1500.0, 2000.0)
AP_PASSWORD_ENV = "RELAYD_SIM_AP_PASSWORD"
API_TOKEN_ENV = "RELAYD_SIM_API_TOKEN"


def pulse_to_deg(pulse_us: float, pulse: Sequence[float] = PULSE_US) -> float:
    """Invert the piecewise-linear servo calibration (pulse widths at -90, 0, +90 deg)."""
    lo, mid, hi = pulse
    if (pulse_us - mid) * (hi - mid) >= 0:
        return 90.0 * (pulse_us - mid) / (hi - mid)
    return -90.0 * (pulse_us - mid) / (lo - mid)


def _pose3(p: Any) -> tuple[float, float, float]:
    """A pose from the FakeRobot: a (x_mm, y_mm, theta_deg) tuple or an object with them."""
    if isinstance(p, tuple | list):
        return float(p[0]), float(p[1]), float(p[2])
    return float(p.x_mm), float(p.y_mm), float(p.theta_deg)


def leader_feed(
    control: dict[str, Any],
    ahead: tuple[str, tuple[float, float, float]] | None,
    own: tuple[float, float, float],
) -> dict[str, Any]:
    """The `[control]` keys of a relay following the relay `ahead` (its in-memory name and
    start pose in the world) with pursuit "trail": its leader's API and where the leader's
    odometry started in ours (each odometry starts at 0, 0, 0 where its robot stands,
    as the fleet config's origins give it on a robot). Empty for the person's follower
    or the bearing pursuit, whose settings (and so traces) stay as they were."""
    if ahead is None or control.get("pursuit") != "trail" or "leader_url" in control:
        return {}
    from relayd.core.trail.align import frame_between

    tag, start = ahead
    f = frame_between(own, start)
    return {
        "leader_url": f"http://{tag}-api.inproc",
        "leader_origin": [round(f.tx_m, 6), round(f.ty_m, 6), round(f.phi_deg, 6)],
    }


def relay_settings(
    *,
    robot_port: str,
    servo_port: str,
    procfs_path: str,
    rear_url: str,
    front_url: str,
    control: dict[str, Any],
    scan: dict[str, Any],
    recovery: dict[str, Any] | None = None,
    avoidance: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The config document (config/relayd.toml's sections and keys) of one simulated relay."""
    return {
        "recovery": dict(recovery or {}),
        "avoidance": dict(avoidance or {}),
        "robot": {"port": robot_port, "baud": 9600},
        "pantilt": {
            "port": servo_port,
            "protocol": "maestro",
            "scan_channel": 0,
            "link_channel": 1,
            "scan_pulse_us": list(map(int, PULSE_US)),
            "link_pulse_us": list(map(int, PULSE_US)),
        },
        "wifi": {
            "source": "procfs",
            "interface": "wlan1",
            "procfs_path": procfs_path,
            "sample_hz": 20,
        },
        "ap": {
            "rear": {"url": rear_url, "username": "ubnt", "password_env": AP_PASSWORD_ENV},
            "front": {"url": front_url, "username": "ubnt", "password_env": AP_PASSWORD_ENV},
        },
        "scan": dict(scan),
        "control": dict(control),
        "api": {"bind": "127.0.0.1", "port": 0, "token_env": API_TOKEN_ENV},
        "log": {"level": "warning", "format": "console"},
    }


@dataclass(slots=True)
class SimRelay:
    """One simulated relay: its fakes and its daemon."""

    name: str
    robot: FakeRobot
    maestro: FakeMaestro
    procfs: ProcfsWriter | MemoryRssi
    rear: FakeAirOs
    front: FakeAirOs
    daemon: Daemon
    task: asyncio.Task[None] | None = None


async def start_relay(
    scenario: Scenario,
    world: World,
    i: int,
    *,
    clock: Clock,
    virtual: bool,
    work: Path,
    prefix: str,
    seed: int,
    password: str,
    recovery: dict[str, Any],
    record_dir: Path | None,
    ahead: SimRelay | None = None,
) -> SimRelay:
    """Relay `i` of `world`: its fakes serving (in memory when `virtual`, else under
    `work`), the robot's SIP loop started, and its daemon built but not yet running.
    `prefix` names its in-memory links; the robot's fake gets seed `seed * 1000 + i`.
    `ahead` is the relay it follows (None: it follows the person); with pursuit
    "trail" it reads that relay's path (`leader_feed`)."""
    from drivers.airos.fake import FakeAirOs
    from drivers.arcos.fake import FakeRobot
    from drivers.pantilt.fake import FakeMaestro
    from drivers.wifi.fake import ProcfsWriter
    from relayd.config.model import Settings
    from relayd.daemon import Daemon, DeviceOverrides
    from relayd.sim.inproc import InProcessAirOs, InProcessPath, MemoryRssi

    body = world.relays[i]

    def sonar_fn(x_mm: float, y_mm: float, theta_deg: float) -> Sequence[int]:
        return world.sonar_ranges(i, x_mm, y_mm, theta_deg)

    def motion_guard(old: Any, new: Any) -> bool:
        return world.motion_ok(i, *_pose3(new), old=_pose3(old))

    robot = FakeRobot(
        name=body.name,
        clock=clock,
        sonar_fn=sonar_fn,
        motion_guard=motion_guard,
        pose=(body.x_m * 1000.0, body.y_m * 1000.0, body.theta_deg),
        seed=seed * 1000 + i,
    )
    maestro = FakeMaestro(clock=clock, initial_us=PULSE_US[1])
    rear = FakeAirOs("ubnt", password, clock=clock)
    front = FakeAirOs("ubnt", password, clock=clock)
    devices: DeviceOverrides | None = None
    procfs: ProcfsWriter | MemoryRssi
    if virtual:
        tag = f"{prefix}-{body.name}"
        robot_port = robot.serve_memory(f"{tag}-base")
        servo_port = maestro.serve_memory(f"{tag}-servo")
        procfs = MemoryRssi("wlan1", clock=clock)
        procfs_path = str(work / f"{body.name}-wireless")  # unused: the source is in memory
        rear_url, front_url = f"http://{tag}-rear.inproc", f"http://{tag}-front.inproc"
        devices = DeviceOverrides(
            rssi_source=procfs,
            airos_clients={
                "rear": InProcessAirOs(rear, clock=clock, name=f"{tag}-rear"),
                "front": InProcessAirOs(front, clock=clock, name=f"{tag}-front"),
            },
        )
    else:
        robot_port = robot.serve_pty(str(work / f"{body.name}-base"))
        servo_port = maestro.serve_pty(str(work / f"{body.name}-servo"))
        procfs = ProcfsWriter(work / f"{body.name}-wireless", "wlan1")
        procfs_path = str(procfs.path)
        rear_url = await rear.start()
        front_url = await front.start()
    await robot.start()
    procfs.write(world.yagi_rssi_dbm(i, 0.0))
    control = dict(scenario.control)
    control.update(scenario.relay[i].control)
    in_front = None
    if ahead is not None:
        lb = world.relays[i - 1]
        in_front = (f"{prefix}-{ahead.name}", (lb.x_m, lb.y_m, lb.theta_deg))
    feed = leader_feed(control, in_front, (body.x_m, body.y_m, body.theta_deg))
    control.update(feed)
    doc = relay_settings(
        robot_port=robot_port,
        servo_port=servo_port,
        procfs_path=procfs_path,
        rear_url=rear_url,
        front_url=front_url,
        control=control,
        scan=scenario.daemon_scan(),
        recovery=recovery,
        avoidance=scenario.avoidance,
    )
    if record_dir is not None:
        doc["record"] = {"enabled": True, "path": str(record_dir / f"{body.name}.mcap")}
    if feed and ahead is not None:
        state = ahead.daemon.state
        path = InProcessPath(lambda: None if state.path_source is None else state.path_source())
        devices = (
            DeviceOverrides(leader_path=path)
            if devices is None
            else replace(devices, leader_path=path)
        )
    settings = Settings.model_validate(doc)
    env = {AP_PASSWORD_ENV: password, API_TOKEN_ENV: secrets.token_hex(16)}
    daemon = Daemon(settings, clock=clock, env=env, devices=devices)
    return SimRelay(body.name, robot, maestro, procfs, rear, front, daemon)
