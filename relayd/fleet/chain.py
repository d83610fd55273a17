"""The fleet document: the chain leader -> relays -> command center, from the pollers' memory.

Pure functions of the relays' last status documents and the fleet's clock, so the
page's whole content is unit-testable without a network. Chain order is config order,
the relay nearest the leader first. Each hop is measured from both ends where radios
see it: the hop into relay k by its front radio (the link to the one ahead; for the
first relay also its Yagi's RSSI^l), the hop out of it by its rear radio (RSSI^b).
Only current documents count; a hop nobody measures now is "unknown", never a guess.
The estimated rate is the 802.11g rate the weaker end's signal supports (the
receiver-sensitivity table of relayd.sim.radio) times the MAC efficiency.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

from relayd.api.reasons import describe
from relayd.fleet.poller import RelayView
from relayd.sim.radio import throughput_mbps


def _num(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return float(value)


def link_status(view: RelayView, now: float, stale_after_s: float) -> str:
    """live, stale (answers too slowly), no_answer, unreachable, bad_answer, or connecting."""
    if view.error_kind is not None:
        return view.error_kind
    if view.ok_t is None:
        return "connecting"
    return "live" if now - view.ok_t <= stale_after_s else "stale"


def relay_summary(view: RelayView, now: float, stale_after_s: float) -> dict[str, Any]:
    doc = view.doc or {}
    status = link_status(view, now, stale_after_s)
    wheels = doc.get("wheels_mm_s") or {}
    return {
        "name": view.relay.name,
        "url": view.relay.url,
        "link": status,
        "current": status == "live",
        "error": view.error,
        "age_s": None if view.ok_t is None else round(now - view.ok_t, 2),
        "latency_ms": None if view.latency_s is None else round(view.latency_s * 1000, 1),
        "has_token": view.relay.token is not None,
        "robot": doc.get("display_name") or doc.get("robot"),
        "state": doc.get("state"),
        "mode": doc.get("mode"),
        "reason": doc.get("reason"),
        "reason_text": describe(doc) if doc else None,
        "battery_v": _num(doc.get("battery_v")),
        "rssi_leader_dbm": _num(doc.get("rssi_leader_dbm")),
        "rssi_behind_dbm": _num(doc.get("rssi_behind_dbm")),
        "bearing_deg": _num(doc.get("bearing_deg")),
        "wheels_mm_s": [_num(wheels.get("left")), _num(wheels.get("right"))],
    }


def _link_dbm(doc: dict[str, Any], side: str) -> float | None:
    link = (doc.get("links") or {}).get(side) or {}
    return _num(link.get("signal_dbm"))


def _hop(frm: str, to: str, measurements: list[dict[str, Any]]) -> dict[str, Any]:
    values = [m["dbm"] for m in measurements]
    weakest = min(values) if values else None
    return {
        "from": frm,
        "to": to,
        "measurements": measurements,
        "rssi_dbm": weakest,
        "est_mbps": None if weakest is None else throughput_mbps(weakest),
    }


def hops(views: list[RelayView], now: float, stale_after_s: float) -> list[dict[str, Any]]:
    names = ["leader", *(v.relay.name for v in views), "command center"]
    docs = [v.doc if link_status(v, now, stale_after_s) == "live" else None for v in views]
    out = []
    for k in range(len(names) - 1):
        measured: list[dict[str, Any]] = []
        upstream = docs[k - 1] if k >= 1 else None  # the relay on the leader's side of the hop
        downstream = docs[k] if k < len(docs) else None  # the relay on the command center's side
        if upstream is not None:
            for label, value in (
                ("rear radio", _link_dbm(upstream, "rear")),
                ("RSSI^b", _num(upstream.get("rssi_behind_dbm"))),
            ):
                if value is not None:
                    measured.append({"by": f"{names[k]} {label}", "dbm": value})
                    break  # the rear radio's own report, or RSSI^b when it has none
        if downstream is not None:
            front = _link_dbm(downstream, "front")
            if front is not None:
                measured.append({"by": f"{names[k + 1]} front radio", "dbm": front})
            if k == 0 and (rl := _num(downstream.get("rssi_leader_dbm"))) is not None:
                measured.append({"by": f"{names[k + 1]} Yagi (RSSI^l)", "dbm": rl})
        out.append(_hop(names[k], names[k + 1], measured))
    return out


#: Why a relay is not on the map without an origin, and how to give it one.
NO_ORIGIN = (
    "no origin configured: odometry starts at zero wherever relayd started; give "
    "origin = [x_m, y_m, heading_deg] in its [[fleet.relay]] (fleet -c), which --relay cannot"
)


def _to_map(origin: tuple[float, float, float], x_mm: float, y_mm: float) -> tuple[float, float]:
    ox, oy, oth = origin
    c, s = math.cos(math.radians(oth)), math.sin(math.radians(oth))
    x, y = x_mm / 1000.0, y_mm / 1000.0
    return ox + c * x - s * y, oy + s * x + c * y


def fleet_map(views: list[RelayView], now: float, stale_after_s: float) -> dict[str, Any]:
    """Relays on one map: each relay's odometry, placed by the origin configured for it.

    Odometry starts at zero wherever relayd started, so without an origin a relay
    cannot be put next to the others; it is listed as unplaced rather than guessed.
    """
    placed, unplaced = [], []
    for v in views:
        doc = v.doc or {}
        pose = doc.get("pose") or {}
        x, y, th = _num(pose.get("x_mm")), _num(pose.get("y_mm")), _num(pose.get("theta_deg"))
        origin = v.relay.origin
        if origin is None or x is None or y is None:
            unplaced.append(
                {
                    "name": v.relay.name,
                    "why": NO_ORIGIN if origin is None else "no odometry yet",
                }
            )
            continue
        mx, my = _to_map(origin, x, y)
        heading = origin[2] + (th or 0.0)
        bearing = _num(doc.get("bearing_deg"))
        placed.append(
            {
                "name": v.relay.name,
                "x_m": round(mx, 3),
                "y_m": round(my, 3),
                "heading_deg": round(heading, 1),
                "leader_deg": None if bearing is None else round(heading + bearing, 1),
                "state": doc.get("state"),
                "current": link_status(v, now, stale_after_s) == "live",
                "trail": [
                    [round(a, 3), round(b, 3)]
                    for a, b in (_to_map(origin, tx, ty) for tx, ty in v.trail)
                ],
            }
        )
    return {"relays": placed, "unplaced": unplaced}


#: What a relay's status document may break with when it is not what a relayd sends.
_BAD_DOC = (AttributeError, TypeError, ValueError, KeyError, IndexError, OverflowError)


def fleet_document(views: list[RelayView], now: float, stale_after_s: float) -> dict[str, Any]:
    """The whole fleet. Each relay's document is read on its own: one that is not what a
    relayd sends is shown as a bad answer, with the reason, and the others stay."""
    relays: list[dict[str, Any]] = []
    good: list[RelayView] = []
    for v in views:
        try:
            summary = relay_summary(v, now, stale_after_s)
            hops([v], now, stale_after_s)
            fleet_map([v], now, stale_after_s)
        except _BAD_DOC as exc:
            relays.append(_bad_summary(v, f"unreadable status: {type(exc).__name__}: {exc}"))
            continue
        relays.append(summary)
        good.append(v)
    return {
        "relays": relays,
        "hops": hops([v if v in good else _without_doc(v) for v in views], now, stale_after_s),
        "map": fleet_map(good, now, stale_after_s),
        "stale_after_s": stale_after_s,
    }


def _without_doc(view: RelayView) -> RelayView:
    return replace(view, doc=None)


def _bad_summary(view: RelayView, error: str) -> dict[str, Any]:
    return {
        "name": view.relay.name,
        "url": view.relay.url,
        "link": "bad_answer",
        "current": False,
        "error": error[:200],
        "age_s": None,
        "latency_ms": None,
        "has_token": view.relay.token is not None,
        "robot": None,
        "state": None,
        "mode": None,
        "reason": None,
        "reason_text": None,
        "battery_v": None,
        "rssi_leader_dbm": None,
        "rssi_behind_dbm": None,
        "bearing_deg": None,
        "wheels_mm_s": [None, None],
    }
