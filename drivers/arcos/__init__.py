"""Pioneer P3-AT over ARCOS: codec, SIP decoding, sonar ring, the ArcosRobot driver.

The fake robot is `drivers.arcos.fake.FakeRobot`, not imported here: the daemon does
not load test fakes (and their pty plumbing) into its memory.
"""

from drivers.arcos.codec import Command, Decoder, Packet, PacketType, encode_command
from drivers.arcos.driver import ArcosError, ArcosRobot, HandshakeError, SessionLost
from drivers.arcos.sip import RawSip, RobotConfig, RobotIdentity, Sip, conv_factors
from drivers.arcos.sonar import SONAR_POSES, SonarPoint, SonarPose, SonarRing

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
