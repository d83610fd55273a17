"""What /status and the live page show of recovery: a read-only view of its memory."""

from __future__ import annotations

import math
from dataclasses import dataclass

from relayd.core.recovery.state import Kind, Phase, RecoveryMemory, RecoveryParams


@dataclass(frozen=True, slots=True)
class RecoveryView:
    """What /status and the live page show of recovery (elapsed whole seconds, distance dm)."""

    enabled: bool
    phase: Phase
    kind: Kind | None
    episodes: int
    elapsed_s: float | None
    distance_m: float | None
    max_distance_m: float
    max_time_s: float
    trail_crumbs: int
    last_outcome: str | None

    def to_json(self) -> dict[str, object]:
        """/status's `recovery` object (the enums as their strings)."""
        return {
            "enabled": self.enabled,
            "phase": str(self.phase),
            "kind": None if self.kind is None else str(self.kind),
            "episodes": self.episodes,
            "elapsed_s": self.elapsed_s,
            "distance_m": self.distance_m,
            "max_distance_m": self.max_distance_m,
            "max_time_s": self.max_time_s,
            "trail_crumbs": self.trail_crumbs,
            "last_outcome": self.last_outcome,
        }


def recovery_view(m: RecoveryMemory, p: RecoveryParams, now_s: float) -> RecoveryView:
    active = m.phase in (Phase.WIDEN, Phase.RETRACE, Phase.BACKUP) and m.started_t is not None
    elapsed = float(math.floor(now_s - m.started_t)) if active and m.started_t is not None else None
    return RecoveryView(
        p.enabled,
        m.phase,
        m.kind,
        m.episodes,
        elapsed,
        round(m.distance_m, 1) if active else None,
        p.max_distance_m,
        p.max_time_s,
        len(m.trail),
        m.last_outcome,
    )
