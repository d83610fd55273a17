"""Pan-tilt servo controllers in degrees: one interface, Maestro and SSC-32 back-ends.

`make_pantilt()` picks the back-end by name; relayd only sees `PanTilt` (angles,
slew speed, moving state, health). The fakes in `drivers.pantilt.fake` play the
controllers' side of the wire for tests and the simulator.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from drivers.pantilt.base import PanTilt
    from drivers.pantilt.calibration import ServoCalibration
    from drivers.pantilt.factory import DEFAULT_BAUD, PROTOCOLS, make_pantilt
    from drivers.pantilt.maestro import MaestroPanTilt
    from drivers.pantilt.session import PanTiltError, ReplyError
    from drivers.pantilt.ssc32 import Ssc32PanTilt

# Names load on first use (PEP 562): importing a pure record such as
# drivers.arcos.sip must not load the I/O driver, asyncio or serial with it,
# since the decision core imports those records (docs/ARCHITECTURE.md).
_WHERE: dict[str, str] = {
    "DEFAULT_BAUD": "drivers.pantilt.factory",
    "MaestroPanTilt": "drivers.pantilt.maestro",
    "PROTOCOLS": "drivers.pantilt.factory",
    "PanTilt": "drivers.pantilt.base",
    "PanTiltError": "drivers.pantilt.session",
    "ReplyError": "drivers.pantilt.session",
    "ServoCalibration": "drivers.pantilt.calibration",
    "Ssc32PanTilt": "drivers.pantilt.ssc32",
    "make_pantilt": "drivers.pantilt.factory",
}


def __getattr__(name: str) -> Any:
    try:
        module = _WHERE[name]
    except KeyError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    return getattr(importlib.import_module(module), name)


__all__ = [
    "DEFAULT_BAUD",
    "PROTOCOLS",
    "MaestroPanTilt",
    "PanTilt",
    "PanTiltError",
    "ReplyError",
    "ServoCalibration",
    "Ssc32PanTilt",
    "make_pantilt",
]
