"""relayd: the on-board daemon of a directional-antenna leader-follower Wi-Fi relay robot."""

__version__ = "0.1.0"
