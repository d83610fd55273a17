"""The control law and what shapes its wheel commands: the law, the actuator, the range cue, the search turn."""
