"""`relayd status [URL] [--json]`: fetch a robot's /status and print it for a human.

Works against any relayd on the bridge (`relayd status http://192.168.1.31:8080`).
An unreachable robot or a non-relayd answer is a one-line message and exit code 1.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any, TextIO

import aiohttp

DEFAULT_URL = "http://127.0.0.1:8080"
TIMEOUT_S = 5.0


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "url",
        nargs="?",
        default=DEFAULT_URL,
        help=f"the robot's API base URL or its /status URL (default {DEFAULT_URL})",
    )
    parser.add_argument("--json", action="store_true", help="print the raw /status JSON")
    parser.add_argument(
        "--timeout", type=float, default=TIMEOUT_S, help="seconds to wait (default 5)"
    )


def status_url(url: str) -> str:
    if "://" not in url:
        url = "http://" + url
    url = url.rstrip("/")
    return url if url.endswith("/status") else url + "/status"


def _f(value: Any, digits: int = 1, unit: str = "") -> str:
    if value is None:
        return "-"
    try:
        text = f"{float(value):.{digits}f}"
    except (TypeError, ValueError):
        return str(value)
    return f"{text} {unit}".rstrip()


def _vs(value: Any, threshold: Any, drive_below: bool) -> str:
    """RSSI against its threshold, with what it means for driving."""
    if value is None or threshold is None:
        return _f(value, 1, "dBm")
    if drive_below:
        go, rel = value < threshold, "<" if value < threshold else ">="
    else:
        go, rel = value > threshold, ">" if value > threshold else "<="
    verdict = "ok to drive" if go else "stop"
    return f"{value:.1f} dBm {rel} {threshold:g} dBm ({verdict})"


def format_recovery(rec: dict[str, Any]) -> str:
    """The recovery state machine in one line: phase, what it heals, progress or last outcome."""
    text = str(rec.get("phase"))
    if rec.get("kind"):
        text += f" ({'link behind' if rec['kind'] == 'rear' else 'leader'})"
    if rec.get("elapsed_s") is not None:
        text += (
            f", {_f(rec.get('elapsed_s'), 0, 's')} of {_f(rec.get('max_time_s'), 0, 's')},"
            f" {_f(rec.get('distance_m'), 1, 'm')} of {_f(rec.get('max_distance_m'), 1, 'm')}"
        )
    elif rec.get("last_outcome"):
        text += f", last {rec['last_outcome']}"
    return (
        text + f"; {rec.get('episodes', 0)} episode(s), trail {rec.get('trail_crumbs', 0)} crumbs"
    )


def format_status(doc: dict[str, Any]) -> str:
    """A compact table of one /status document."""
    rows: list[tuple[str, str]] = []
    thr = doc.get("thresholds") or {}
    # The operator's name first; the base's own name says which hardware answered.
    name = " / ".join(str(n) for n in (doc.get("display_name"), doc.get("robot")) if n) or "-"
    rows.append(
        (
            "robot",
            f"{name}  (relayd {doc.get('version', '?')}, up {_f(doc.get('uptime_s'), 0, 's')})",
        )
    )
    rows.append(("mode / state", f"{doc.get('mode')} / {doc.get('state')}"))
    rows.append(("reason", str(doc.get("reason"))))
    situation = doc.get("situation")
    names = {0: "0 clear", 1: "1 avoiding obstacle", 2: "2 obstacle penalty"}
    rows.append(
        (
            "situation",
            names.get(situation, str(situation)) if isinstance(situation, int) else str(situation),
        )
    )
    rows.append(
        (
            "bearing",
            f"{_f(doc.get('bearing_deg'), 1, 'deg')}  "
            f"(link antenna {_f(doc.get('link_bearing_deg'), 1, 'deg')})",
        )
    )
    rows.append(
        ("RSSI^l leader", _vs(doc.get("rssi_leader_dbm"), thr.get("threshold_l_dbm"), True))
    )
    rows.append(
        ("RSSI^b behind", _vs(doc.get("rssi_behind_dbm"), thr.get("threshold_b_dbm"), False))
    )
    model = doc.get("link_model")
    if isinstance(model, dict):
        in_force = "in force" if model.get("policy") == "adaptive" else "advice only (fixed policy)"
        rows.append(
            (
                "rear limit model",
                f"{_f(model.get('threshold_b_dbm'), 1, 'dBm')} {in_force}; "
                f"mu {_f(model.get('mu_dbm'), 1, 'dBm')}, spread "
                f"{_f(model.get('spread_db'), 1, 'dB')}, P(>= "
                f"{_f(model.get('target_hop_mbps'), 0, 'Mb/s')}) now "
                f"{_f(model.get('p_ok_now'), 2)}, {model.get('samples')} polls"
                f"{'' if model.get('learning') else ', still learning'}",
            )
        )
    wheels = doc.get("wheels_mm_s") or {}
    rows.append(
        (
            "wheels",
            f"L {_f(wheels.get('left'), 0, 'mm/s')}  R {_f(wheels.get('right'), 0, 'mm/s')}"
            f"  motors {'on' if doc.get('motors_enabled') else 'off'}",
        )
    )
    pose = doc.get("pose") or {}
    rows.append(
        (
            "pose",
            f"x {_f(pose.get('x_mm'), 0, 'mm')}  y {_f(pose.get('y_mm'), 0, 'mm')}"
            f"  theta {_f(pose.get('theta_deg'), 1, 'deg')}",
        )
    )
    rows.append(("battery", _f(doc.get("battery_v"), 1, "V")))
    sonar = doc.get("sonar_mm") or []
    front = [r for r in sonar[:8] if r is not None]
    rows.append(("sonar front min", _f(min(front) / 1000 if front else None, 2, "m")))
    scan = doc.get("last_scan")
    if scan:
        rows.append(
            (
                "last scan",
                f"{len(scan.get('angles') or [])} samples, {_f(scan.get('age_s'), 1, 's')} ago, "
                f"period {_f(scan.get('period_s'), 2, 's')}, #{doc.get('scan_count')}",
            )
        )
    rec = doc.get("recovery")
    if isinstance(rec, dict):
        rows.append(("recovery", format_recovery(rec)))
    for name, link in sorted((doc.get("links") or {}).items()):
        rows.append(
            (
                f"link {name}",
                f"signal {_f(link.get('signal_dbm'), 0, 'dBm')}  noise {_f(link.get('noise_dbm'), 0, 'dBm')}"
                f"  ccq {_f(link.get('ccq_pct'), 0, '%')}  tx {_f(link.get('tx_mbps'), 1, 'Mb/s')}"
                f"  rx {_f(link.get('rx_mbps'), 1, 'Mb/s')}  age {_f(link.get('age_s'), 1, 's')}",
            )
        )
    rec = doc.get("recording")
    if rec and rec.get("enabled"):
        text = f"{rec.get('state')}  {rec.get('path') or '-'}  {_f((rec.get('bytes') or 0) / 1e6, 1, 'MB')}"
        if rec.get("dropped"):
            text += f"  {rec['dropped']} events dropped"
        if rec.get("error"):
            text += f"  ({rec['error']})"
        rows.append(("recording", text.upper() if rec.get("state") == "failed" else text))
    width = max(len(k) for k, _ in rows)
    lines = [f"{k:<{width}}  {v}" for k, v in rows]
    health = doc.get("health") or {}
    if health:
        lines.append("")
        lines.append(
            f"{'device':<10} {'link':<5} {'age':>8} {'errors':>7} {'reconn':>7}  last error"
        )
        for name, h in sorted(health.items()):
            lines.append(
                f"{name:<10} {'up' if h.get('connected') else 'DOWN':<5} "
                f"{_f(h.get('age_s'), 2, 's'):>8} {h.get('errors', 0):>7} "
                f"{h.get('reconnects', 0):>7}  {h.get('last_error') or ''}"
            )
    return "\n".join(lines)


async def fetch_status(url: str, timeout_s: float = TIMEOUT_S) -> dict[str, Any]:
    """GET the /status document; raises RuntimeError with a readable message on any failure."""
    target = status_url(url)
    try:
        async with (
            aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=timeout_s)) as session,
            session.get(target) as resp,
        ):
            if resp.status != 200:
                raise RuntimeError(f"{target} answered HTTP {resp.status}")
            doc = await resp.json(content_type=None)
    except (aiohttp.ClientError, TimeoutError, OSError) as exc:
        raise RuntimeError(f"cannot reach {target}: {exc or type(exc).__name__}") from exc
    except json.JSONDecodeError as exc:
        raise RuntimeError(f"{target} did not answer JSON: {exc}") from exc
    if not isinstance(doc, dict) or "state" not in doc:
        raise RuntimeError(f"{target} did not answer a relayd status document")
    return doc


async def run(
    args: argparse.Namespace, out: TextIO | None = None, err: TextIO | None = None
) -> int:
    out = sys.stdout if out is None else out
    err = sys.stderr if err is None else err
    try:
        doc = await fetch_status(args.url, args.timeout)
    except RuntimeError as exc:
        print(f"relayd status: {exc}", file=err)
        return 1
    if args.json:
        print(json.dumps(doc, indent=2), file=out)
    else:
        print(format_status(doc), file=out)
    return 0
