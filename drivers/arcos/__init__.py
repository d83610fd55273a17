"""Pioneer P3-AT over ARCOS: codec, SIP decoding, sonar ring, the ArcosRobot driver.

The fake robot is `drivers.arcos.fake.FakeRobot`, not imported here: the daemon does
not load test fakes (and their pty plumbing) into its memory.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from drivers.arcos.codec import Command, Decoder, Packet, PacketType, encode_command
    from drivers.arcos.driver import ArcosError, ArcosRobot, HandshakeError, SessionLost
    from drivers.arcos.sip import RawSip, RobotConfig, RobotIdentity, Sip, conv_factors
    from drivers.arcos.sonar import SONAR_POSES, SonarPoint, SonarPose, SonarRing

# Names load on first use (PEP 562): importing a pure record such as
# drivers.arcos.sip must not load the I/O driver, asyncio or serial with it,
# since the decision core imports those records (docs/ARCHITECTURE.md).
_WHERE: dict[str, str] = {
    "ArcosError": "drivers.arcos.driver",
    "ArcosRobot": "drivers.arcos.driver",
    "Command": "drivers.arcos.codec",
    "Decoder": "drivers.arcos.codec",
    "HandshakeError": "drivers.arcos.driver",
    "Packet": "drivers.arcos.codec",
    "PacketType": "drivers.arcos.codec",
    "RawSip": "drivers.arcos.sip",
    "RobotConfig": "drivers.arcos.sip",
    "RobotIdentity": "drivers.arcos.sip",
    "SONAR_POSES": "drivers.arcos.sonar",
    "SessionLost": "drivers.arcos.driver",
    "Sip": "drivers.arcos.sip",
    "SonarPoint": "drivers.arcos.sonar",
    "SonarPose": "drivers.arcos.sonar",
    "SonarRing": "drivers.arcos.sonar",
    "conv_factors": "drivers.arcos.sip",
    "encode_command": "drivers.arcos.codec",
}


def __getattr__(name: str) -> Any:
    try:
        module = _WHERE[name]
    except KeyError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    return getattr(importlib.import_module(module), name)


__all__ = [
    "SONAR_POSES",
    "ArcosError",
    "ArcosRobot",
    "Command",
    "Decoder",
    "HandshakeError",
    "Packet",
    "PacketType",
    "RawSip",
    "RobotConfig",
    "RobotIdentity",
    "SessionLost",
    "Sip",
    "SonarPoint",
    "SonarPose",
    "SonarRing",
    "conv_factors",
    "encode_command",
]
