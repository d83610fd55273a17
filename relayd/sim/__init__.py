"""The simulated world in which real relayd daemons drive fake devices (docs/SIMULATOR.md).

geometry (segments, rays, collisions), radio (path loss, walls, shadowing, fading,
antenna patterns, 802.11g rates), scenario (TOML format and validation), world (the
leader script, relay bodies, sonar, the radio chain), runner (fakes + daemons + world,
trace and summary), plots (matplotlib, optional), progress (terminal line).
"""
