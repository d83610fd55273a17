"""Config rules that span several keys, and the helpers that make config errors readable.

The rules work on plain dicts (one section, defaults filled in), so they run in the
same pass as the schema (relayd.config.load) even when other keys of the section are
invalid: a config with a wrong type *and* inverted thresholds reports both at once.
The pydantic models in relayd.config.model call the same rules, so a Settings built in code
obeys them too.
A rule skips a comparison when one of its inputs is not a usable number; the schema
error for that key is reported instead.
"""

from __future__ import annotations

import difflib
import errno
import math
from collections.abc import Iterable, Mapping
from typing import Any, get_args
from urllib.parse import urlsplit

from pydantic import BaseModel, ValidationError

from relayd.core.control.rangecue import NEAR_M, RELEASE_HYSTERESIS_M


class ConfigError(Exception):
    """A config that cannot be used; `errors` lists every problem as 'key.path: message'."""

    def __init__(self, errors: list[str]) -> None:
        super().__init__("\n".join(errors))
        self.errors = errors


#: The P3-AT sonar's reach (m, relayd/core/scan/estimator.py SONAR_MAX_RANGE_M): no sonar floor says more.
SONAR_REACH_M = 5.0

#: (key, message): the key is dotted from the top of the config ("control.kp").
Problem = tuple[str, str]


def _num(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    return float(v) if math.isfinite(v) else None


def control_rules(c: Mapping[str, Any]) -> list[Problem]:
    out: list[Problem] = []
    stop, obst, detect = (
        _num(c.get(k)) for k in ("stop_distance_m", "threshold_o_m", "detect_range_m")
    )
    if stop is not None and obst is not None and detect is not None and not stop < obst < detect:
        out.append(
            (
                "control.threshold_o_m",
                "need stop_distance_m < threshold_o_m < detect_range_m "
                f"(got {stop:g} < {obst:g} < {detect:g})",
            )
        )
    gap = _num(c.get("leader_gap_max_m"))
    if (
        gap is not None
        and gap > 0
        and obst is not None
        and not max(obst, NEAR_M) < gap - RELEASE_HYSTERESIS_M
        and gap <= SONAR_REACH_M
    ):
        # Once released, the release holds down to gap - hysteresis: all of that must lie
        # beyond threshold_o (the obstacle rule's) and where the floor holds (NEAR_M).
        out.append(
            (
                "control.leader_gap_max_m",
                f"must be 0 (off) or more than {RELEASE_HYSTERESIS_M:g} m (the "
                "release's hysteresis) above both threshold_o_m "
                f"({obst:g}) and {NEAR_M:g} m, the nearest a sonar floor holds",
            )
        )
    elif gap is not None and gap > 0 and not gap <= SONAR_REACH_M:
        out.append(
            (
                "control.leader_gap_max_m",
                f"must be 0 (off) or at most {SONAR_REACH_M:g} m, the sonars' "
                "reach: the sonar floor it is compared with says how far the "
                "leader is at least",
            )
        )
    out.extend(leader_feed_rules(c))
    thr_l, thr_b, lost = (
        _num(c.get(k)) for k in ("threshold_l_dbm", "threshold_b_dbm", "lost_rssi_dbm")
    )
    if thr_l is not None and thr_b is not None and not thr_l > thr_b:
        out.append(
            (
                "control.threshold_l_dbm",
                f"must be above threshold_b_dbm ({thr_b:g}): the robot stops "
                "when the leader is heard this well, and the node behind must "
                "fade further than that first (the paper uses -30 and -40)",
            )
        )
    if thr_l is not None and lost is not None and not lost < thr_l:
        out.append(
            (
                "control.lost_rssi_dbm",
                f"must be below threshold_l_dbm ({thr_l:g}): a leader heard "
                "well enough to stop for cannot also be lost",
            )
        )
    b_min, b_max = _num(c.get("threshold_b_min_dbm")), _num(c.get("threshold_b_max_dbm"))
    if b_min is not None and b_max is not None and not b_min < b_max:
        out.append(
            (
                "control.threshold_b_min_dbm",
                f"must be below threshold_b_max_dbm ({b_max:g}): they are "
                "the adaptive rear limit's bounds",
            )
        )
    elif c.get("link_policy") == "adaptive" and b_min is not None and b_max is not None:
        if thr_b is not None and not b_min <= thr_b <= b_max:
            out.append(
                (
                    "control.threshold_b_dbm",
                    f"must lie within threshold_b_min_dbm..threshold_b_max_dbm "
                    f'({b_min:g}..{b_max:g}) with link_policy = "adaptive": '
                    "it is where the adaptive limit starts",
                )
            )
        if c.get("rear_link") == "ignore":
            out.append(
                (
                    "control.link_policy",
                    '"adaptive" sets the rear limit, and rear_link = "ignore" has '
                    'none: use "fixed" or rear_link = "require"',
                )
            )
        if thr_l is not None and not thr_l > b_max:
            out.append(
                (
                    "control.threshold_b_max_dbm",
                    f"must be below threshold_l_dbm ({thr_l:g}) with "
                    'link_policy = "adaptive": the rear limit may rise '
                    "that far",
                )
            )
    return out


def avoidance_rules(a: Mapping[str, Any]) -> list[Problem]:
    rate, least = _num(a.get("turn_rate_deg_s")), _num(a.get("min_turn_deg_s"))
    if rate is not None and least is not None and rate < least:
        return [
            (
                "avoidance.turn_rate_deg_s",
                f"must be at least min_turn_deg_s ({least:g}): no turn "
                "in place is ever commanded slower than that",
            )
        ]
    first, most = _num(a.get("blocked_retry_s")), _num(a.get("blocked_retry_max_s"))
    if first is not None and most is not None and first > 0 and most < first:
        return [
            (
                "avoidance.blocked_retry_max_s",
                f"must be at least blocked_retry_s ({first:g}): the longest wait "
                "before a blocked escape starts afresh",
            )
        ]
    return []


def pantilt_rules(p: Mapping[str, Any]) -> list[Problem]:
    scan, link = p.get("scan_channel"), p.get("link_channel")
    if isinstance(scan, int) and isinstance(link, int) and scan == link:
        return [("pantilt.link_channel", "scan_channel and link_channel must differ")]
    return []


def leader_url_error(url: str) -> str | None:
    """Why `control.leader_url` is not a relay's API base URL (None: it is)."""
    parts = urlsplit(url)
    try:
        parts.port  # noqa: B018 - raises ValueError for a port that is not a number
    except ValueError:
        return f"bad port in {url!r}"
    if parts.scheme not in ("http", "https") or not parts.hostname:
        return f"must be the leader relay's API as http(s)://host:port, got {url!r}"
    if parts.query or parts.fragment or parts.path not in ("", "/"):
        return f"the leader relay's base URL has no path, query or fragment: {url!r}"
    return None


def leader_feed_rules(c: Mapping[str, Any]) -> list[Problem]:
    """A leader feed needs the start poses (the frame's prior) and the trail pursuit."""
    if c.get("leader_url") is None:
        return []
    out: list[Problem] = []
    if c.get("leader_origin") is None:
        out.append(
            (
                "control.leader_origin",
                "is needed with leader_url: where the leader's odometry started, in "
                "this relay's odometry frame (x_m, y_m, heading_deg; the fleet "
                "config's origins give it)",
            )
        )
    if c.get("pursuit") != "trail":
        out.append(
            (
                "control.leader_url",
                'is followed only with pursuit = "trail" (the bearing pursuit has no trail)',
            )
        )
    return out


def ap_rules(side: str, ap: Mapping[str, Any]) -> list[Problem]:
    if (ap.get("password_env") is None) == (ap.get("password_file") is None):
        return [(f"ap.{side}", "set exactly one of password_env or password_file")]
    return []


def cross_section_rules(data: Mapping[str, Any], control: Mapping[str, Any]) -> list[Problem]:
    """Rules between sections, on the raw TOML document (`control` with defaults filled in)."""
    ap = data.get("ap")
    rear = ap.get("rear") if isinstance(ap, Mapping) else None
    if control.get("rear_link") == "require" and not (
        isinstance(rear, Mapping) and rear.get("enabled", True)
    ):
        return [
            (
                "control.rear_link",
                '"require" needs an enabled [ap.rear] (the radio that hears the '
                'node behind); set rear_link = "ignore" for the first robot of a test',
            )
        ]
    return []


def message(problem: Problem) -> str:
    return f"{problem[0]}: {problem[1]}"


def raise_first(problems: Iterable[Problem]) -> None:
    """For model validators: the first problem as a ValueError (the same text check-config prints)."""
    for _key, text in problems:
        raise ValueError(text)


def did_you_mean(key: str, known: Iterable[str]) -> str:
    match = difflib.get_close_matches(key, list(known), n=1, cutoff=0.6)
    return f" (did you mean {match[0]!r}?)" if match else ""


def loads_toml(text: str) -> dict[str, Any]:
    """tomllib.loads, with nesting too deep for the parser (`a = [[[[...`, which once ended
    check-config in a RecursionError traceback) reported as the TOMLDecodeError it is."""
    import tomllib

    try:
        return tomllib.loads(text)
    except RecursionError:
        raise tomllib.TOMLDecodeError("arrays or tables nested too deeply") from None


def undecodable(raw: bytes, exc: UnicodeDecodeError) -> str:
    """Where a non-UTF-8 byte sits in a TOML file: 'section.key (line N)' and the byte."""
    before = raw[: exc.start].decode("utf-8", errors="replace")
    line_no = before.count("\n") + 1
    section = ""
    for line in before.splitlines():
        stripped = line.strip()
        if stripped.startswith("[") and "]" in stripped:
            section = stripped.strip("[]").strip()
    this_line = before.rsplit("\n", 1)[-1]
    key = this_line.split("=", 1)[0].strip() if "=" in this_line else ""
    where = ".".join(p for p in (section, key) if p) or "(top level)"
    return (
        f"{where} (line {line_no}): not UTF-8 (byte 0x{raw[exc.start]:02x}); save the file as UTF-8"
    )


def _loc(loc: tuple[int | str, ...]) -> str:
    return ".".join(str(p) for p in _keys(loc)) or "(top level)"


def _keys(loc: tuple[int | str, ...]) -> tuple[int | str, ...]:
    # pydantic puts union/type tags into loc ("function-after[...]"); keep only real keys.
    return tuple(
        p for p in loc if not (isinstance(p, str) and ("[" in p or p.startswith("function-")))
    )


def _model_at(keys: tuple[int | str, ...], root: type[BaseModel]) -> type[BaseModel] | None:
    model = root
    for part in keys:
        field = model.model_fields.get(str(part))
        if field is None:
            return None
        models = [
            a
            for a in (get_args(field.annotation) or (field.annotation,))
            if isinstance(a, type) and issubclass(a, BaseModel)
        ]
        if not models:
            return None
        model = models[0]
    return model


def validation_messages(exc: ValidationError, root: type[BaseModel] | None = None) -> list[str]:
    """One 'key.path: message' per error; an unknown key gets the closest known one."""
    out = []
    for e in exc.errors():
        keys = _keys(e["loc"])
        text = e["msg"].removeprefix("Value error, ")
        if e["type"] == "extra_forbidden" and root is not None and keys:
            model = _model_at(keys[:-1], root)
            if model is not None:
                text = "unknown key" + did_you_mean(str(keys[-1]), model.model_fields)
        out.append(f"{_loc(e['loc'])}: {text}")
    return out


def with_defaults(model: type[BaseModel], raw: Any) -> dict[str, Any]:
    out = {name: f.default for name, f in model.model_fields.items() if not f.is_required()}
    if isinstance(raw, Mapping):
        out.update(raw)
    return out


def api_bind_error(bind: str, port: int, exc: OSError) -> str:
    """Why the API could not listen, naming the key to change."""
    if exc.errno == errno.EADDRINUSE:
        return f"api.port: {port} is already in use on {bind} (another relayd?); choose another api.port"
    if exc.errno == errno.EADDRNOTAVAIL:
        return f"api.bind: {bind} is not an address of this machine (use 0.0.0.0 or one of its addresses)"
    if exc.errno == errno.EACCES:
        return f"api.port: {port} is a privileged port; use one above 1023"
    return f"api.bind: cannot listen on {bind}:{port}: {exc.strerror or exc}"
