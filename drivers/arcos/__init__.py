"""Pioneer P3-AT over ARCOS: codec, SIP decoding, sonar ring, ArcosRobot driver, FakeRobot."""

from drivers.arcos.codec import Command, Decoder, Packet, PacketType, encode_command
from drivers.arcos.driver import ArcosError, ArcosRobot, HandshakeError, SessionLost
from drivers.arcos.fake import FakeRobot
from drivers.arcos.sip import RawSip, RobotConfig, RobotIdentity, Sip, conv_factors
from drivers.arcos.sonar import SONAR_POSES, SonarPoint, SonarPose, SonarRing

__all__ = [
    "SONAR_POSES",
    "ArcosError",
    "ArcosRobot",
    "Command",
    "Decoder",
    "FakeRobot",
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
