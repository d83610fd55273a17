"""The pan-tilt interface in degrees, on top of the controller's serial session.

Angles map to pulse widths through each servo's `ServoCalibration` (calibration.py);
`PanTilt` clamps them to the servo's limits, remembers each servo's slew speed and
re-sends it on every reconnect. The one serial port both servos share, its lock,
reply waiters, silence -> disconnect, reconnect and health, is `ServoSession`
(session.py). The back-ends (`maestro.py`, `ssc32.py`) only say how to encode a
command and how long each reply is.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping

from drivers.pantilt.calibration import ServoCalibration, check_angle, check_speed
from drivers.pantilt.session import PanTiltError, ServoSession
from drivers.transport.backoff import Backoff
from drivers.transport.clock import REAL_CLOCK, Clock

__all__ = ["PanTilt", "ServoCalibration", "check_angle", "check_speed"]


class PanTilt(ServoSession):
    """Two (or more) hobby servos on one serial servo controller, addressed in degrees.

    Call `run()` as a long-lived task (it connects, polls the controller for health,
    and reconnects with backoff), or `connect()` once for a one-shot tool. Commands
    raise `PanTiltError` when not connected or when the controller does not answer.
    """

    def __init__(
        self,
        url: str,
        baud: int,
        calibrations: Mapping[int, ServoCalibration],
        *,
        clock: Clock = REAL_CLOCK,
        reply_timeout_s: float = 0.25,
        max_timeouts: int = 3,
        poll_s: float = 1.0,
        backoff: Backoff | None = None,
    ) -> None:
        if not calibrations:
            raise ValueError("at least one servo channel needs a calibration")
        self._cal: dict[int, ServoCalibration] = dict(calibrations)
        for channel, cal in self._cal.items():
            self._check_channel_range(channel, cal)
        super().__init__(
            url,
            baud,
            clock=clock,
            reply_timeout_s=reply_timeout_s,
            max_timeouts=max_timeouts,
            poll_s=poll_s,
            backoff=backoff,
        )
        self._speed_deg_s: dict[int, float] = {}

    # ---- back-end hooks ---------------------------------------------------------------

    @abc.abstractmethod
    def _check_channel_range(self, channel: int, cal: ServoCalibration) -> None:
        """Raise ValueError if the controller cannot address `channel` or reach its pulses."""

    @abc.abstractmethod
    async def _send_target(self, channel: int, pulse_us: float) -> None: ...

    @abc.abstractmethod
    async def _send_speed(self, channel: int, us_per_s: float) -> None: ...

    @abc.abstractmethod
    async def _read_pulse_us(self, channel: int) -> float: ...

    @abc.abstractmethod
    async def _read_moving(self) -> bool: ...

    async def _on_connected(self) -> None:
        """Prove the controller answers and restore per-connection settings."""
        await self._read_moving()
        for channel, deg_s in self._speed_deg_s.items():
            await self._send_speed(channel, deg_s * self._cal[channel].us_per_deg)

    async def _poll(self) -> None:
        """Periodic health check while connected (a silent controller is dropped)."""
        await self._read_moving()

    # ---- public API ------------------------------------------------------------------

    @property
    def channels(self) -> tuple[int, ...]:
        return tuple(sorted(self._cal))

    def calibration(self, channel: int) -> ServoCalibration:
        try:
            return self._cal[channel]
        except KeyError:
            raise PanTiltError(
                f"servo channel {channel} is not configured (configured: {self.channels})"
            ) from None

    def limits(self, channel: int) -> tuple[float, float]:
        lo, hi = self.calibration(channel).limits_deg
        return (lo, hi)

    def speed_deg_s(self, channel: int) -> float:
        """The slew speed last asked for (0 = unlimited)."""
        self.calibration(channel)
        return self._speed_deg_s.get(channel, 0.0)

    async def set_angle(self, channel: int, angle_deg: float) -> float:
        """Command `channel` to `angle_deg`; returns the (clamped) angle actually commanded."""
        cal = self.calibration(channel)
        wanted = check_angle(angle_deg)
        angle = cal.clamp(wanted)
        if angle != wanted:
            self.counters["clamped"] += 1
            self._log.warning(
                "angle_clamped",
                channel=channel,
                asked_deg=wanted,
                commanded_deg=angle,
                limits_deg=cal.limits_deg,
            )
        await self._send_target(channel, cal.angle_to_pulse_us(angle))
        return angle

    async def set_speed(self, channel: int, deg_s: float) -> None:
        """Limit the slew of `channel` to `deg_s` (0 = unlimited).

        Remembered and re-sent on every (re)connect, so it may be called before `run()`
        has connected; when connected it is sent at once.
        """
        cal = self.calibration(channel)
        speed = check_speed(deg_s)
        self._speed_deg_s[channel] = speed
        if self.connected:
            await self._send_speed(channel, speed * cal.us_per_deg)

    async def get_angle(self, channel: int) -> float:
        """The angle the controller is currently driving `channel` to (read back, not assumed)."""
        cal = self.calibration(channel)
        pulse = await self._read_pulse_us(channel)
        if pulse <= 0:
            raise PanTiltError(f"servo channel {channel} is not being driven (no pulses)")
        return cal.pulse_us_to_angle(pulse)

    async def is_moving(self) -> bool:
        """True while any servo of the controller is still slewing to its target."""
        return await self._read_moving()

    async def wait_stopped(self, timeout_s: float, poll_s: float = 0.02) -> bool:
        """Poll until no servo moves; False if still moving after `timeout_s` clock seconds."""
        deadline = self._clock.now() + timeout_s
        while await self._read_moving():
            if self._clock.now() >= deadline:
                return False
            await self._clock.sleep(poll_s)
        return True
