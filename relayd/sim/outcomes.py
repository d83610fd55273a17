"""What a run's trace says about link breaks and recovery (pure functions of trace.jsonl).

`relayd.sim.summary.summarize` puts them into summary.json: the end-to-end link's
breaks (start, end), its total down time, and each relay's recovery episodes (start,
end, kind, outcome, distance driven). docs/SIMULATOR.md describes the keys.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import Any

#: Link-down spells closer together than this are one break (a hop flickering at its threshold).
BREAK_MERGE_S = 1.0


def link_breaks(
    records: Sequence[dict[str, Any]], merge_s: float = BREAK_MERGE_S
) -> list[dict[str, Any]]:
    """The spells the end-to-end link was down: start and end (None: still down at the end)."""
    spells: list[list[float | None]] = []
    for r in records:
        t = r["t"]
        if r["broken"]:
            if spells and spells[-1][1] is not None and t - spells[-1][1] <= merge_s:
                spells[-1][1] = None  # flickered back up only briefly: the same break
            elif not spells or spells[-1][1] is not None:
                spells.append([t, None])
        elif spells and spells[-1][1] is None:
            spells[-1][1] = t
    out = []
    for start, end in spells:
        if start is None:  # a spell always opens with its start; nothing to report otherwise
            continue
        out.append(
            {
                "start_s": start,
                "end_s": end,
                "duration_s": None if end is None else round(end - start, 2),
            }
        )
    return out


def downtime_s(records: Sequence[dict[str, Any]]) -> float:
    """Clock seconds the end-to-end link was down (each trace record stands for its interval)."""
    total = 0.0
    for a, b in itertools.pairwise(records):
        if a["broken"]:
            total += b["t"] - a["t"]
    return round(total, 2)


def recovery_episodes(records: Sequence[dict[str, Any]], i: int) -> list[dict[str, Any]]:
    """Relay i's recovery episodes from the trace: start, end, kind, outcome, distance driven."""
    out: list[dict[str, Any]] = []
    cur: dict[str, Any] | None = None
    for r in records:
        rec = r["relays"][i].get("recovery")
        if rec is None:
            continue
        active = rec["phase"] in ("widen", "retrace", "backup")
        if cur is not None and (not active or rec["episodes"] != cur["episode"]):
            cur["end_s"] = r["t"]
            cur["outcome"] = (
                rec["outcome"] if rec["episodes"] == cur["episode"] or not active else "preempted"
            )
            out.append(cur)
            cur = None
        if active and cur is None:
            cur = {
                "episode": rec["episodes"],
                "kind": rec["kind"],
                "start_s": r["t"],
                "end_s": None,
                "outcome": None,
                "distance_m": 0.0,
            }
        if cur is not None and rec.get("distance_m") is not None:
            cur["distance_m"] = max(cur["distance_m"], rec["distance_m"])
    if cur is not None:
        out.append(cur)
    return out
