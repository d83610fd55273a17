"""A relay's brain in a small kinematic world, on virtual time: the estimator benches' test rig.

`BrainRig` feeds `relayd.core.brain.Brain` the events its shells would, at the times they
would: a SIP every 0.1 s (pose from the wheel commands through the P3-AT's
DiffConvFactor), a fresh RSSI reading every sample period, and step-mode sweeps timed
like the scanner's (servo travel at the slew rate, then `settle_s`, then the next RSSI
sample). RSSI comes from `relayd.sim.radio` (path loss, shadowing, Rician/Rayleigh
fading) with any antenna pattern. Nothing here reads a clock: a run is a pure
function of its settings and seed, and runs much faster than real time.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from dataclasses import dataclass, field

from drivers.arcos.sip import DIFF_CONV_FACTOR, Sip
from drivers.wifi.records import RssiSample
from relayd.config.model import Settings
from relayd.config.params import brain_params
from relayd.core.brain import PANTILT, Brain
from relayd.core.events import (
    DeviceEvent,
    DeviceStatus,
    ModeCommand,
    RssiEvent,
    ScanDone,
    ScanPlan,
    ScanReady,
    ScanResult,
    ScanSampleEvent,
    SipEvent,
    WheelCommand,
)
from relayd.core.vocab import Mode
from relayd.sim.radio import Radio, RadioParams, yagi_gain_db

Pattern = Callable[[float], float]
LeaderPath = Callable[[float], tuple[float, float]]
SIP_S = 0.1


def cos_n_pattern(beamwidth_deg: float, front_to_back_db: float) -> Pattern:
    """A cos^n power pattern with the given 3 dB beamwidth, floored at -front_to_back."""
    n = -3.0 / (10.0 * math.log10(math.cos(math.radians(beamwidth_deg / 2.0))))

    def gain(off_deg: float) -> float:
        a = abs(math.remainder(off_deg, 360.0))
        c = math.cos(math.radians(a)) if a < 90.0 else 0.0
        return -front_to_back_db if c <= 0.0 else max(-front_to_back_db, 10.0 * n * math.log10(c))

    return gain


def gaussian_pattern(beamwidth_deg: float, front_to_back_db: float) -> Pattern:
    """A Gaussian beam: -12 (off / beamwidth)^2 dB, floored (the 3GPP sector model)."""
    return lambda off: max(
        -front_to_back_db, -12.0 * (math.remainder(off, 360.0) / beamwidth_deg) ** 2
    )


def sim_yagi(off_deg: float) -> float:
    """The simulator's Yagi (cos^2, 90 deg between the 3 dB points, -20 dB floor)."""
    return yagi_gain_db(off_deg)


def still(x_m: float, y_m: float) -> LeaderPath:
    return lambda t: (x_m, y_m)


def crossing(
    distance_m: float, speed_m_s: float, start_y_m: float, wait_s: float = 0.0
) -> LeaderPath:
    """A straight run across the relay's front, `distance_m` ahead, from y = start_y upward
    (after standing there for `wait_s`)."""
    return lambda t: (distance_m, start_y_m + speed_m_s * max(0.0, t - wait_s))


@dataclass
class BrainRig:
    """One relay at the origin facing +x; its leader on `leader(t)`."""

    scan: dict[str, object]
    leader: LeaderPath
    pattern: Pattern = sim_yagi
    radio: Radio = field(
        default_factory=lambda: Radio(RadioParams.outdoor(fading=False, shadow_sigma_db=0.0), [])
    )
    mode: Mode = Mode.HOLD
    control: dict[str, object] = field(default_factory=dict)
    sample_hz: float = 20.0
    servo_deg_s: float = 180.0
    t: float = 0.0
    x_m: float = 0.0
    y_m: float = 0.0
    theta_deg: float = 0.0
    results: list[tuple[float, ScanResult]] = field(default_factory=list)
    wheels: tuple[float, float] = (0.0, 0.0)
    #: Real adapters report whole dBm that wander: with `jitter_db` > 0 each reading gets a
    #: uniform +-jitter_db (seeded by `jitter_seed`) and is rounded to a whole dB.
    jitter_db: float = 0.0
    jitter_seed: int = 0

    def __post_init__(self) -> None:
        control = {"rear_link": "ignore", "mode": str(self.mode), **self.control}
        self.settings = Settings.model_validate(
            {
                "scan": self.scan,
                "control": control,
                "wifi": {"sample_hz": self.sample_hz},
                "pantilt": {"speed_deg_s": self.servo_deg_s},
            }
        )
        self.brain = Brain(brain_params(self.settings), mode=self.mode)
        self._plan: list[float] = []
        self._next_sample_t = math.inf
        self._scan_start = 0.0
        self._servo = 0.0
        self._jitter = random.Random(self.jitter_seed)

    # -- the world ---------------------------------------------------------------------

    def true_bearing_deg(self) -> float:
        lx, ly = self.leader(self.t)
        return math.remainder(
            math.degrees(math.atan2(ly - self.y_m, lx - self.x_m)) - self.theta_deg, 360.0
        )

    def gap_m(self) -> float:
        lx, ly = self.leader(self.t)
        return math.hypot(lx - self.x_m, ly - self.y_m)

    def rssi_dbm(self, servo_deg: float) -> float:
        off = self.true_bearing_deg() - servo_deg
        rssi = self.radio.sample_dbm((self.x_m, self.y_m), self.leader(self.t), self.pattern(off))
        if self.jitter_db > 0.0:
            return float(round(rssi + self._jitter.uniform(-self.jitter_db, self.jitter_db)))
        return rssi

    def _feed(self, event: object) -> None:
        for a in self.brain.handle(event):  # type: ignore[arg-type]
            if isinstance(a, WheelCommand):
                self.wheels = (a.left_mm_s, a.right_mm_s)
            elif isinstance(a, ScanPlan):
                self._start_sweep(a.angles_deg)
            elif isinstance(a, ScanResult):
                self.results.append((self.t, a))

    def _start_sweep(self, angles: tuple[float, ...]) -> None:
        self._plan = list(angles)
        self._scan_start = self.t
        self._schedule()

    def _schedule(self) -> None:
        if not self._plan:
            self._next_sample_t = math.inf
            return
        travel = abs(self._plan[0] - self._servo) / self.servo_deg_s
        ready = self.t + travel + float(self.settings.scan.settle_s)
        period = 1.0 / self.sample_hz
        self._next_sample_t = math.ceil(ready / period - 1e-9) * period  # the next RSSI read

    def _move(self, dt: float) -> None:
        left, right = self.wheels
        v = (left + right) / 2.0 / 1000.0
        w = math.degrees((right - left) / 2.0 * DIFF_CONV_FACTOR)
        self.theta_deg = math.remainder(self.theta_deg + w * dt, 360.0)
        self.x_m += v * dt * math.cos(math.radians(self.theta_deg))
        self.y_m += v * dt * math.sin(math.radians(self.theta_deg))

    def _sip(self) -> None:
        s = Sip(
            t=self.t,
            x_mm=self.x_m * 1000.0,
            y_mm=self.y_m * 1000.0,
            theta_deg=self.theta_deg,
            left_mm_s=self.wheels[0],
            right_mm_s=self.wheels[1],
            battery_v=13.0,
            motors_enabled=True,
            estop=False,
            stall_left=False,
            stall_right=False,
            moving=False,
            sonar=(),
        )
        self._feed(SipEvent(self.t, s, (5000,) * 16))

    # -- running -----------------------------------------------------------------------

    def start(self) -> None:
        self._sip()
        self._feed(DeviceEvent(self.t, PANTILT, DeviceStatus.UP))
        self._feed(ModeCommand(self.t, self.mode))
        self._feed(ScanReady(self.t))

    def run_until(self, end_t: float, on_step: Callable[[BrainRig], None] | None = None) -> None:
        """Advance in RSSI sample periods to `end_t`, SIPs every 0.1 s, sweeps as planned."""
        period = 1.0 / self.sample_hz
        next_sip = self.t + SIP_S
        while self.t < end_t - 1e-9:
            self.t = round(self.t + period, 9)
            self._move(period)
            if self.t >= next_sip - 1e-9:
                next_sip += SIP_S
                self._sip()
                if on_step is not None:
                    on_step(self)
            self._feed(RssiEvent(self.t, RssiSample(self.t, -50.0, True)))
            if self.t >= self._next_sample_t - 1e-9 and self._plan:
                angle = self._plan.pop(0)
                self._servo = angle
                self._feed(ScanSampleEvent(self.t, angle, self.rssi_dbm(angle)))
                if self._plan:
                    self._schedule()
                else:
                    self._next_sample_t = math.inf
                    self._feed(ScanDone(self.t, self._scan_start, 0))
                    self._feed(ScanReady(self.t))

    def run_scans(self, scans: int, limit_s: float = 600.0) -> None:
        """Run until `scans` more sweeps have finished (or `limit_s` of virtual time)."""
        target = len(self.results) + scans
        while len(self.results) < target and self.t < limit_s:
            self.run_until(self.t + SIP_S)

    def bearing_now(self) -> float | None:
        """The bearing the controller steers by right now (robot frame)."""
        return self.brain.inputs(self.t).bearing_deg
