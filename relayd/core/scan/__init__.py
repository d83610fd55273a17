"""Finding the leader: scan planning and memory, the adaptive window, the bearing fits, the tracking filter, the leader model."""
