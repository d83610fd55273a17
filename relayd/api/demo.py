"""Serve the API and live page on a plausible, moving `RelayState` without any device.

`python -m relayd.api.demo --host 127.0.0.1 --port 8080 [--token T]` is for working on
the live page's layout; `populate` gives unit tests (tests/api/test_app.py) a full state.
The state is synthetic and says so in `reason`; nothing here is used by the daemon.
For the real thing without hardware: `relayd fake rig` and `relayd run -c` on its config.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import random
from dataclasses import replace

import structlog

from drivers.transport.clock import REAL_CLOCK, Clock
from drivers.transport.health import DeviceHealth, LinkState
from relayd.api.app import make_app
from relayd.api.server import start_api
from relayd.core.vocab import DriveState, Mode, ScanRecord
from relayd.runtime.state import LinkInfo, ModeError, RelayState

log = structlog.get_logger(__name__)


class DemoControls:
    """`Controls` acting directly on the state: mode switches and manual wheels."""

    def __init__(self, state: RelayState) -> None:
        self.state = state

    def set_mode(self, mode: Mode) -> None:
        self.state.mode = mode
        if mode is not Mode.FOLLOW:
            self.state.wheels_left_mm_s = self.state.wheels_right_mm_s = 0.0
        self.state.touch()

    def manual_drive(self, left_mm_s: float, right_mm_s: float) -> None:
        if self.state.mode is not Mode.MANUAL:
            raise ModeError(f"drive needs manual mode, robot is in {self.state.mode} mode")
        self.state.wheels_left_mm_s = left_mm_s
        self.state.wheels_right_mm_s = right_mm_s
        self.state.touch()


def synthetic_scan(
    t: float,
    leader_deg: float,
    samples: int = 25,
    peak_dbm: float = -42.0,
    rng: random.Random | None = None,
) -> ScanRecord:
    """A Yagi sweep -90..+90 towards a leader at `leader_deg` (cos^2 beam, some noise)."""
    rng = rng or random.Random(0)
    angles = tuple(-90.0 + 180.0 * j / (samples - 1) for j in range(samples))
    rssi = []
    for a in angles:
        off = math.radians(a - leader_deg)
        gain_db = (
            10 * math.log10(max(math.cos(off) ** 2, 1e-3)) if abs(off) < math.pi / 2 else -30.0
        )
        rssi.append(round(peak_dbm + gain_db + rng.gauss(0, 1.0), 1))
    weights = [10 ** ((r - max(rssi)) / 10) for r in rssi]
    bearing = sum(w * a for w, a in zip(weights, angles, strict=True)) / sum(weights)
    return ScanRecord(
        t=t,
        angles_deg=angles,
        rssi_dbm=tuple(rssi),
        bearing_deg=round(bearing, 2),
        rssi_leader_dbm=max(rssi),
        situation=0,
        period_s=1.6,
    )


def populate(state: RelayState, clock: Clock) -> None:
    """Fill every field /status reports with plausible values."""
    now = clock.now()
    state.started_t = now
    state.robot_name = "relay-demo"
    state.mode = Mode.FOLLOW
    state.state = DriveState.DRIVING
    state.reason = "demo: synthetic state, no devices"
    state.thresholds = {
        "threshold_l_dbm": -30.0,
        "threshold_b_dbm": -60.0,
        "threshold_o_m": 0.8,
        "v_max_mm_s": 400.0,
    }
    scan = synthetic_scan(now, 20.0)
    state.last_scan = scan
    state.scan_count = 1
    state.bearing_deg = scan.bearing_deg
    state.link_bearing_deg = scan.bearing_deg
    state.rssi_leader_dbm = scan.rssi_leader_dbm
    state.rssi_behind_dbm = -52.0
    state.wheels_left_mm_s, state.wheels_right_mm_s = 180.0, 220.0
    state.x_mm, state.y_mm, state.theta_deg = 1250.0, -300.0, 12.0
    state.battery_v = 12.6
    state.motors_enabled = True
    state.sonar_mm = [
        2400,
        1800,
        3100,
        4200,
        4300,
        2900,
        1200,
        650,
        5000,
        5000,
        3300,
        2800,
        2700,
        3900,
        1500,
        900,
    ]
    state.links = {
        "front": LinkInfo(
            signal_dbm=-48, rssi=47, noise_dbm=-96, ccq_pct=91, tx_mbps=54.0, rx_mbps=48.0, t=now
        ),
        "rear": LinkInfo(
            signal_dbm=-55, rssi=40, noise_dbm=-95, ccq_pct=84, tx_mbps=36.0, rx_mbps=36.0, t=now
        ),
    }
    for name in ("base", "servo", "wifi", "ap_front", "ap_rear"):
        state.health[name] = DeviceHealth(name, LinkState.UP, last_rx_t=now)
    state.loop_tick_t = now
    state.touch()


async def animate(state: RelayState, clock: Clock, period_s: float = 0.1) -> None:
    """Keep the demo alive: the loop ticks, a scan arrives every 16 ticks, the leader wanders."""
    rng = random.Random(1)
    tick = 0
    while True:
        await clock.sleep(period_s)
        now = clock.now()
        tick += 1
        state.loop_tick_t = now
        state.health = {name: replace(h, last_rx_t=now) for name, h in state.health.items()}
        if tick % 16 == 0:
            leader = 40.0 * math.sin(now / 7.0)
            scan = synthetic_scan(now, leader, rng=rng)
            state.last_scan = scan
            state.scan_count += 1
            state.bearing_deg = scan.bearing_deg
            state.link_bearing_deg = scan.bearing_deg
            state.rssi_leader_dbm = scan.rssi_leader_dbm
            state.sonar_mm = [
                max(300, min(5000, (r or 2000) + rng.randint(-80, 80))) for r in state.sonar_mm
            ]
        state.touch()


async def serve(host: str, port: int, token: str | None, animated: bool = True) -> None:
    clock = REAL_CLOCK
    state = RelayState()
    populate(state, clock)
    app = make_app(state, DemoControls(state), clock=clock, token=token)
    runner, bound = await start_api(app, host, port)
    # Tests wait for this line to know the port is bound.
    print(f"relayd-demo listening on http://{host}:{bound}/", flush=True)
    try:
        if animated:
            await animate(state, clock)
        else:
            await asyncio.Event().wait()
    finally:
        await runner.cleanup()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8080)
    parser.add_argument("--static", action="store_true", help="do not animate the state")
    args = parser.parse_args()
    token = os.environ.get("RELAYD_API_TOKEN") or None
    try:
        asyncio.run(serve(args.host, args.port, token, animated=not args.static))
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main()
