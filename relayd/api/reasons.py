"""Reason codes in plain language: "stopped: the link behind is weak (−64 dBm ≤ −60)".

The phrases live in one file, `static/reasons.json`, which the live page fetches and
this module renders for Python readers (the fleet view, tests). The measured
comparison in brackets is computed the same way here and in static/reasons.js; the
browser test checks the two agree on a real daemon's status document.
"""

from __future__ import annotations

import json
import math
from functools import cache
from importlib import resources
from typing import Any

MINUS = "\u2212"


@cache
def phrasebook() -> dict[str, dict[str, str]]:
    """reason code -> {"text", optional "manual", optional "detail"}."""
    raw = (resources.files("relayd.api") / "static" / "reasons.json").read_text(encoding="utf-8")
    phrases: dict[str, dict[str, str]] = json.loads(raw)["phrases"]
    return phrases


def fmt_db(value: float) -> str:
    """-64.0 -> "−64", -63.46 -> "−63.5": one decimal at most, a real minus sign.

    Rounds as JavaScript's Math.round does (half up), on integers, so reasons.js
    writes the very same characters for the same number.
    """
    scaled = value * 10 + 0.5
    if not math.isfinite(scaled):  # 1e308 from a broken peer: no number to write
        return "?"
    tenths = math.floor(scaled)
    whole, frac = divmod(abs(tenths), 10)
    text = f"{whole}" if frac == 0 else f"{whole}.{frac}"
    return text if tenths >= 0 else MINUS + text


def _num(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return float(value)


def comparison(kind: str, doc: dict[str, Any]) -> str | None:
    """The measured value against its threshold, or None when either is unknown.

    While stopped the robot resumes only beyond the hysteresis band, so a value inside
    the band is shown with the level it must reach rather than as a false inequality.
    """
    thresholds = doc.get("thresholds") or {}
    band = _num(thresholds.get("hysteresis_db")) or 0.0
    if kind == "leader":
        value, thr = _num(doc.get("rssi_leader_dbm")), _num(thresholds.get("threshold_l_dbm"))
        if value is None or thr is None:
            return None
        if value >= thr:
            return f"{fmt_db(value)} dBm \u2265 {fmt_db(thr)}"
        return f"{fmt_db(value)} dBm, drives again below {fmt_db(thr - band)}"
    if kind == "rear":
        value, thr = _num(doc.get("rssi_behind_dbm")), _num(thresholds.get("threshold_b_dbm"))
        if value is None or thr is None:
            return None
        if value <= thr:
            return f"{fmt_db(value)} dBm \u2264 {fmt_db(thr)}"
        return f"{fmt_db(value)} dBm, drives again above {fmt_db(thr + band)}"
    raise ValueError(f"unknown detail kind {kind!r}")


def describe(doc: dict[str, Any]) -> str:
    """The plain-language reason of one /status document; an unknown code is shown as is."""
    reason = str(doc.get("reason", ""))
    code, colon, extra = reason.partition(":")
    entry = phrasebook().get(code.strip())
    if entry is None:
        return reason
    text = entry.get("manual", entry["text"]) if doc.get("mode") == "manual" else entry["text"]
    kind = entry.get("detail")
    detail = comparison(kind, doc) if kind else (extra.strip() if colon else None)
    if detail:
        text = f"{text} ({detail})"
    return text
