"""Foxglove's well-known schemas, and the views of the route that fit them.

Foxglove opens any JSON channel with a JSON schema, but three of its own schemas get
its dedicated panels: `foxglove.PoseInFrame` (the 3D panel draws the odometry path),
`foxglove.Log` (the Log panel) and `foxglove.KeyValuePair` (State Transitions on
`/state.value`). These channels are *views*: derived from the raw events and actions,
which are recorded in full on their own channels; replay never reads them.

- `/robot/pose` (foxglove.PoseInFrame, frame "odom"): the odometry pose of each SIP, m.
- `/state` (foxglove.KeyValuePair): "drive_state", "reason" and "mode" when they change.
- `/log` (foxglove.Log): the lines an operator looks for first: drive-state changes,
  devices up and down, mode changes, recorder gaps. The daemon's full log stays in
  the journal.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from relayd.core.events import (
    Action,
    Decision,
    DeviceEvent,
    DeviceStatus,
    Event,
    ModeCommand,
    SipEvent,
)

_TIME: dict[str, Any] = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
    },
    "required": ["sec", "nsec"],
}


def _xyz(title: str, keys: str) -> dict[str, Any]:
    return {
        "title": title,
        "type": "object",
        "properties": {k: {"type": "number"} for k in keys},
        "required": list(keys),
    }


POSE_IN_FRAME: dict[str, Any] = {
    "title": "foxglove.PoseInFrame",
    "description": "A timestamped pose for an object or reference frame in 3D space",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "pose": {
            "title": "foxglove.Pose",
            "type": "object",
            "properties": {
                "position": _xyz("foxglove.Vector3", "xyz"),
                "orientation": _xyz("foxglove.Quaternion", "xyzw"),
            },
            "required": ["position", "orientation"],
        },
    },
    "required": ["timestamp", "frame_id", "pose"],
}

LOG_LEVELS = {"UNKNOWN": 0, "DEBUG": 1, "INFO": 2, "WARNING": 3, "ERROR": 4, "FATAL": 5}
LOG: dict[str, Any] = {
    "title": "foxglove.Log",
    "description": "A log message",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "level": {
            "title": "foxglove.LogLevel",
            "oneOf": [{"title": k, "const": v} for k, v in LOG_LEVELS.items()],
        },
        "message": {"type": "string"},
        "name": {"type": "string"},
        "file": {"type": "string"},
        "line": {"type": "integer", "minimum": 0},
    },
    "required": ["timestamp", "level", "message", "name", "file", "line"],
}

KEY_VALUE_PAIR: dict[str, Any] = {
    "title": "foxglove.KeyValuePair",
    "description": "A key with its associated value",
    "type": "object",
    "properties": {"key": {"type": "string"}, "value": {"type": "string"}},
    "required": ["key", "value"],
}

#: View topic -> its schema.
VIEWS: dict[str, dict[str, Any]] = {
    "/robot/pose": POSE_IN_FRAME,
    "/state": KEY_VALUE_PAIR,
    "/log": LOG,
}


def stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def pose_in_frame(ev: SipEvent, ns: int) -> dict[str, Any]:
    half = math.radians(ev.sip.theta_deg) / 2.0
    return {
        "timestamp": stamp(ns),
        "frame_id": "odom",
        "pose": {
            "position": {"x": ev.sip.x_mm / 1000.0, "y": ev.sip.y_mm / 1000.0, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(half), "w": math.cos(half)},
        },
    }


def log_line(ns: int, level: str, message: str, name: str, file: str) -> dict[str, Any]:
    return {
        "timestamp": stamp(ns),
        "level": LOG_LEVELS[level],
        "message": message,
        "name": name,
        "file": file,
        "line": 0,
    }


class Views:
    """Turns each (event, actions) into the view messages it causes: (topic, message)."""

    def __init__(self, name: str = "relayd") -> None:
        self.name = name
        self._mode: str | None = None

    def derive(
        self, event: Event, actions: Sequence[Action], ns: int
    ) -> list[tuple[str, dict[str, Any]]]:
        out: list[tuple[str, dict[str, Any]]] = []
        if isinstance(event, SipEvent):
            out.append(("/robot/pose", pose_in_frame(event, ns)))
        elif isinstance(event, DeviceEvent):
            level = "INFO" if event.status is DeviceStatus.UP else "WARNING"
            detail = f": {event.detail}" if event.detail else ""
            out.append(
                (
                    "/log",
                    log_line(
                        ns,
                        level,
                        f"device {event.device} {event.status}{detail}",
                        self.name,
                        "relayd.runtime.control",
                    ),
                )
            )
        elif isinstance(event, ModeCommand):
            out.append(
                (
                    "/log",
                    log_line(
                        ns, "INFO", f"operator asks for mode {event.mode}", self.name, "relayd.api"
                    ),
                )
            )
        for action in actions:
            if not isinstance(action, Decision):
                continue
            mode = str(action.mode)
            if mode != self._mode:
                self._mode = mode
                out.append(("/state", {"key": "mode", "value": mode}))
            if action.changed:
                out.append(("/state", {"key": "drive_state", "value": str(action.state)}))
                out.append(("/state", {"key": "reason", "value": action.reason}))
                out.append(
                    (
                        "/log",
                        log_line(
                            ns,
                            "INFO",
                            f"drive_state {action.state} ({action.reason}) wheels "
                            f"{action.left_mm_s:.0f}/{action.right_mm_s:.0f} mm/s",
                            self.name,
                            "relayd.core.brain",
                        ),
                    )
                )
        return out

    def gap(self, ns: int, lost: int) -> tuple[str, dict[str, Any]]:
        return (
            "/log",
            log_line(
                ns,
                "WARNING",
                f"recorder fell behind: {lost} event(s) not recorded here",
                self.name,
                "relayd.record",
            ),
        )
