"""The leader's trail: where the leader is, where it went, and how to go there.

- `estimate`: the leader's position in the relay's odometry frame (an EKF over the scan
  bearing, the RSSI through the path-loss model and the sonar floor), with its covariance.
- `polyline`: the positions it passed through, thinned, with times: the trail.
- `pursuit`: pure pursuit along the trail (the steering angle the paper's law then uses).
- `keeper`: the brain's one writer of this memory.

All pure: time comes in the arguments, nothing reads a clock or does I/O.
"""
