"""The scan shell: sweep the Yagi on servo 1 as the brain plans, pair angles with RSSI.

This is the I/O around the brain's scan logic (`relayd.core.scan.memory`: bearing memory,
plan, estimate, leader-lost). `RssiMonitor` samples the Wi-Fi source at `sample_hz`,
publishes every read as an `RssiEvent` (the brain judges freshness on that stream)
and keeps a short history, so a sweep can pair samples with servo angles.
`Scanner` executes the brain's `ScanPlan`s:

- step mode: command an angle, wait the servo's travel time at the configured slew
  rate plus `settle_s`, then take the first fresh sample taken after that instant;
- continuous mode: command the far end of the window once at the slew rate and
  interpolate each fresh sample's angle from the commanded motion.

Before each sweep the scanner publishes `ScanReady` and the brain answers with the
plan; each paired sample is published as a `ScanSampleEvent`, the sweep's end as
`ScanDone`, and the brain answers with the estimate and a `ServoTarget` for the link
antenna (carried out here before the next sweep).
"""

from __future__ import annotations

import asyncio
import bisect
import math
from collections import deque
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar

import structlog

from drivers.transport.clock import REAL_CLOCK, Clock
from drivers.wifi.records import RssiSample
from relayd.core.events import (
    Event,
    RssiEvent,
    ScanDone,
    ScanPlan,
    ScanReady,
    ScanSampleEvent,
    ServoPosition,
    ServoTarget,
)

log = structlog.get_logger(__name__)

T = TypeVar("T")


class ServoController(Protocol):
    """What the scanner needs of a pan-tilt driver (drivers.pantilt.PanTilt, or a test double)."""

    @property
    def connected(self) -> bool: ...
    @property
    def answering(self) -> bool: ...
    async def set_angle(self, channel: int, angle_deg: float) -> float: ...
    async def set_speed(self, channel: int, deg_s: float) -> None: ...
    async def get_angle(self, channel: int) -> float: ...
    async def is_moving(self) -> bool: ...


class RssiReader(Protocol):
    """What the monitor needs of an RSSI source (drivers.wifi sources)."""

    async def read(self) -> RssiSample: ...


class Publisher(Protocol):
    def publish(self, event: Event) -> None: ...


@dataclass(frozen=True, slots=True)
class TimedRssi:
    t: float
    rssi_dbm: float


class RssiMonitor:
    """Samples an RSSI source continuously; keeps the fresh samples of the last few seconds."""

    def __init__(
        self,
        source: RssiReader,
        sample_hz: float,
        bus: Publisher | None = None,
        clock: Clock = REAL_CLOCK,
        history_s: float = 10.0,
    ) -> None:
        self._source = source
        self._period_s = 1.0 / sample_hz
        self._bus = bus
        self._clock = clock
        self._samples: deque[TimedRssi] = deque(maxlen=max(16, int(history_s * sample_hz)))
        self._arrived = asyncio.Event()
        self.last_fresh_t: float | None = None

    @property
    def period_s(self) -> float:
        return self._period_s

    async def run(self) -> None:
        next_t = self._clock.now()
        while True:
            sample = await self._source.read()
            if sample.fresh and sample.rssi_dbm is not None:
                self._add(TimedRssi(sample.t, float(sample.rssi_dbm)))
            if self._bus is not None:
                self._bus.publish(RssiEvent(self._clock.now(), sample))
            next_t += self._period_s
            now = self._clock.now()
            if next_t < now - self._period_s:
                next_t = now  # fell behind (a slow read): do not burst to catch up
            await self._clock.sleep(next_t - now)

    def _add(self, s: TimedRssi) -> None:
        self._samples.append(s)
        self.last_fresh_t = s.t
        self._arrived.set()
        self._arrived = asyncio.Event()

    def age_s(self, now: float) -> float | None:
        return None if self.last_fresh_t is None else now - self.last_fresh_t

    async def first_after(self, t: float, timeout_s: float) -> TimedRssi | None:
        """The first fresh sample taken at or after clock time `t`; None on timeout."""
        try:
            async with self._clock.timeout(timeout_s):
                while True:
                    # Newest samples are at the right: scan back to the first one at or after t.
                    found = None
                    for s in reversed(self._samples):
                        if s.t < t:
                            break
                        found = s
                    if found is not None:
                        return found
                    await self._arrived.wait()
        except TimeoutError:
            return None

    def between(self, t0: float, t1: float) -> list[TimedRssi]:
        times = [s.t for s in self._samples]
        lo = bisect.bisect_left(times, t0)
        hi = bisect.bisect_right(times, t1)
        return list(self._samples)[lo:hi]


class ScanServoError(RuntimeError):
    """The scan servo did not answer; the brain stops the wheels."""


class Scanner:
    """Runs the brain's sweep plans forever; publishes samples and sweep ends."""

    def __init__(
        self,
        *,
        pantilt: ServoController,
        monitor: RssiMonitor,
        bus: Publisher,
        clock: Clock,
        scan_channel: int,
        link_channel: int,
        limits_deg: tuple[float, float],
        speed_deg_s: float,
        settle_s: float,
        mode: str,
        on_servo_change: Callable[[], None] | None = None,
    ) -> None:
        self._pt = pantilt
        self._monitor = monitor
        self._bus = bus
        self._clock = clock
        self._scan_ch = scan_channel
        self._link_ch = link_channel
        self._limits = limits_deg
        self._speed = speed_deg_s
        self._settle = settle_s
        self._mode = mode
        self._on_servo_change = on_servo_change
        self._angle: float | None = None  # last commanded scan angle
        #: The controller answered the scanner's latest request; a write alone never sets it.
        self._answered = False
        self._plan: ScanPlan | None = None
        self._link_target: ServoTarget | None = None
        self._wake = asyncio.Event()
        self.link_errors = 0
        self.last_period_s: float | None = None

    @property
    def servo_ok(self) -> bool:
        """The scan servo answers: our last request was answered and the driver saw no timeout since.

        Writes (set_angle, set_speed) have no reply, so they succeed on a controller whose
        logic has hung; only a read proves it alive. The driver's own state is looked at
        too, so a pulled cable or a timed-out health poll stops the wheels at the next
        control tick instead of at the end of the sweep.
        """
        return self._answered and self._pt.connected and self._pt.answering

    # -- actions in (from the brain, through the daemon) ---------------------------------

    def plan(self, plan: ScanPlan) -> None:
        self._plan = plan
        self._wake.set()

    def point_link(self, target: ServoTarget) -> None:
        self._link_target = target

    def _set_answered(self, answered: bool) -> None:
        if answered != self._answered:
            self._answered = answered
            if self._on_servo_change is not None:
                self._on_servo_change()

    async def _servo(self, coro: Awaitable[T], *, answered: bool = False) -> T:
        """Run one servo operation; `answered`: it is a request the controller replied to."""
        try:
            result = await coro
        except Exception as exc:
            self._set_answered(False)
            raise ScanServoError(f"{type(exc).__name__}: {exc}") from exc
        if answered:
            self._set_answered(True)
        return result

    async def prepare(self) -> None:
        """Set both servos' slew rate (the scan timing assumes it), then prove the controller answers."""
        await self._servo(self._pt.set_speed(self._scan_ch, self._speed))
        await self._servo(self._pt.set_speed(self._link_ch, self._speed))
        # A moving-state read answers whether or not a channel is pulsing yet (a position
        # read fails on a channel that was never driven).
        await self._servo(self._pt.is_moving(), answered=True)

    async def run(self) -> None:
        while True:
            if not self._pt.connected:
                self._set_answered(False)
                await self._clock.sleep(0.1)
                continue
            try:
                self._plan = None
                await self.prepare()
                while True:
                    plan = await self.next_plan()
                    await self.sweep(plan)
            except ScanServoError as exc:
                log.warning("scan_servo_error", error=str(exc))
                await self._clock.sleep(0.2)

    async def point_pending_link(self) -> None:
        """Carry out the brain's latest link-antenna target, if one is waiting."""
        target, self._link_target = self._link_target, None
        if target is not None:
            await self._point(target)

    def _take_plan(self) -> ScanPlan | None:
        plan, self._plan = self._plan, None
        return plan

    async def next_plan(self) -> ScanPlan:
        """Point the link antenna if asked, then ask the brain for the next sweep's plan."""
        await self.point_pending_link()
        self._plan = None
        # The brain answers synchronously when the servo counts as answering; otherwise
        # as soon as it does.
        self._bus.publish(ScanReady(self._clock.now()))
        while True:
            plan = (
                self._take_plan()
            )  # set by the brain meanwhile (a method: mypy narrows attributes)
            if plan is not None:
                return plan
            self._wake.clear()
            await self._wake.wait()

    async def _point(self, target: ServoTarget) -> None:
        # A failure here is the link servo's, not the scan's: counted, logged, scanning goes on.
        try:
            commanded = await self._pt.set_angle(target.channel, target.angle_deg)
        except Exception as exc:  # noqa: BLE001 - the link servo failing must not end scanning
            self.link_errors += 1
            log.warning("link_servo_error", error=str(exc))
            return
        self._bus.publish(ServoPosition(self._clock.now(), target.channel, float(commanded), False))

    async def sweep(self, plan: ScanPlan) -> int:
        """One sweep of `plan`; returns the number of samples published."""
        t_start = self._clock.now()
        if self._mode == "continuous":
            samples = await self._sweep_continuous(plan.angles_deg)
        else:
            samples = await self._sweep_steps(plan.angles_deg)
        now = self._clock.now()
        self.last_period_s = now - t_start
        if samples < 3:
            log.warning("scan_too_few_samples", samples=samples)
        self._bus.publish(ScanDone(now, t_start, samples))
        return samples

    def _sample(self, angle_deg: float, rssi_dbm: float) -> None:
        self._bus.publish(ScanSampleEvent(self._clock.now(), angle_deg, rssi_dbm))

    def _travel_s(self, target: float) -> float:
        if self._angle is None:
            # Unknown start position: allow a full-range move once.
            return (self._limits[1] - self._limits[0]) / self._speed
        return abs(target - self._angle) / self._speed

    async def _sweep_steps(self, angles: Sequence[float]) -> int:
        count = 0
        wait_s = 4.0 * self._monitor.period_s + 0.2
        for target in angles:
            commanded = float(await self._servo(self._pt.set_angle(self._scan_ch, target)))
            t_cmd = self._clock.now()
            ready_t = t_cmd + self._travel_s(commanded) + self._settle
            self._angle = commanded
            sample = await self._monitor.first_after(ready_t, (ready_t - t_cmd) + wait_s)
            if sample is None:
                continue  # no fresh RSSI: the brain's freshness fail-safe handles it
            self._sample(commanded, sample.rssi_dbm)
            count += 1
        # The servo really answered during this sweep? A position read proves it.
        await self._servo(self._pt.get_angle(self._scan_ch), answered=True)
        return count

    async def _sweep_continuous(self, angles: Sequence[float]) -> int:
        start, end = angles[0], angles[-1]
        if self._angle is None or abs(self._angle - start) > 0.5:
            first = float(await self._servo(self._pt.set_angle(self._scan_ch, start)))
            await self._clock.sleep(self._travel_s(first) + self._settle)
            self._angle = first
        start = self._angle
        commanded_end = float(await self._servo(self._pt.set_angle(self._scan_ch, end)))
        t0 = self._clock.now()
        duration = abs(commanded_end - start) / self._speed
        end_t = t0 + duration
        # A source stamps its reading before awaiting the device (netlink, `iw`), so a
        # sample can land after the scanner has looked past its timestamp: samples are
        # taken by "newer than the last one used", never by the time we looked. Reads
        # are sequential, so once a sample stamped at or after the sweep's end is in,
        # none from inside the sweep is still on its way; that sample (the servo at the
        # end) is the sweep's last.
        deadline = end_t + 4.0 * self._monitor.period_s + 0.2
        count = 0
        last_t = -math.inf
        done = False
        while True:
            now = self._clock.now()
            for s in self._monitor.between(t0, math.inf):
                if s.t <= last_t:
                    continue
                frac = 1.0 if duration <= 0 else min(1.0, max(0.0, (s.t - t0) / duration))
                self._sample(start + (commanded_end - start) * frac, s.rssi_dbm)
                count += 1
                last_t = s.t
                if s.t >= end_t:
                    done = True
                    break
            if done or now >= deadline:
                break
            await self._clock.sleep(self._monitor.period_s)
        self._angle = commanded_end
        await self._servo(self._pt.get_angle(self._scan_ch), answered=True)
        return count
