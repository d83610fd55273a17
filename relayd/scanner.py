"""The scan task: sweep the Yagi on servo 1, pair angles with RSSI, point servo 2.

This is the I/O around the pure estimator. `RssiMonitor` samples the Wi-Fi source at
`sample_hz` into a short history (so freshness is known even between scans, and a
continuous sweep can interpolate angles at sample times). `Scanner` runs sweeps:

- step mode: command an angle, wait the servo's travel time at the configured slew
  rate plus `settle_s`, then take the first fresh sample taken after that instant;
- continuous mode: command the far end of the window once at the slew rate and
  interpolate each fresh sample's angle from the commanded motion.

Sweeps alternate direction, so no time is spent slewing back. Every sample carries
the robot's odometry heading, and the estimate is expressed in the robot frame at the
scan's end. The window is centred on the previous bearing (corrected for the turn
since), or spans the whole servo range while the leader is lost.
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

from drivers.clock import REAL_CLOCK, Clock
from relayd.estimator import (
    LOST_AFTER_SCANS,
    EstimatorParams,
    ScanEstimate,
    ScanSample,
    estimate_scan,
    front_readings,
    plan_scan,
    update_lost_count,
)
from relayd.state import RelayState, ScanRecord

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


class RssiReading(Protocol):
    @property
    def t(self) -> float: ...
    @property
    def rssi_dbm(self) -> float | None: ...
    @property
    def fresh(self) -> bool: ...


class RssiReader(Protocol):
    """What the monitor needs of an RSSI source (drivers.wifi sources)."""

    async def read(self) -> RssiReading: ...


@dataclass(frozen=True, slots=True)
class TimedRssi:
    t: float
    rssi_dbm: float


class RssiMonitor:
    """Samples an RSSI source continuously; keeps the fresh samples of the last few seconds."""

    def __init__(self, source: RssiReader, sample_hz: float, state: RelayState, clock: Clock = REAL_CLOCK,
                 history_s: float = 10.0) -> None:
        self._source = source
        self._period_s = 1.0 / sample_hz
        self._state = state
        self._clock = clock
        self._samples: deque[TimedRssi] = deque(maxlen=max(16, int(history_s * sample_hz)))
        self._arrived = asyncio.Event()
        self.last_fresh_t: float | None = None

    @property
    def period_s(self) -> float:
        return self._period_s

    async def run(self) -> None:
        health = self._state.device("wifi")
        next_t = self._clock.now()
        while True:
            sample = await self._source.read()
            health.connected = bool(getattr(self._source, "available", True))
            health.errors = int(getattr(self._source, "errors", 0)) + int(getattr(self._source, "rejected", 0))
            health.last_error = getattr(self._source, "last_error", None)
            if sample.fresh and sample.rssi_dbm is not None:
                self._add(TimedRssi(sample.t, float(sample.rssi_dbm)))
                health.last_data_t = sample.t
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

    def add_sample(self, t: float, rssi_dbm: float) -> None:
        """Feed a sample directly (tests, or a push-style source)."""
        self._add(TimedRssi(t, rssi_dbm))

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
    """The scan servo did not answer; the controller stops the wheels."""


def scan_period_nominal_s(width_deg: float, speed_deg_s: float, samples: int, settle_s: float,
                          sample_hz: float, mode: str) -> float:
    """A sweep's expected duration, used for the 'no fresh RSSI for 2 scan periods' fail-safe."""
    slew = width_deg / speed_deg_s
    if mode == "continuous":
        return slew + 1.0 / sample_hz
    return slew + samples * (settle_s + 1.0 / sample_hz)


class Scanner:
    """Runs sweeps forever and publishes each estimate."""

    def __init__(
        self,
        *,
        pantilt: ServoController,
        monitor: RssiMonitor,
        state: RelayState,
        clock: Clock,
        scan_channel: int,
        link_channel: int,
        samples: int,
        width_deg: float,
        limits_deg: tuple[float, float],
        speed_deg_s: float,
        settle_s: float,
        mode: str,
        params: EstimatorParams,
        lost_rssi_dbm: float,
        heading_deg: Callable[[], float | None],
        sonar_mm: Callable[[], Sequence[int | None]],
        on_scan: Callable[[ScanEstimate, float], None] | None = None,
    ) -> None:
        self._pt = pantilt
        self._monitor = monitor
        self._state = state
        self._clock = clock
        self._scan_ch = scan_channel
        self._link_ch = link_channel
        self._samples = samples
        self._width = width_deg
        self._limits = limits_deg
        self._speed = speed_deg_s
        self._settle = settle_s
        self._mode = mode
        self._params = params
        self._lost_rssi = lost_rssi_dbm
        self._heading = heading_deg
        self._sonar = sonar_mm
        self._on_scan = on_scan
        self._ascending = True
        self._angle: float | None = None  # last commanded scan angle
        #: The controller answered the scanner's latest request; a write alone never sets it.
        self._answered = False
        self.lost_count = 0
        self.bearing_deg: float | None = None
        self.bearing_heading_deg: float | None = None
        self.prev_bearing_deg: float | None = None
        self.prev_heading_deg: float | None = None
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

    @property
    def leader_lost(self) -> bool:
        return self.lost_count >= LOST_AFTER_SCANS

    def _center(self) -> tuple[float, float]:
        """Centre and width of the next window: previous bearing, or the full range when lost."""
        if self.leader_lost or self.bearing_deg is None:
            lo, hi = self._limits
            if self.leader_lost:
                return (lo + hi) / 2.0, hi - lo
            return 0.0, self._width
        heading = self._heading()
        turned = 0.0
        if heading is not None and self.bearing_heading_deg is not None:
            turned = heading - self.bearing_heading_deg
        return self.bearing_deg - turned, self._width

    async def _servo(self, coro: Awaitable[T], *, answered: bool = False) -> T:
        """Run one servo operation; `answered`: it is a request the controller replied to."""
        try:
            result = await coro
        except Exception as exc:
            self._answered = False
            self._state.device("pantilt").last_error = f"{type(exc).__name__}: {exc}"
            raise ScanServoError(str(exc)) from exc
        if answered:
            self._answered = True
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
                self._answered = False
                await self._clock.sleep(0.1)
                continue
            try:
                await self.prepare()
                while True:
                    await self.scan_once()
            except ScanServoError as exc:
                log.warning("scan_servo_error", error=str(exc))
                await self._clock.sleep(0.2)

    async def scan_once(self) -> ScanEstimate | None:
        center, width = self._center()
        angles = plan_scan(center, width, self._samples, self._limits, self._ascending)
        self._ascending = not self._ascending
        t_start = self._clock.now()
        if self._mode == "continuous":
            samples = await self._sweep_continuous(angles)
        else:
            samples = await self._sweep_steps(angles)
        if len(samples) < 3:
            log.warning("scan_too_few_samples", samples=len(samples))
            return None
        heading_end = self._heading()
        estimate = estimate_scan(
            samples,
            heading_end if heading_end is not None else samples[-1].heading_deg,
            front_readings(self._sonar()),
            self._params,
        )
        now = self._clock.now()
        self.last_period_s = now - t_start
        self.prev_bearing_deg, self.prev_heading_deg = self.bearing_deg, self.bearing_heading_deg
        self.bearing_deg = estimate.bearing_deg
        self.bearing_heading_deg = heading_end
        self.lost_count = update_lost_count(self.lost_count, estimate.rssi_leader_dbm, self._lost_rssi)
        self._publish(estimate, now)
        # Point the data-link antenna at the leader; a failure here is the link servo's,
        # not the scan's, so it is logged and the scan goes on.
        try:
            commanded = await self._pt.set_angle(self._link_ch, estimate.bearing_deg)
            self._state.link_bearing_deg = float(commanded)
        except Exception as exc:  # noqa: BLE001 - the link servo failing must not end scanning
            self._state.device("pantilt").errors += 1
            log.warning("link_servo_error", error=str(exc))
        return estimate

    def _publish(self, est: ScanEstimate, now: float) -> None:
        st = self._state
        st.last_scan = ScanRecord(
            t=now,
            angles_deg=tuple(round(a, 2) for a in est.angles_deg),
            rssi_dbm=tuple(round(r, 2) for r in est.rssi_dbm),
            bearing_deg=round(est.bearing_deg, 3),
            rssi_leader_dbm=est.rssi_leader_dbm,
            situation=est.situation,
            period_s=self.last_period_s,
        )
        st.scan_count += 1
        st.bearing_deg = est.bearing_deg
        st.rssi_leader_dbm = est.rssi_leader_dbm
        st.touch()
        if self._on_scan is not None:
            self._on_scan(est, now)

    def _travel_s(self, target: float) -> float:
        if self._angle is None:
            # Unknown start position: allow a full-range move once.
            return (self._limits[1] - self._limits[0]) / self._speed
        return abs(target - self._angle) / self._speed

    async def _sweep_steps(self, angles: Sequence[float]) -> list[ScanSample]:
        samples: list[ScanSample] = []
        wait_s = 4.0 * self._monitor.period_s + 0.2
        for target in angles:
            commanded = float(await self._servo(self._pt.set_angle(self._scan_ch, target)))
            t_cmd = self._clock.now()
            ready_t = t_cmd + self._travel_s(commanded) + self._settle
            self._angle = commanded
            sample = await self._monitor.first_after(ready_t, (ready_t - t_cmd) + wait_s)
            if sample is None:
                continue  # no fresh RSSI: the controller's freshness fail-safe handles it
            samples.append(ScanSample(commanded, sample.rssi_dbm, self._heading_or(samples)))
        # The servo really answered during this sweep? A position read proves it.
        await self._servo(self._pt.get_angle(self._scan_ch), answered=True)
        return samples

    async def _sweep_continuous(self, angles: Sequence[float]) -> list[ScanSample]:
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
        samples: list[ScanSample] = []
        last_t = -math.inf
        done = False
        while True:
            now = self._clock.now()
            for s in self._monitor.between(t0, math.inf):
                if s.t <= last_t:
                    continue
                frac = 1.0 if duration <= 0 else min(1.0, max(0.0, (s.t - t0) / duration))
                samples.append(ScanSample(start + (commanded_end - start) * frac, s.rssi_dbm,
                                          self._heading_or(samples)))
                last_t = s.t
                if s.t >= end_t:
                    done = True
                    break
            if done or now >= deadline:
                break
            await self._clock.sleep(self._monitor.period_s)
        self._angle = commanded_end
        await self._servo(self._pt.get_angle(self._scan_ch), answered=True)
        return samples

    def _heading_or(self, samples: list[ScanSample]) -> float:
        h = self._heading()
        if h is not None:
            return h
        return samples[-1].heading_deg if samples else 0.0
