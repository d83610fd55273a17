"""Never stuck without saying so: an escape that gets no nearer the trail's head (pure).

While the obstacle escape drives (the law's AVOIDING or "rejoining" commands), the
guard watches how far along the trail the relay still has to go (`remaining_m`:
along the trail to its head, else straight to the leader's estimate). If that has not
shrunk by `progress_m` for `after_s`, the escape has given up without deciding: the
relay stops on purpose, reason "trail_blocked", for a wait that doubles each time
(`backoff_s` .. `backoff_max_s`) while the scans go on; then the escape starts afresh.
Any progress (or the escape ending by itself) resets the backoff. Time is the step's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True, slots=True)
class BlockedParams:
    after_s: float = 30.0
    progress_m: float = 0.5
    backoff_s: float = 10.0
    backoff_max_s: float = 80.0


@dataclass(frozen=True, slots=True)
class BlockedState:
    #: The least remaining distance seen in this escape, and when it was last beaten.
    best_m: float | None = None
    best_t: float | None = None
    #: Stopped on "trail_blocked" until then (None: not stopped).
    until_t: float | None = None
    #: The last wait (s); 0 before the first.
    backoff_s: float = 0.0


def waiting(st: BlockedState, t_s: float) -> bool:
    """Is the relay in a "trail_blocked" wait at t_s?"""
    return st.until_t is not None and t_s < st.until_t


def blocked_step(
    st: BlockedState, t_s: float, escaping: bool, remaining_m: float | None, p: BlockedParams
) -> tuple[BlockedState, bool]:
    """(new state, stop now on "trail_blocked")."""
    if waiting(st, t_s):
        return st, True
    if st.until_t is not None:  # the wait is over: the escape tries again from here
        st = replace(st, until_t=None, best_m=None, best_t=None)
    if not escaping or remaining_m is None:
        if not escaping and st.best_m is not None:
            # The escape ended by itself (the paper's law drives again): a clean slate.
            return BlockedState(), False
        return st, False
    if st.best_m is None or st.best_t is None:
        return replace(st, best_m=remaining_m, best_t=t_s), False
    if remaining_m < st.best_m - p.progress_m:
        return replace(st, best_m=remaining_m, best_t=t_s, backoff_s=0.0), False
    if t_s - st.best_t > p.after_s:
        wait = min(p.backoff_max_s, max(p.backoff_s, 2.0 * st.backoff_s))
        return BlockedState(until_t=t_s + wait, backoff_s=wait), True
    return st, False
