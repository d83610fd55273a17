"""The scan shell and the brain against a byte-true FakeMaestro and a scripted RSSI source.

The scripted source is a tiny world: every reading is what a Yagi would hear where
the fake scan servo *physically* points at the reading's timestamp (the fake slews in
clock time), and every value is unique, so a test can tell exactly which reading the
scanner paired with which angle, when it was taken and where the servo really was.
Real driver on an in-memory link, real RssiMonitor, the brain planning the sweeps and
estimating; only the radio is scripted. Virtual time: the sweeps take no wall time.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from drivers.arcos.sip import Sip
from drivers.pantilt import PanTilt, ServoCalibration, make_pantilt
from drivers.pantilt.fake import FakeMaestro
from drivers.transport.backoff import Backoff
from drivers.transport.clock import Clock
from drivers.wifi.records import RssiSample
from relayd.core.brain import PANTILT, Brain, BrainParams
from relayd.core.events import (
    Action,
    DeviceEvent,
    DeviceStatus,
    Event,
    ScanPlan,
    ScanResult,
    ServoTarget,
    SipEvent,
)
from relayd.core.scan.estimator import LOST_AFTER_SCANS, EstimatorParams, ScanEstimate
from relayd.core.scan.plan import ScanParams
from relayd.fakes.rig import pulse_to_deg
from relayd.runtime.bus import Bus
from relayd.runtime.scanner import RssiMonitor, Scanner, ScanServoError
from relayd.runtime.state import RelayState
from relayd.runtime.statewriter import StateWriter
from relayd.runtime.vtime import LoopClock
from relayd.sim.radio import yagi_gain_db
from tests.support import until

_names = itertools.count()

SCAN, LINK = 0, 1
SPEED_DEG_S = 300.0
SETTLE_S = 0.03
SAMPLE_HZ = 100.0
WIDTH_DEG = 60.0
SAMPLES = 7
LIMITS = (-90.0, 90.0)


@dataclass
class Logged:
    t: float
    servo_deg: float  # where the fake scan servo physically pointed at t
    rssi_dbm: float


class ScriptedSource:
    """Reads the fake servo's real position and answers with a leader's RSSI.

    `latency_s` models a source whose reading is stamped before an await (netlink,
    `iw`): the sample reaches the monitor that long after its timestamp. Every
    `stale_every`-th read is not fresh and carries a poison value that must never be
    used.
    """

    POISON_DBM = 10.0

    def __init__(
        self, fake: FakeMaestro, clock: Clock, *, latency_s: float = 0.0, stale_every: int = 0
    ) -> None:
        self.fake = fake
        self.clock = clock
        self.latency_s = latency_s
        self.stale_every = stale_every
        self.leader_deg = 20.0
        self.level_dbm = -50.0
        self.reads = 0
        self.log: dict[float, Logged] = {}

    def servo_deg(self) -> float:
        return pulse_to_deg(self.fake.position_us(SCAN))

    async def read(self) -> RssiSample:
        t = self.clock.now()
        servo = self.servo_deg()
        self.reads += 1
        if self.latency_s:
            await asyncio.sleep(self.latency_s)
        if self.stale_every and self.reads % self.stale_every == 0:
            return RssiSample(t, self.POISON_DBM, False)
        # Unique per reading (1e-6 dB apart): the value identifies the reading.
        rssi = self.level_dbm + yagi_gain_db(servo - self.leader_deg) - self.reads * 1e-6
        self.log[rssi] = Logged(t, servo, rssi)
        return RssiSample(t, rssi, True)

    def used(self, rssi: float) -> Logged:
        return self.log[rssi]


class RecordingServo:
    """The real driver, with every set_angle recorded as (time it returned, channel, angle)."""

    def __init__(self, pt: PanTilt, clock: Clock) -> None:
        self.pt = pt
        self.clock = clock
        self.commands: list[tuple[float, int, float]] = []
        self.on_command: Callable[[int], None] | None = None

    @property
    def connected(self) -> bool:
        return self.pt.connected

    @property
    def answering(self) -> bool:
        return self.pt.answering

    async def is_moving(self) -> bool:
        return await self.pt.is_moving()

    async def set_angle(self, channel: int, angle_deg: float) -> float:
        angle = await self.pt.set_angle(channel, angle_deg)
        self.commands.append((self.clock.now(), channel, angle))
        if self.on_command is not None:
            self.on_command(channel)
        return angle

    async def set_speed(self, channel: int, deg_s: float) -> None:
        await self.pt.set_speed(channel, deg_s)

    async def get_angle(self, channel: int) -> float:
        return await self.pt.get_angle(channel)

    def scan_commands(self, since: int = 0) -> list[tuple[float, float]]:
        return [(t, a) for t, ch, a in self.commands[since:] if ch == SCAN]


@dataclass
class Bench:
    """The scan shell wired to a brain as the daemon wires them, with the robot's heading scripted."""

    clock: Clock
    fake: FakeMaestro
    pt: PanTilt
    servo: RecordingServo
    source: ScriptedSource
    monitor: RssiMonitor
    state: RelayState
    scanner: Scanner
    brain: Brain
    bus: Bus[Event, Action]
    writer: StateWriter
    results: list[ScanEstimate] = field(default_factory=list)

    def on_actions(self, event: Event, actions: Sequence[Action]) -> None:
        self.writer.on_event(event)
        for a in actions:
            if isinstance(a, ScanPlan):
                self.scanner.plan(a)
            elif isinstance(a, ServoTarget):
                self.scanner.point_link(a)
            else:
                if isinstance(a, ScanResult):
                    self.results.append(a.estimate)
                self.writer.on_action(a)

    def turn_to(self, heading_deg: float) -> None:
        """The robot's odometry heading is now `heading_deg` (a SIP says so)."""
        t = self.clock.now()
        sip = Sip(
            t=t,
            x_mm=0.0,
            y_mm=0.0,
            theta_deg=heading_deg,
            left_mm_s=0.0,
            right_mm_s=0.0,
            battery_v=13.0,
            motors_enabled=True,
            estop=False,
            stall_left=False,
            stall_right=False,
            moving=False,
            sonar=(),
        )
        self.bus.publish(SipEvent(t, sip, (None,) * 16))

    async def prepare(self) -> None:
        """Prove the servo answers; the brain, told so, plans the first sweep."""
        await self.scanner.prepare()
        self.bus.publish(DeviceEvent(self.clock.now(), PANTILT, DeviceStatus.UP))

    async def scan_once(self) -> ScanEstimate | None:
        """One sweep of the brain's plan; then the link antenna is pointed, as `run()` does
        (which also proves the servo answers again after a failure before sweeping)."""
        if not self.brain.servo_ok:
            await self.prepare()
        plan = await self.scanner.next_plan()
        before = len(self.results)
        await self.scanner.sweep(plan)
        await self.scanner.point_pending_link()
        return self.results[-1] if len(self.results) > before else None


@contextlib.asynccontextmanager
async def bench(
    tmp_path: Path,
    *,
    mode: str = "step",
    latency_s: float = 0.0,
    stale_every: int = 0,
    reply_timeout_s: float = 0.25,
) -> AsyncIterator[Bench]:
    clock = LoopClock()
    fake = FakeMaestro(clock=clock, initial_us=1500.0)
    url = fake.serve_memory(f"scanner-servo-{next(_names)}")
    pt = make_pantilt(
        "maestro",
        url,
        None,
        {SCAN: ServoCalibration(), LINK: ServoCalibration()},
        clock=clock,
        reply_timeout_s=reply_timeout_s,
        poll_s=1000.0,
        backoff=Backoff(initial_s=0.05, maximum_s=0.2),
    )
    servo = RecordingServo(pt, clock)
    source = ScriptedSource(fake, clock, latency_s=latency_s, stale_every=stale_every)
    state = RelayState()
    bus: Bus[Event, Action] = Bus()
    monitor = RssiMonitor(source, SAMPLE_HZ, bus, clock)
    brain = Brain(
        BrainParams(
            estimator=EstimatorParams(),
            scan=ScanParams(
                scan_channel=SCAN,
                link_channel=LINK,
                samples=SAMPLES,
                width_deg=WIDTH_DEG,
                limits_deg=LIMITS,
                lost_rssi_dbm=-85.0,
            ),
        )
    )

    def servo_changed() -> None:
        ok = scanner.servo_ok
        bus.publish(DeviceEvent(clock.now(), PANTILT, DeviceStatus.UP if ok else DeviceStatus.DOWN))

    scanner = Scanner(
        pantilt=servo,
        monitor=monitor,
        bus=bus,
        clock=clock,
        scan_channel=SCAN,
        link_channel=LINK,
        limits_deg=LIMITS,
        speed_deg_s=SPEED_DEG_S,
        settle_s=SETTLE_S,
        mode=mode,
        on_servo_change=servo_changed,
    )
    b = Bench(
        clock,
        fake,
        pt,
        servo,
        source,
        monitor,
        state,
        scanner,
        brain,
        bus,
        StateWriter(state, link_channel=LINK),
    )
    bus.connect(brain.handle, b.on_actions)
    b.turn_to(0.0)
    tasks = [asyncio.create_task(pt.run()), asyncio.create_task(monitor.run())]
    try:
        await until(lambda: pt.connected and monitor.last_fresh_t is not None)
        yield b
    finally:
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        await pt.close()
        fake.close()


def travel_s(prev: float | None, target: float) -> float:
    """The scanner's own travel estimate: full range for the first move."""
    if prev is None:
        return (LIMITS[1] - LIMITS[0]) / SPEED_DEG_S
    return abs(target - prev) / SPEED_DEG_S


@pytest.mark.virtual_time
async def test_step_mode_pairs_each_angle_with_the_first_fresh_sample_after_arrival(
    tmp_path: Path,
) -> None:
    async with bench(tmp_path, stale_every=4) as b:
        await b.prepare()
        prev: float | None = None
        for _ in range(2):
            mark = len(b.servo.commands)
            est = await b.scan_once()
            assert est is not None
            cmds = b.servo.scan_commands(mark)
            assert len(cmds) == SAMPLES == len(est.rssi_dbm)
            readings = sorted(b.source.log.values(), key=lambda r: r.t)
            for (t_cmd, angle), rssi in zip(cmds, est.rssi_dbm, strict=True):
                assert rssi != ScriptedSource.POISON_DBM  # a stale read is never used
                used = b.source.used(rssi)
                ready = t_cmd + travel_s(prev, angle) + SETTLE_S
                # Taken after arrival + settle: the servo really pointed at the angle.
                assert used.t >= ready - 1e-9
                assert used.servo_deg == pytest.approx(angle, abs=0.3)
                # ...and the first such reading: the one before it predates `ready`
                # (20 ms of slack: the scanner stamps its command a moment after we do).
                i = readings.index(used)
                assert i > 0 and readings[i - 1].t < ready + 0.02
                prev = angle
            # Readings taken while the servo was still slewing exist, and were skipped.
            assert any(abs(r.servo_deg - a) > 2.0 for r in readings for _, a in cmds)
            # The link antenna is commanded to the new bearing.
            assert b.state.link_bearing_deg == pytest.approx(est.bearing_deg)
            bearing = est.bearing_deg
            await until(lambda: abs(pulse_to_deg(b.fake.position_us(LINK)) - bearing) < 0.3)  # noqa: B023


@pytest.mark.virtual_time
async def test_sweeps_alternate_direction(tmp_path: Path) -> None:
    async with bench(tmp_path) as b:
        await b.prepare()
        directions = []
        for _ in range(3):
            mark = len(b.servo.commands)
            assert await b.scan_once() is not None
            angles = [a for _, a in b.servo.scan_commands(mark)]
            assert angles in (sorted(angles), sorted(angles, reverse=True))
            directions.append(angles[-1] > angles[0])
        assert directions == [True, False, True]


@pytest.mark.virtual_time
async def test_window_centred_on_previous_bearing_corrected_for_the_turn(tmp_path: Path) -> None:
    async with bench(tmp_path) as b:
        b.source.leader_deg = 25.0
        await b.prepare()
        mark = len(b.servo.commands)
        est1 = await b.scan_once()
        assert est1 is not None
        first = [a for _, a in b.servo.scan_commands(mark)]
        # No bearing yet: the configured width centred straight ahead.
        assert (min(first), max(first)) == pytest.approx((-WIDTH_DEG / 2, WIDTH_DEG / 2))
        # Pulled towards the leader (the WCA of one 60-degree window is biased to its centre).
        assert 0.0 < est1.bearing_deg < 25.0
        # The robot turned 10 degrees left since: the leader is 10 degrees further right.
        b.turn_to(10.0)
        mark = len(b.servo.commands)
        assert await b.scan_once() is not None
        second = [a for _, a in b.servo.scan_commands(mark)]
        assert sum(second) / len(second) == pytest.approx(est1.bearing_deg - 10.0, abs=1e-6)
        assert max(second) - min(second) == pytest.approx(WIDTH_DEG)


@pytest.mark.virtual_time
async def test_window_is_kept_inside_the_servo_limits(tmp_path: Path) -> None:
    async with bench(tmp_path) as b:
        b.source.leader_deg = 25.0
        await b.prepare()
        est1 = await b.scan_once()
        assert est1 is not None
        # Turned 80 degrees right: the window's centre is past 60, its edge past the limit.
        b.turn_to(-80.0)
        mark = len(b.servo.commands)
        assert await b.scan_once() is not None
        angles = [a for _, a in b.servo.scan_commands(mark)]
        assert est1.bearing_deg + 80.0 + WIDTH_DEG / 2 > LIMITS[1]
        assert all(LIMITS[0] <= a <= LIMITS[1] for a in angles)
        assert max(angles) == pytest.approx(LIMITS[1])
        assert max(angles) - min(angles) == pytest.approx(WIDTH_DEG)  # shifted, not narrowed
        assert b.pt.counters["clamped"] == 0  # never asked the driver for an angle it must clamp


@pytest.mark.virtual_time
async def test_full_range_while_the_leader_is_lost(tmp_path: Path) -> None:
    async with bench(tmp_path) as b:
        await b.prepare()
        b.source.level_dbm = -100.0  # RSSI^l below lost_rssi (-85)
        for i in range(LOST_AFTER_SCANS):
            assert not b.brain.leader_lost
            mark = len(b.servo.commands)
            assert await b.scan_once() is not None
            angles = [a for _, a in b.servo.scan_commands(mark)]
            assert max(angles) - min(angles) == pytest.approx(WIDTH_DEG), i
        assert b.brain.leader_lost
        mark = len(b.servo.commands)
        assert await b.scan_once() is not None
        angles = [a for _, a in b.servo.scan_commands(mark)]
        assert (min(angles), max(angles)) == pytest.approx(LIMITS)
        # The leader is heard again: one good scan ends "lost" and the window narrows.
        b.source.level_dbm = -50.0
        assert await b.scan_once() is not None
        assert not b.brain.leader_lost
        mark = len(b.servo.commands)
        assert await b.scan_once() is not None
        angles = [a for _, a in b.servo.scan_commands(mark)]
        assert max(angles) - min(angles) == pytest.approx(WIDTH_DEG)


@pytest.mark.virtual_time
async def test_heading_per_sample_and_bearing_in_the_frame_at_scan_end(tmp_path: Path) -> None:
    async with bench(tmp_path) as b:
        await b.prepare()
        count = [0]

        def turned(channel: int) -> None:
            # The robot turns 3 degrees left between two scan commands.
            if channel == SCAN:
                count[0] += 1
                b.turn_to(3.0 * count[0])

        b.servo.on_command = turned
        mark = len(b.servo.commands)
        est = await b.scan_once()
        assert est is not None
        cmds = [a for _, a in b.servo.scan_commands(mark)]
        end = 3.0 * SAMPLES
        assert b.brain.scans.bearing_heading_deg == end
        # Sample j was taken at heading 3(j+1); seen from the end heading it lies further right.
        expected = [a + 3.0 * (j + 1) - end for j, a in enumerate(cmds)]
        assert list(est.angles_deg) == pytest.approx(expected)


@pytest.mark.virtual_time
async def test_continuous_mode_interpolates_the_commanded_motion(tmp_path: Path) -> None:
    async with bench(tmp_path, mode="continuous") as b:
        await b.prepare()
        for _ in range(2):
            mark = len(b.servo.commands)
            est = await b.scan_once()
            assert est is not None
            cmds = b.servo.scan_commands(mark)
            assert 1 <= len(cmds) <= 2  # a repositioning move at most, then the sweep
            t0, end = cmds[-1]  # the sweep: the far end, commanded once
            # It starts where the command before it left the servo.
            start_deg = b.servo.scan_commands()[-2][1]
            duration = abs(end - start_deg) / SPEED_DEG_S
            assert duration > 0.1
            # A continuous sweep yields about one sample per period, not one per angle.
            assert len(est.rssi_dbm) >= 0.5 * duration * SAMPLE_HZ
            ts = []
            for angle, rssi in zip(est.angles_deg, est.rssi_dbm, strict=True):
                used = b.source.used(rssi)
                ts.append(used.t)
                frac = min(1.0, max(0.0, (used.t - t0) / duration))
                # Interpolated from the commanded motion (we stamp the command a moment
                # before the scanner does: 1 degree of slack)...
                assert angle == pytest.approx(start_deg + (end - start_deg) * frac, abs=1.0)
                # ...which is where the fake servo physically pointed, give or take latency.
                assert angle == pytest.approx(used.servo_deg, abs=6.0)
                assert used.t >= t0 - 0.02  # nothing from before the sweep started
            assert ts == sorted(ts)


@pytest.mark.virtual_time
async def test_continuous_mode_keeps_samples_that_arrive_late(tmp_path: Path) -> None:
    """A source stamps its reading before awaiting the device (netlink, `iw`): none may be lost."""
    async with bench(tmp_path, mode="continuous", latency_s=0.015) as b:
        await b.prepare()
        await b.scan_once()  # position the servo at the first window's end
        mark = len(b.servo.commands)
        est = await b.scan_once()
        assert est is not None
        t0, end = b.servo.scan_commands(mark)[-1]
        start_deg = b.servo.scan_commands()[-2][1]
        used = {b.source.used(r).t for r in est.rssi_dbm}
        duration = abs(end - start_deg) / SPEED_DEG_S
        # Every fresh reading taken inside the sweep (one latency short of its end, when
        # the scanner stops listening) was used.
        inside = [r.t for r in b.source.log.values() if t0 + 0.02 <= r.t <= t0 + duration - 0.05]
        assert inside
        missing = [t for t in inside if t not in used]
        assert missing == [], f"{len(missing)} of {len(inside)} readings lost"


@pytest.mark.virtual_time
async def test_scan_servo_not_answering_clears_servo_ok(tmp_path: Path) -> None:
    async with bench(tmp_path) as b:
        await b.prepare()
        assert await b.scan_once() is not None
        assert b.scanner.servo_ok
        b.fake.silent = True  # the controller's logic hangs: no replies
        with pytest.raises(ScanServoError):
            await b.scan_once()
        assert not b.scanner.servo_ok
        b.fake.silent = False
        assert await b.scan_once() is not None
        assert b.scanner.servo_ok


@pytest.mark.virtual_time
async def test_run_reports_a_silent_servo_and_recovers(tmp_path: Path) -> None:
    async with bench(tmp_path) as b:
        task = asyncio.create_task(b.scanner.run())
        try:
            await until(lambda: b.state.scan_count >= 1 and b.scanner.servo_ok)
            b.fake.silent = True
            await until(lambda: not b.scanner.servo_ok)
            count = b.state.scan_count
            b.fake.silent = False
            await until(lambda: b.scanner.servo_ok and b.state.scan_count > count)
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
