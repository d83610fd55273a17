"""JSON for the bus vocabulary: every event and action to a dict and back, and its JSON schema.

The codec is generic over frozen dataclasses: it reads each class's type hints once,
so a new event or action type added to `relayd.core.events` is recorded, validated and
replayed without a line here (its channel is `/event/<Name>` or `/action/<Name>`
until it gets a name in `TOPICS`). Decisions:

- Floats are written with Python's shortest round-trip repr, so a replayed brain sees
  bit-identical numbers. JSON has no NaN or infinity: a non-finite float is written as
  null, and read back as NaN where the field cannot be None.
- Enums are written as their string values, tuples as arrays.
- Every message carries `seq`, the number of the event in the recording; an action's
  message also carries `i`, its place in the list the brain returned for that event.
  Replay regroups on these, not on file order or time.
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from enum import Enum
from functools import cache
from typing import Any

from relayd.core.events import Action, Event

#: Recording format: bumped when a message layout changes incompatibly.
FORMAT = 1

#: Channel topic of each event and action type (by class name).
TOPICS: dict[str, str] = {
    "SipEvent": "/robot/sip",
    "RssiEvent": "/wifi/rssi",
    "ServoPosition": "/servo/position",
    "ScanReady": "/scan/ready",
    "ScanSampleEvent": "/scan/sample",
    "ScanDone": "/scan/done",
    "LinkEvent": "/link",
    "DeviceEvent": "/device",
    "ModeCommand": "/operator/mode",
    "DriveCommand": "/operator/drive",
    "Tick": "/tick",
    "LeaderPath": "/leader/path",
    "Shutdown": "/shutdown",
    "WheelCommand": "/action/wheels",
    "ServoTarget": "/action/servo",
    "ScanPlan": "/action/scan_plan",
    "Decision": "/action/decision",
    "ScanResult": "/action/scan_result",
    "RearLink": "/action/rear_link",
    "RecoveryReport": "/action/recovery",
    "LinkModelView": "/action/link_model",
}
#: Envelope keys added to every message; no event or action field may use them.
ENVELOPE = ("seq", "i")


class DecodeError(ValueError):
    """A message that does not fit its type (names the field)."""


def _union_members(union: Any) -> tuple[type, ...]:
    return tuple(a for a in typing.get_args(union))


EVENT_TYPES: dict[str, type] = {c.__name__: c for c in _union_members(Event)}
ACTION_TYPES: dict[str, type] = {c.__name__: c for c in _union_members(Action)}


def topic_of(cls: type) -> str:
    name = cls.__name__
    if name in TOPICS:
        return TOPICS[name]
    return f"/action/{name}" if name in ACTION_TYPES else f"/event/{name}"


def schema_name(cls: type) -> str:
    return f"relayd.{cls.__name__}"


# -- encoding ------------------------------------------------------------------------


def to_json(value: Any) -> Any:
    """A dataclass tree as JSON-ready data (see the module's decisions)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, bool | int):
        return value
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, str):
        return value
    if isinstance(value, tuple | list):
        return [to_json(v) for v in value]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {name: to_json(getattr(value, name)) for name in _field_names(type(value))}
    raise TypeError(f"cannot record a {type(value).__name__}")


@cache
def _field_names(cls: type) -> tuple[str, ...]:
    names = tuple(f.name for f in dataclasses.fields(cls))
    clash = set(names) & set(ENVELOPE)
    if clash:
        raise TypeError(
            f"{cls.__name__} has fields {sorted(clash)} reserved for the recording envelope"
        )
    return names


def encode(obj: Any, seq: int, i: int | None = None) -> bytes:
    """One message: the envelope and the object's fields, as compact JSON bytes."""
    doc: dict[str, Any] = {"seq": seq}
    if i is not None:
        doc["i"] = i
    doc.update(to_json(obj))
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()


# -- decoding ------------------------------------------------------------------------


@cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


# Complexity: one branch per kind of type hint the codec supports (a type switch).
def from_json(hint: Any, value: Any, where: str) -> Any:  # noqa: C901
    """`value` (JSON data) as the Python type `hint`, or DecodeError naming `where`."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        arms = [a for a in typing.get_args(hint) if a is not type(None)]
        if value is None:
            if len(arms) < len(typing.get_args(hint)):
                return None
            if arms == [float]:
                return math.nan
            raise DecodeError(f"{where}: null is not allowed")
        errors = []
        for arm in arms:
            try:
                return from_json(arm, value, where)
            except DecodeError as exc:
                errors.append(str(exc))
        raise DecodeError("; ".join(errors))
    if hint is float:
        if value is None:
            return math.nan
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise DecodeError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if hint is bool or hint is int or hint is str:
        if not isinstance(value, hint) or (hint is int and isinstance(value, bool)):
            raise DecodeError(f"{where}: expected {hint.__name__}, got {value!r}")
        return value
    if hint is Any:
        return value
    if origin is tuple:
        args = typing.get_args(hint)
        if not isinstance(value, list):
            raise DecodeError(f"{where}: expected an array, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(from_json(args[0], v, f"{where}[{k}]") for k, v in enumerate(value))
        if len(args) != len(value):
            raise DecodeError(f"{where}: expected {len(args)} items, got {len(value)}")
        return tuple(
            from_json(a, v, f"{where}[{k}]")
            for k, (a, v) in enumerate(zip(args, value, strict=True))
        )
    if isinstance(hint, type) and issubclass(hint, Enum):
        try:
            return hint(value)
        except ValueError:
            raise DecodeError(f"{where}: {value!r} is not a {hint.__name__}") from None
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        if not isinstance(value, dict):
            raise DecodeError(f"{where}: expected an object, got {value!r}")
        hints = _hints(hint)
        kwargs = {}
        for name in _field_names(hint):
            if name not in value:
                raise DecodeError(f"{where}.{name}: missing")
            kwargs[name] = from_json(hints[name], value[name], f"{where}.{name}")
        return hint(**kwargs)
    raise DecodeError(f"{where}: cannot decode type {hint!r}")


def decode(cls: type, doc: dict[str, Any]) -> Any:
    """A message dict (with its envelope) as an instance of `cls`."""
    return from_json(cls, doc, cls.__name__)


# -- schemas -------------------------------------------------------------------------

_NUMBER: dict[str, Any] = {"type": ["number", "null"], "description": "null: not a finite number"}


def schema_of(hint: Any) -> dict[str, Any]:
    """The JSON schema of a type hint, as `to_json` writes it."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        arms = [schema_of(a) for a in args if a is not type(None)]
        if type(None) in args:
            arms.append({"type": "null"})
        return arms[0] if len(arms) == 1 else {"anyOf": arms}
    if hint is float:
        return dict(_NUMBER)
    if hint is bool:
        return {"type": "boolean"}
    if hint is int:
        return {"type": "integer"}
    if hint is str:
        return {"type": "string"}
    if origin is tuple:
        args = typing.get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            return {"type": "array", "items": schema_of(args[0])}
        return {
            "type": "array",
            "prefixItems": [schema_of(a) for a in args],
            "minItems": len(args),
            "maxItems": len(args),
        }
    if isinstance(hint, type) and issubclass(hint, Enum):
        return {"type": "string", "enum": [m.value for m in hint]}
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        hints = _hints(hint)
        props = {name: schema_of(hints[name]) for name in _field_names(hint)}
        out: dict[str, Any] = {
            "type": "object",
            "properties": props,
            "required": list(props),
            "additionalProperties": False,
        }
        doc = (hint.__doc__ or "").strip().splitlines()
        if doc:
            out["description"] = doc[0]
        return out
    raise TypeError(f"no JSON schema for {hint!r}")


def message_schema(cls: type) -> dict[str, Any]:
    """A channel's schema: the type's fields plus the envelope."""
    body = schema_of(cls)
    props: dict[str, Any] = {
        "seq": {
            "type": "integer",
            "minimum": 0,
            "description": "the event's number in the recording",
        }
    }
    if cls.__name__ in ACTION_TYPES:
        props["i"] = {
            "type": "integer",
            "minimum": 0,
            "description": "place in the list of actions the brain returned for event `seq`",
        }
    props.update(body["properties"])
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": schema_name(cls),
        "description": body.get("description", ""),
        "type": "object",
        "properties": props,
        "required": list(props),
        "additionalProperties": False,
    }
