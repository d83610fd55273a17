"""Rate limits for log lines that someone outside the robot can trigger at will.

A wrong API token, a malformed HTTP request or a connection refused at the cap is one
packet away for anyone on the bridge; logged every time, a script fills the journal
(and the robot laptop's disk) and buries the lines that matter. `LogRateLimit` lets the
first occurrence through at once and then at most one line per period, carrying how
many occurrences it stands for, so nothing is hidden and nothing floods.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(slots=True)
class _Slot:
    last_t: float
    suppressed: int = 0


class LogRateLimit:
    """Decide per key whether an occurrence is logged; time comes from the caller."""

    def __init__(self, every_s: float = 60.0, max_keys: int = 256) -> None:
        self.every_s = every_s
        # Keys include peer addresses: bound the table so a scan of the bridge cannot grow it.
        self.max_keys = max_keys
        self._slots: dict[str, _Slot] = {}

    def hit(self, key: str, now: float) -> int | None:
        """None: stay quiet. Otherwise log now; the number of occurrences the line stands for
        (1 for the first, more when earlier ones were held back)."""
        slot = self._slots.get(key)
        if slot is None:
            if len(self._slots) >= self.max_keys:
                self._slots.pop(next(iter(self._slots)))
            self._slots[key] = _Slot(now)
            return 1
        if now - slot.last_t >= self.every_s:
            count = slot.suppressed + 1
            slot.last_t, slot.suppressed = now, 0
            return count
        slot.suppressed += 1
        return None
