"""The sonar escape: its state table, its per-mode state and the ring's geometry as the escape sees it."""
