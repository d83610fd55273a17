"""LogRateLimit (relayd/runtime/ratelimit.py): nothing hidden, nothing flooding, whatever the timing."""

from __future__ import annotations

import itertools

from hypothesis import given
from hypothesis import strategies as st

from relayd.runtime.ratelimit import LogRateLimit

EVERY_S = 60.0


@given(st.lists(st.floats(min_value=0.0, max_value=600.0, allow_nan=False), max_size=300))
def test_counts_add_up_and_lines_are_spaced(gaps_s: list[float]) -> None:
    limit = LogRateLimit(EVERY_S)
    t, logged = 0.0, []
    for gap in gaps_s:
        t += gap
        count = limit.hit("k", t)
        if count is not None:
            logged.append((t, count))
    if not gaps_s:
        return
    # The first occurrence is logged at once, with count 1.
    assert logged[0][1] == 1
    # At most one line per period after it.
    assert all(b[0] - a[0] >= EVERY_S for a, b in itertools.pairwise(logged))
    # Every occurrence is counted exactly once, except those held back since the last line.
    held_back = len(gaps_s) - sum(c for _, c in logged)
    assert held_back >= 0
    assert held_back == limit.hit("k", t + 2 * EVERY_S) - 1  # the next line carries them


def test_keys_are_separate_and_the_table_is_bounded() -> None:
    limit = LogRateLimit(EVERY_S, max_keys=4)
    assert limit.hit("a", 0.0) == 1 and limit.hit("b", 0.0) == 1
    assert limit.hit("a", 1.0) is None
    for n in range(100):
        limit.hit(f"peer{n}", 2.0)
    assert len(limit._slots) <= 4
