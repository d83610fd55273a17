"""The simulation runner: real relayd daemons driving fake devices in a simulated world.

For each relay it starts a FakeRobot (its true pose integrated by the fake, sonar and
collisions answered by the world), a FakeMaestro, the Yagi's RSSI and two FakeAirOs
radios, generates that relay's Settings and runs a `relayd.daemon.Daemon` on them in
this event loop, exactly as `relayd run` would on a robot (relayd/sim/relay.py builds
each relay; this module runs them and the world).

Two modes, chosen by the loop it runs on:

- virtual time (`relayd.runtime.vtime.VirtualTimeLoop`, what `relayd sim` uses): the devices
  are in-process (memory:// links for the base and the servo controller, a
  `MemoryRssi`, `InProcessAirOs` clients), every event is a loop callback at its
  virtual time, and the same scenario and seed give byte-identical summary.json and
  trace.jsonl. The status API still answers on a real socket.
- real time (any other loop): ptys, a procfs-format RSSI file and the airOS fakes
  over HTTP, one `Clock(speed)` shared by everything. Kept for bench/soak.py, which
  injects faults at the OS level (a pty hang-up, an HTTP radio going down) and
  measures wall-clock resource growth over real I/O.

The world ticks at the scenario's `tick_hz` (clock time): it moves the scripted leader,
reads every robot's true pose and servo angles, writes the Yagi's RSSI into each
relay's procfs file, updates the airOS link values, and records the trace. The summary
(`summarize`) is a pure function of the trace.
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import json
import math
import os
import secrets
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import structlog

from drivers.transport.clock import Clock
from relayd.runtime.vtime import LoopClock, VirtualTimeLoop
from relayd.sim.relay import SimRelay, pulse_to_deg, start_relay
from relayd.sim.scenario import Scenario
from relayd.sim.summary import summarize, unapplied_command_s
from relayd.sim.tasks import cancel_and_wait
from relayd.sim.world import World

__all__ = ["SimResult", "SimRunner", "summarize", "unapplied_command_s"]

log = structlog.get_logger(__name__)

#: How often the airOS fakes get new link values (clock s); the pollers poll at 1 s.
AIROS_UPDATE_S = 0.5
#: Trace records per clock second.
TRACE_HZ = 10.0


def scratch_root() -> str | None:
    """Where the simulated relays' ptys and RSSI files go: a RAM filesystem when there is one.

    Each world tick rewrites every relay's procfs-format RSSI file (write + atomic
    rename). On a disk filesystem such as ext4 a rename over an existing file starts a
    write-back of the new data, which blocked the event loop for ~10 ms per tick and
    made the simulation lag its clock at speed 10 and above. /dev/shm (tmpfs) makes it a
    memory copy. None: the platform's default temporary directory.
    """
    shm = "/dev/shm"
    if os.path.isdir(shm) and os.access(shm, os.W_OK | os.X_OK):
        return shm
    return None


def _relay_context(name: str) -> contextvars.Context:
    ctx = contextvars.copy_context()
    ctx.run(structlog.contextvars.bind_contextvars, relay=name)
    return ctx


@dataclass(slots=True)
class SimResult:
    summary: dict[str, Any]
    records: list[dict[str, Any]]
    api_ports: dict[str, int | None] = field(default_factory=dict)


class SimRunner:
    """Runs one scenario with real daemons; `await run()` returns the summary and trace."""

    def __init__(
        self,
        scenario: Scenario,
        *,
        speed: float | None = 10.0,
        seed: int = 1,
        seconds: float | None = None,
        out_dir: Path | None = None,
        workdir: Path | None = None,
        on_progress: Callable[[dict[str, Any]], None] | None = None,
        on_ready: Callable[[dict[str, int | None]], None] | None = None,
        record_dir: Path | None = None,
        recovery: bool | None = None,
    ) -> None:
        self.scenario = scenario
        #: Each relay's daemon records to <record_dir>/<name>.mcap (its own [record] config).
        self.record_dir = record_dir
        #: Forces every relay's recovery.enabled (the bench's on/off); None: the scenario's.
        self.recovery = recovery
        self.speed = speed
        # Real-time mode's clock; on a virtual-time loop run() replaces it with the loop's.
        self.clock: Clock = Clock(speed or 1.0)
        self.virtual = False
        self.t0: float | None = None
        self.seed = seed
        self.seconds = scenario.duration_s if seconds is None else seconds
        self.out_dir = out_dir
        self.workdir = workdir
        self.on_progress = on_progress
        self.on_ready = on_ready
        self.world = World(scenario, seed=seed)
        self.relays: list[SimRelay] = []
        self.records: list[dict[str, Any]] = []
        self._password = secrets.token_hex(8)
        self._travelled = [0.0] * len(self.world.relays)

    # -- bring-up ---------------------------------------------------------------------
    async def _start_relay(self, i: int, work: Path) -> SimRelay:
        relay = await start_relay(
            self.scenario,
            self.world,
            i,
            clock=self.clock,
            virtual=self.virtual,
            work=work,
            prefix=f"sim{id(self):x}",
            seed=self.seed,
            password=self._password,
            recovery=self._recovery_section(),
            record_dir=self.record_dir,
            ahead=self.relays[i - 1] if i > 0 else None,
        )
        self._update_links()
        return relay

    def _recovery_section(self) -> dict[str, Any]:
        section = dict(self.scenario.recovery)
        if self.recovery is not None:
            section["enabled"] = self.recovery
        return section

    async def _wait_ports(self) -> dict[str, int | None]:
        async with asyncio.timeout(10.0):
            # The Daemon publishes its port as an attribute once bound; poll it briefly.
            while any(r.daemon.api_port is None for r in self.relays):  # noqa: ASYNC110
                await asyncio.sleep(0.01)
        return {r.name: r.daemon.api_port for r in self.relays}

    # -- the world tick ---------------------------------------------------------------
    def _sync_bodies(self) -> None:
        for i, r in enumerate(self.relays):
            body = self.world.relays[i]
            x, y, th = float(r.robot.x_mm), float(r.robot.y_mm), float(r.robot.theta_deg)
            self._travelled[i] += math.hypot(x / 1000.0 - body.x_m, y / 1000.0 - body.y_m)
            self.world.set_pose(i, x, y, th)
            self.world.set_servos(
                i, pulse_to_deg(r.maestro.position_us(0)), pulse_to_deg(r.maestro.position_us(1))
            )

    def _write_rssi(self) -> None:
        for i, r in enumerate(self.relays):
            r.procfs.write(self.world.yagi_rssi_dbm(i))

    def _update_links(self) -> None:
        w = self.world
        noise = w.radio.params.noise_floor_dbm
        n = len(self.relays)
        for i, r in enumerate(self.relays):
            # relay i is node i+1: its front link is hop i, its rear AP hears hop i+1.
            for ap, k in ((r.front, i), (r.rear, i + 1)):
                if k > n:
                    continue
                level = w.hop_sample_dbm(k)
                rate = w.hop(k).phy_mbps
                ap.set_link(
                    level,
                    noise_dbm=noise,
                    ccq_pct=95.0 if rate else 0.0,
                    tx_mbps=rate,
                    rx_mbps=rate,
                )

    def _record(self, t: float) -> dict[str, Any]:
        w = self.world
        links = w.links()
        relays = []
        for i, r in enumerate(self.relays):
            body = w.relays[i]
            st = r.daemon.state
            relays.append(
                {
                    "name": body.name,
                    "x": round(body.x_m, 3),
                    "y": round(body.y_m, 3),
                    "theta_deg": round(body.theta_deg, 1),
                    "state": str(st.state),
                    "reason": st.reason,
                    "bearing_deg": st.bearing_deg,
                    "true_bearing_deg": round(w.true_bearing_deg(i), 1),
                    "rssi_l_dbm": st.rssi_leader_dbm,
                    "rssi_b_dbm": st.rssi_behind_dbm,
                    "scan_deg": round(body.scan_deg, 1),
                    "link_deg": round(body.link_deg, 1),
                    "gap_m": round(w.gap_m(i), 3),
                    "collisions": body.collisions,
                    "wheels": [round(st.wheels_left_mm_s), round(st.wheels_right_mm_s)],
                    "v_mm_s": round(float(r.robot.vel_mm_s)),
                    "w_deg_s": round(float(r.robot.rvel_deg_s), 1),
                    "rssi_l_mean_dbm": round(w.radio.mean_power_dbm(body.pos, w.node_pos(i))[0], 1),
                    "situation": st.situation,
                    "threshold_b_dbm": st.thresholds.get("threshold_b_dbm"),
                    # Pursuit "trail" only, so a "bearing" run's trace stays as it was.
                    **self._trail_record(r),
                    "recovery": None
                    if (rv := st.recovery) is None
                    else {
                        "phase": str(rv.phase),
                        "kind": None if rv.kind is None else str(rv.kind),
                        "episodes": rv.episodes,
                        "distance_m": rv.distance_m,
                        "outcome": rv.last_outcome,
                    },
                }
            )
        return {
            "t": round(t, 2),
            "leader": {
                "x": round(w.leader.x_m, 3),
                "y": round(w.leader.y_m, 3),
                "moving": w.leader.moving,
            },
            "cc": [round(w.cc[0], 3), round(w.cc[1], 3)],
            "timed_present": list(w.timed_present),
            "relays": relays,
            "hops": [
                {"dbm": round(h.power_dbm, 1), "mbps": h.rate_mbps, "walls": h.walls}
                for h in links.hops
            ],
            "e2e_mbps": links.e2e_mbps,
            "broken": links.broken,
        }

    @staticmethod
    def _trail_record(relay: SimRelay) -> dict[str, Any]:
        """The relay's trail source and leader estimate (odometry frame = the world's here)."""
        trail = relay.daemon.brain.trail
        if trail.params.pursuit != "trail":
            return {}
        v = trail.view()
        shown: dict[str, Any] = {
            "source": v.source,
            "leader_xy_m": None if v.leader_xy_m is None else list(v.leader_xy_m),
            "leader_sigma_m": v.leader_sigma_m,
            "caught_up": v.caught_up,
        }
        if v.feed is not None:  # a relay following a relay: why it is (not) on the feed
            shown["feed"] = v.feed.state
            shown["feed_alignment"] = v.feed.alignment
        return {"trail": shown}

    async def _world_loop(self) -> None:
        clock = self.clock
        dt = 1.0 / self.scenario.tick_hz
        t0 = self.t0 = clock.now()
        next_t = t0
        next_airos = 0.0
        next_trace = 0.0
        end = self.seconds
        done_at: float | None = None
        while True:
            t = clock.now() - t0
            self.world.advance(t)
            self._sync_bodies()
            self._write_rssi()
            if t >= next_airos:
                self._update_links()
                next_airos = t + AIROS_UPDATE_S
            if t >= next_trace:
                rec = self._record(t)
                self.records.append(rec)
                next_trace += 1.0 / TRACE_HZ
                if self.on_progress is not None:
                    self.on_progress(rec)
            if self.world.leader.done and done_at is None:
                done_at = t
            if t >= end or (
                done_at is not None and t >= done_at + self.scenario.settle_after_goal_s
            ):
                break
            next_t += dt
            await clock.sleep(next_t - clock.now())

    # -- run --------------------------------------------------------------------------
    async def run(self) -> SimResult:
        loop = asyncio.get_running_loop()
        if isinstance(loop, VirtualTimeLoop):
            self.virtual = True
            self.clock = LoopClock(loop)
        with contextlib.ExitStack() as stack:
            work = self.workdir
            if work is None:
                work = Path(
                    stack.enter_context(
                        tempfile.TemporaryDirectory(prefix="relayd-sim-", dir=scratch_root())
                    )
                )
            try:
                contexts = [_relay_context(b.name) for b in self.world.relays]
                for i, ctx in enumerate(contexts):
                    # In the relay's own context: its fakes' tasks inherit `relay=<name>` for sim.log.
                    self.relays.append(
                        await asyncio.create_task(self._start_relay(i, work), context=ctx)
                    )
                for r, ctx in zip(self.relays, contexts, strict=True):
                    r.task = asyncio.create_task(
                        r.daemon.run(), name=f"sim-daemon-{r.name}", context=ctx
                    )
                ports = await self._wait_ports() if self.relays else {}
                if self.on_ready is not None:
                    self.on_ready(ports)
                await self._world_loop()
            finally:
                await self._teardown()
        result = SimResult(self._summary(ports), self.records, ports)
        if self.out_dir is not None:
            self.write_outputs(result, self.out_dir)
        return result

    async def _teardown(self) -> None:
        await cancel_and_wait(r.task for r in self.relays)
        for r in self.relays:
            await self._close_devices(r)

    async def _close_devices(self, r: SimRelay) -> None:
        """Stop one relay's fakes once its daemon has ended."""
        for closer in (r.robot.stop, r.rear.stop, r.front.stop):
            with contextlib.suppress(Exception):
                await closer()
        with contextlib.suppress(Exception):
            r.maestro.close()

    def sim_time(self) -> float:
        """Simulated seconds since the world started (trace.jsonl's `t`); 0 while relays start."""
        return 0.0 if self.t0 is None else self.clock.now() - self.t0

    def _summary(self, ports: dict[str, int | None]) -> dict[str, Any]:
        followers = [
            {"name": b.name, "collisions": b.collisions, "travelled_m": self._travelled[i]}
            for i, b in enumerate(self.world.relays)
        ]
        return summarize(
            self.records,
            scenario=self.scenario.name,
            relays=len(self.world.relays),
            goal=self.world.leader_script.goal,
            goal_radius_m=self.scenario.goal_radius_m,
            collisions=self.world.collisions(),
            followers=followers,
        )

    def write_outputs(self, result: SimResult, out: Path) -> None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "summary.json").write_text(
            json.dumps(result.summary, indent=2) + "\n", encoding="utf-8"
        )
        # The API ports the OS picked: where to look during the run, not a result of it
        # (so they stay out of summary.json, which the same scenario and seed reproduce).
        (out / "ports.json").write_text(
            json.dumps(result.api_ports, indent=2) + "\n", encoding="utf-8"
        )
        with (out / "trace.jsonl").open("w", encoding="utf-8") as f:
            for rec in result.records:
                f.write(json.dumps(rec, separators=(",", ":")) + "\n")
