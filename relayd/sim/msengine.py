"""The MobileSim engine of `relayd sim`: the robots in the vendor's simulator, the radio in relayd's.

One MobileSim process (relayd/sim/msproc.py) holds every robot of the run: the leader
(a P3-AT standing in for the scenario's leader, person or robot) and the relays, in the
scenario's ARIA map. Each robot is reached through an ARCOS bridge
(relayd/sim/msbridge.py) that places it (SIM_SET_POSE) and reads its true pose
(SIMSTAT) and stall flags. Each relay is a real `relayd.daemon.Daemon`, as `relayd run`
makes it, whose robot port is its bridge; its other devices (servo controller, the
Yagi's RSSI, the two airOS radios) are the in-process fakes of the built-in engine, fed
by relayd's radio model (relayd/sim/world.py) from the TRUE poses. The leader is driven
along the scenario's waypoints over ARCOS by a pursuit controller here (a P3-AT for a
robot leader, MobileSim's small AmigoBot standing in for a person).

Real time: MobileSim runs on its own clock (100 ms steps), so a run takes as long as it
simulates and is not reproducible to the byte: the daemons' timing, MobileSim's
odometry noise and the host's load all differ from run to run. The world's radio draws
(shadowing, fading) are still seeded, so the same poses give the same signal levels.
The trace, summary and plots are the built-in engine's (relayd/sim/runner.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import secrets
from pathlib import Path
from typing import Any, cast

from drivers.arcos.driver import ArcosRobot
from drivers.arcos.sip import vel_rvel_to_wheels
from relayd.core.geometry import wrap_deg
from relayd.sim.leader_script import LeaderPose
from relayd.sim.msbridge import ArcosBridge, BridgeBody
from relayd.sim.msproc import MobileSim, MobileSimError
from relayd.sim.relay import AP_PASSWORD_ENV, API_TOKEN_ENV, PULSE_US, SimRelay, relay_settings
from relayd.sim.runner import AIROS_UPDATE_S, TRACE_HZ, SimRunner
from relayd.sim.scenario import Scenario
from relayd.sim.tasks import cancel_and_wait

LEADER = "leader"
#: MobileSim's model for a person leader.
PERSON_MODEL = "amigo-nosonar"
#: The leader counts a waypoint reached within this distance (m).
WAYPOINT_REACHED_M = 0.25
#: Pursuit gains: turn rate per degree of heading error, its cap, and how far off the
#: heading may be before the leader turns in place.
TURN_GAIN = 1.5
MAX_TURN_DEG_S = 50.0
TURN_IN_PLACE_DEG = 45.0
#: How long the robots may take to report their first SIMSTAT once connected.
POSE_TIMEOUT_S = 15.0


class MobileSimRunner(SimRunner):
    """`SimRunner` with the robots in MobileSim (real time; see the module docstring)."""

    def __init__(
        self,
        scenario: Scenario,
        *,
        program: Path | None = None,
        mobilesim_log: Path | None = None,
        sim: MobileSim | None = None,
        **kwargs: Any,
    ) -> None:
        """`program` starts a MobileSim for this run; or `sim`, one already running whose
        robots include "leader" and every relay's name (it is left running)."""
        if scenario.map is None:
            raise MobileSimError("the MobileSim engine needs an ARIA map (--map FILE.map or map =)")
        kwargs["speed"] = 1.0
        super().__init__(scenario, **kwargs)
        names = [LEADER] + [b.name for b in self.world.relays]
        self._own_sim = sim is None
        if sim is None:
            if program is None:
                raise MobileSimError("no MobileSim program given")
            # A person is stood in for by MobileSim's smallest robot (an AmigoBot, about
            # 0.33 x 0.28 m, without sonar): the relays' sonar sees a body of about a
            # person's size; a robot leader is a P3-AT like the relays.
            models = {LEADER: PERSON_MODEL} if scenario.leader.kind == "person" else {}
            sim = MobileSim(
                program, Path(scenario.map), names, models=models, log_path=mobilesim_log
            )
        elif not set(names) <= set(sim.names):
            raise MobileSimError(f"the running MobileSim has robots {sim.names}, not {names}")
        self.sim = sim
        self.bridges: dict[str, ArcosBridge] = {}
        self.leader_robot: ArcosRobot | None = None
        self._leader_task: asyncio.Task[None] | None = None
        self._wp = 1
        self._pause_until: float | None = None

    # -- bring-up ---------------------------------------------------------------------
    async def _bridge(self, name: str, pose: tuple[float, float, float]) -> ArcosBridge:
        b = ArcosBridge(BridgeBody(name), self.sim.port(name), pose)
        await b.start()
        self.bridges[name] = b
        return b

    async def _start_relay(self, i: int, work: Path) -> SimRelay:
        from drivers.airos.fake import FakeAirOs
        from drivers.pantilt.fake import FakeMaestro
        from relayd.config.model import Settings
        from relayd.daemon import Daemon, DeviceOverrides
        from relayd.sim.inproc import InProcessAirOs, MemoryRssi

        body = self.world.relays[i]
        bridge = await self._bridge(body.name, (body.x_m * 1000, body.y_m * 1000, body.theta_deg))
        clock = self.clock
        tag = f"ms{id(self):x}-{body.name}"
        maestro = FakeMaestro(clock=clock, initial_us=PULSE_US[1])
        rear = FakeAirOs("ubnt", self._password, clock=clock)
        front = FakeAirOs("ubnt", self._password, clock=clock)
        rssi = MemoryRssi("wlan1", clock=clock)
        rssi.write(self.world.yagi_rssi_dbm(i, 0.0))
        control = dict(self.scenario.control)
        control.update(self.scenario.relay[i].control)
        doc = relay_settings(
            robot_port=bridge.url,
            servo_port=maestro.serve_memory(f"{tag}-servo"),
            procfs_path=str(work / f"{body.name}-wireless"),
            rear_url=f"http://{tag}-rear.inproc",
            front_url=f"http://{tag}-front.inproc",
            control=control,
            scan=dict(self.scenario.scan),
            recovery=self._recovery_section(),
            avoidance=self.scenario.avoidance,
        )
        devices = DeviceOverrides(
            rssi_source=rssi,
            airos_clients={
                "rear": InProcessAirOs(rear, clock=clock, name=f"{tag}-rear"),
                "front": InProcessAirOs(front, clock=clock, name=f"{tag}-front"),
            },
        )
        env = {AP_PASSWORD_ENV: self._password, API_TOKEN_ENV: secrets.token_hex(16)}
        daemon = Daemon(Settings.model_validate(doc), clock=clock, env=env, devices=devices)
        # The runner reads x_mm, y_mm, theta_deg, vel_mm_s, rvel_deg_s of `robot`: the bridge's.
        relay = SimRelay(body.name, cast(Any, bridge.body), maestro, rssi, rear, front, daemon)
        self._update_links()
        return relay

    async def run(self) -> Any:
        try:
            if self._own_sim:
                await self.sim.start()
            lead = self.scenario.leader.waypoints
            heading = (
                math.degrees(math.atan2(lead[1].y - lead[0].y, lead[1].x - lead[0].x))
                if len(lead) > 1
                else 0.0
            )
            lb = await self._bridge(LEADER, (lead[0].x * 1000, lead[0].y * 1000, heading))
            self.leader_robot = ArcosRobot(lb.url, clock=self.clock, enable_motors=True)
            self._leader_task = asyncio.create_task(self.leader_robot.run(), name="ms-leader")
            return await super().run()
        finally:
            await self._stop_all()

    async def _wait_ports(self) -> dict[str, int | None]:
        ports = await super()._wait_ports()
        try:
            async with asyncio.timeout(POSE_TIMEOUT_S):
                for b in self.bridges.values():
                    await b.body.posed.wait()
        except TimeoutError:
            raise MobileSimError(
                f"no SIMSTAT from MobileSim in {POSE_TIMEOUT_S:.0f} s (log: {self.sim.log_path})"
            ) from None
        return ports

    async def _close_devices(self, r: SimRelay) -> None:
        # The robot is MobileSim's (its bridge is closed in _stop_all); the radios are in-process.
        with contextlib.suppress(Exception):
            r.maestro.close()

    async def _stop_all(self) -> None:
        """The leader's driver, the bridges, then MobileSim: stopped whatever happens before."""
        try:
            if self.leader_robot is not None:
                with contextlib.suppress(Exception):
                    await self.leader_robot.shutdown()
            await cancel_and_wait([self._leader_task])
            for b in self.bridges.values():
                await b.close()
        finally:
            if self._own_sim:
                await self.sim.stop()

    # -- the world tick ---------------------------------------------------------------
    def _sync_bodies(self) -> None:
        for i, r in enumerate(self.relays):
            body = self.world.relays[i]
            b = self.bridges[r.name].body
            x, y, th = b.x_mm, b.y_mm, b.theta_deg
            self._travelled[i] += math.hypot(x / 1000.0 - body.x_m, y / 1000.0 - body.y_m)
            self.world.set_pose(i, x, y, th)
            self.world.set_servos(
                i,
                _pulse_deg(r.maestro.position_us(0)),
                _pulse_deg(r.maestro.position_us(1)),
            )
            # A stall (a wheel pushing against something) is a collision episode.
            if b.stalled and not body.in_contact:
                body.collisions += 1
            body.in_contact = b.stalled

    def _drive_leader(self, t: float) -> None:
        """One pursuit step of the leader toward its current waypoint; world.leader updated."""
        lb = self.bridges[LEADER].body
        x, y, th = lb.x_mm / 1000.0, lb.y_mm / 1000.0, lb.theta_deg
        wps = self.scenario.leader.waypoints
        done = self._wp >= len(wps)
        v = w = 0.0
        if not done and t >= self.scenario.leader.start_s:
            wp = wps[self._wp]
            dist = math.hypot(wp.x - x, wp.y - y)
            if dist < WAYPOINT_REACHED_M:
                if self._pause_until is None and wp.pause_s > 0:
                    self._pause_until = t + wp.pause_s
                if self._pause_until is None or t >= self._pause_until:
                    self._wp += 1
                    self._pause_until = None
                done = self._wp >= len(wps)
            else:
                err = wrap_deg(math.degrees(math.atan2(wp.y - y, wp.x - x)) - th)
                w = max(-MAX_TURN_DEG_S, min(MAX_TURN_DEG_S, TURN_GAIN * err))
                if abs(err) < TURN_IN_PLACE_DEG:
                    last = self._wp == len(wps) - 1
                    v = self.scenario.leader.speed_m_s * math.cos(math.radians(err))
                    v = min(v, dist) if last else v
        if self.leader_robot is not None:
            self.leader_robot.set_wheels(*vel_rvel_to_wheels(v * 1000.0, w))
        self.world.leader = LeaderPose(x, y, th, v > 0.0, done)

    async def _world_loop(self) -> None:
        clock = self.clock
        dt = 1.0 / self.scenario.tick_hz
        t0 = self.t0 = clock.now()
        next_t, next_airos, next_trace = t0, 0.0, 0.0
        done_at: float | None = None
        while True:
            t = clock.now() - t0
            self.world.t = t
            self._drive_leader(t)
            self._sync_bodies()
            self._write_rssi()
            if t >= next_airos:
                self._update_links()
                next_airos = t + AIROS_UPDATE_S
            if t >= next_trace:
                rec = self._record(t)
                rec["stalled"] = [self.bridges[r.name].body.stalled for r in self.relays]
                self.records.append(rec)
                next_trace += 1.0 / TRACE_HZ
                if self.on_progress is not None:
                    self.on_progress(rec)
            if self.world.leader.done and done_at is None:
                done_at = t
            if t >= self.seconds or (
                done_at is not None and t >= done_at + self.scenario.settle_after_goal_s
            ):
                break
            next_t += dt
            await clock.sleep(next_t - clock.now())


def _pulse_deg(pulse_us: float) -> float:
    from relayd.sim.relay import pulse_to_deg

    return pulse_to_deg(pulse_us)
