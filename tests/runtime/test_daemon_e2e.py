"""End to end in-process: a real `Daemon` driving one relay's fakes (FakeRig), virtual time.

The rig's world places a leader on the floor and writes the RSSI the Yagi would hear
from where the fake scan servo physically points, so the whole chain runs for real:
procfs RSSI file -> monitor -> sweeps of the fake Maestro over an in-memory link ->
brain (estimator, controller) on every SIP -> VEL/RVEL to the fake P3-AT over an
in-memory link -> the fake robot moves -> the RSSI changes. The airOS radios answer
over loopback HTTP. Time is virtual (`relayd.runtime.vtime`): waits cost no wall time and a
loaded machine cannot make a test late. The tests read the fakes (where the robot is, what it was
told, where the link servo points), not only the daemon's own state.

Scans are kept short (9 samples over 120 degrees, a fast servo) so each test takes a
few seconds; every wait polls for a condition with a generous timeout.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from relayd.config.load import parse_settings
from relayd.core.vocab import DriveState, Mode
from relayd.daemon import Daemon, control_params
from relayd.fakes.rig import FakeRig
from relayd.runtime.vtime import LoopClock
from tests.support import running, until

pytestmark = pytest.mark.slow

SCAN = {"samples": 9, "width_deg": 120, "settle_s": 0.02}
PANTILT = {"speed_deg_s": 1000}
#: Waits are generous: the machine is shared and a scan takes ~0.5 s.
TIMEOUT_S = 20.0


class Transitions:
    """Every (clock time, state, reason) the daemon went through, recorded as it happens."""

    def __init__(self, daemon: Daemon) -> None:
        self.daemon = daemon
        self.seen: list[tuple[float, DriveState, str]] = []
        self._task = asyncio.create_task(self._watch())

    async def _watch(self) -> None:
        st = self.daemon.state
        while True:
            changed = st.changed
            if not self.seen or self.seen[-1][1:] != (st.state, st.reason):
                self.seen.append((self.daemon.clock.now(), st.state, st.reason))
            await changed.wait()

    def first(self, reason: str, after: float) -> float | None:
        return next((t for t, _, r in self.seen if r == reason and t >= after), None)

    async def close(self) -> None:
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._task


def leader_at(rig: FakeRig, bearing_deg: float, distance_m: float) -> tuple[float, float]:
    """A floor point at `bearing_deg` (robot frame, ccw +) and `distance_m` from the robot now."""
    r = rig.robot
    a = math.radians(r.theta_deg + bearing_deg)
    return (r.x_mm / 1000.0 + distance_m * math.cos(a), r.y_mm / 1000.0 + distance_m * math.sin(a))


def wheels_zero(rig: FakeRig) -> bool:
    """The fake robot was told to stand still (VEL 0 and RVEL 0 arrived)."""
    return rig.robot.target_vel_mm_s == 0.0 and rig.robot.target_rvel_deg_s == 0.0


def reason(daemon: Daemon) -> tuple[DriveState, str]:
    return daemon.state.state, daemon.state.reason


@contextlib.asynccontextmanager
async def relay(
    tmp_path: Path,
    *,
    leader_deg: float = 0.0,
    distance_m: float = 6.0,
    control: dict[str, Any] | None = None,
    scan: dict[str, Any] | None = None,
    pantilt: dict[str, Any] | None = None,
) -> AsyncIterator[tuple[FakeRig, Daemon]]:
    a = math.radians(leader_deg)
    rig = FakeRig(
        tmp_path,
        leader_xy_m=(distance_m * math.cos(a), distance_m * math.sin(a)),
        clock=LoopClock(),
        links="memory",
    )
    async with rig:
        settings = parse_settings(
            rig.config_doc(
                scan={**SCAN, **(scan or {})},
                control=control,
                pantilt={**PANTILT, **(pantilt or {})},
            )
        )
        daemon = Daemon(settings, env=rig.env, clock=rig.clock)
        async with running(daemon):
            yield rig, daemon


async def driving(rig: FakeRig, daemon: Daemon) -> None:
    await until(
        lambda: reason(daemon) == (DriveState.DRIVING, "driving") and rig.robot.target_vel_mm_s > 0,
        "the relay drives",
    )


@pytest.mark.parametrize(
    ("leader_deg", "mode"), [(25.0, "step"), (-25.0, "step"), (25.0, "continuous")]
)
@pytest.mark.virtual_time
async def test_bearing_converges_and_the_robot_turns_toward_the_leader(
    tmp_path: Path, leader_deg: float, mode: str
) -> None:
    side = math.copysign(1.0, leader_deg)
    # A continuous sweep samples at 20 Hz while moving: slew slowly enough for ~13 samples.
    speed = {"speed_deg_s": 180} if mode == "continuous" else None
    async with relay(tmp_path, leader_deg=leader_deg, scan={"mode": mode}, pantilt=speed) as (
        rig,
        daemon,
    ):
        st = daemon.state
        await until(lambda: st.scan_count >= 3, "three scans")
        # From then on every scan's bearing is within 6 degrees of the truth at its end.
        errors = []
        for _ in range(3):
            count = st.scan_count
            await until(lambda: st.scan_count > count, "the next scan")  # noqa: B023
            assert st.bearing_deg is not None
            errors.append(st.bearing_deg - rig.true_bearing_deg())
        assert max(abs(e) for e in errors) < 6.0, errors
        # The robot turns toward the leader: heading moves to its side, the true bearing shrinks.
        await until(
            lambda: side * rig.robot.theta_deg > 4.0 and side * rig.true_bearing_deg() < 20.0,
            "the robot turning toward the leader",
        )
        assert rig.robot.x_mm > 100.0  # and drives forward
        assert side * rig.true_bearing_deg() > -6.0  # without overshooting
        # The link antenna points where the scan says the leader is.
        await until(
            lambda: st.bearing_deg is not None and abs(rig.link_deg - st.bearing_deg) < 2.0,
            "the link servo at the bearing",
        )
        assert side * rig.link_deg > 3.0
        assert st.link_bearing_deg is not None and abs(st.link_bearing_deg - rig.link_deg) < 2.0


@pytest.mark.virtual_time
async def test_stops_when_the_leader_is_near_and_resumes(tmp_path: Path) -> None:
    # threshold_l -40 dBm: at 6 m RSSI^l is about -46 (drive), at 2 m about -36 (stop).
    async with relay(tmp_path, control={"threshold_l_dbm": -40.0}) as (rig, daemon):
        await driving(rig, daemon)
        assert daemon.state.rssi_leader_dbm is not None and daemon.state.rssi_leader_dbm < -40.0
        rig.leader_xy_m = leader_at(rig, 0.0, 2.0)
        await until(
            lambda: reason(daemon) == (DriveState.STOPPED, "leader_near"), "stopped, leader_near"
        )
        assert daemon.state.rssi_leader_dbm is not None and daemon.state.rssi_leader_dbm >= -40.0
        await until(
            lambda: wheels_zero(rig) and rig.robot.vel_mm_s == 0.0, "the fake robot standing"
        )
        assert (daemon.state.wheels_left_mm_s, daemon.state.wheels_right_mm_s) == (0.0, 0.0)
        # The leader drives off: RSSI^l falls below threshold_l - hysteresis, the relay follows.
        rig.leader_xy_m = leader_at(rig, 0.0, 10.0)
        await driving(rig, daemon)


@pytest.mark.virtual_time
async def test_stops_when_the_rear_link_is_weak_or_stale_and_resumes(tmp_path: Path) -> None:
    async with relay(tmp_path) as (rig, daemon):
        await driving(rig, daemon)
        rig.set_rear_signal(-80.0)  # RSSI^b below threshold_b (-60)
        await until(
            lambda: reason(daemon) == (DriveState.STOPPED, "rear_weak"), "stopped, rear_weak"
        )
        await until(lambda: wheels_zero(rig), "VEL 0 at the fake robot")
        assert daemon.state.rssi_behind_dbm == -80.0
        rig.set_rear_signal(-55.0)
        await driving(rig, daemon)
        # The rear AP stops answering: RSSI^b goes stale and the relay holds (rear_link = require).
        await rig.rear.set_down(True)
        await until(
            lambda: reason(daemon) == (DriveState.FAULT, "rear_link_stale"),
            "fault, rear_link_stale",
        )
        await until(lambda: wheels_zero(rig), "VEL 0 at the fake robot")
        await rig.rear.set_down(False)
        await driving(rig, daemon)


@pytest.mark.virtual_time
async def test_stops_within_one_sip_period_of_rssi_going_stale_and_resumes(tmp_path: Path) -> None:
    async with relay(tmp_path) as (rig, daemon):
        rec = Transitions(daemon)
        try:
            await driving(rig, daemon)
            assert daemon.monitor is not None
            timeout = control_params(daemon.settings).rssi_timeout_s  # max(0.5 s, 5 sample periods)
            frozen_t = daemon.clock.now()
            rig.rssi_frozen = True
            # Wait on the recorder, not the state: the recorder's task may not have run yet
            # when the state already shows the fault.
            await until(lambda: rec.first("rssi_stale", frozen_t) is not None, "fault, rssi_stale")
            assert reason(daemon) == (DriveState.FAULT, "rssi_stale")
            stop_t = rec.first("rssi_stale", frozen_t)
            last_fresh = daemon.monitor.last_fresh_t
            assert stop_t is not None and last_fresh is not None
            late_s = stop_t - (last_fresh + timeout)
            print(f"rssi_stale {late_s * 1000:.0f} ms after the freshness limit ({timeout:.2f} s)")
            assert late_s >= 0.0  # not before the limit...
            assert (
                late_s <= 0.1 + 0.3
            )  # ...and within one SIP period (plus slack for a busy machine)
            await until(lambda: wheels_zero(rig), "VEL 0 at the fake robot")
            rig.rssi_frozen = False
            await driving(rig, daemon)
        finally:
            await rec.close()


@pytest.mark.virtual_time
async def test_modes_hold_manual_and_deadman(tmp_path: Path) -> None:
    async with relay(tmp_path, control={"manual_deadman_s": 0.5}) as (rig, daemon):
        await driving(rig, daemon)
        daemon.control.set_mode(Mode.HOLD)
        await until(lambda: wheels_zero(rig), "hold: VEL 0 at the fake robot")
        assert reason(daemon) == (DriveState.STOPPED, "hold")
        daemon.control.set_mode(Mode.MANUAL)
        assert reason(daemon) == (DriveState.STOPPED, "deadman")  # no command yet
        x0 = rig.robot.x_mm
        theta0 = rig.robot.theta_deg
        # Commands every 0.2 s (inside the dead-man time) keep it moving: a left turn forward.
        last_cmd = daemon.clock.now()
        for _ in range(6):
            daemon.control.manual_drive(150.0, 250.0)
            last_cmd = daemon.clock.now()
            await asyncio.sleep(0.2)
            assert reason(daemon) == (DriveState.DRIVING, "manual")
        assert rig.robot.target_vel_mm_s == pytest.approx(200.0, abs=5.0)
        assert rig.robot.target_rvel_deg_s > 0.0
        await until(
            lambda: rig.robot.x_mm > x0 + 50.0 and rig.robot.theta_deg > theta0 + 1.0,
            "the fake robot moving under manual control",
        )
        # Commands stop: the dead-man zeroes the wheels.
        await until(
            lambda: reason(daemon) == (DriveState.STOPPED, "deadman") and wheels_zero(rig),
            "dead-man stop",
        )
        assert daemon.clock.now() - last_cmd >= 0.5
        # Drive commands are refused outside manual mode; follow resumes the loop.
        daemon.control.set_mode(Mode.FOLLOW)
        with pytest.raises(Exception, match="manual"):
            daemon.control.manual_drive(100.0, 100.0)
        await driving(rig, daemon)
