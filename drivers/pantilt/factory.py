"""The pantilt driver the config names, built by `make_pantilt`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

from drivers.pantilt.base import PanTilt
from drivers.pantilt.calibration import ServoCalibration
from drivers.pantilt.maestro import MaestroPanTilt
from drivers.pantilt.ssc32 import Ssc32PanTilt
from drivers.transport.clock import REAL_CLOCK, Clock

PROTOCOLS: dict[str, type[PanTilt]] = {"maestro": MaestroPanTilt, "ssc32": Ssc32PanTilt}
#: Baud rate when none is configured: the Maestro's USB command port ignores it; the
#: SSC-32U ships at 9600.
DEFAULT_BAUD: dict[str, int] = {"maestro": 115200, "ssc32": 9600}


def make_pantilt(
    protocol: Literal["maestro", "ssc32"] | str,
    url: str,
    baud: int | None,
    calibrations: Mapping[int, ServoCalibration],
    *,
    clock: Clock = REAL_CLOCK,
    **options: Any,
) -> PanTilt:
    """A pan-tilt driver for `protocol` on `url`; `options` go to the driver
    (reply_timeout_s, max_timeouts, poll_s)."""
    try:
        cls = PROTOCOLS[protocol]
    except KeyError:
        raise ValueError(
            f"unknown pan-tilt protocol {protocol!r}; expected one of {sorted(PROTOCOLS)}"
        ) from None
    return cls(url, baud or DEFAULT_BAUD[protocol], calibrations, clock=clock, **options)
