"""Planning round obstacles: the sonar map, A* on it, and when to detour."""
