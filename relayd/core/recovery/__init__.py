"""Self-healing: the recovery state machine and the trail it drives back along."""
