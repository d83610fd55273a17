"""Replay: the recorded inputs through a new brain, compared with the recorded actions.

The brain reads no clock (the time is in each event), so replay is virtual time at
its simplest: the recorded events, control ticks included, are handed to
`Brain.handle` in their recorded order, as fast as it goes. The brain is built from
the recorded config exactly as the daemon builds it (`relayd.config.params.brain_params`),
so a faithful replay returns, event for event, the very actions that were recorded;
any difference is a *divergence* (a bug in determinism, a lost event, or a brain
changed since the recording).

A what-if (`overrides`) builds a second brain from the recorded config with some keys
changed and compares its decisions with the recorded ones. It is open loop: the
inputs stay what the robot really saw, so it answers "what would the brain have
decided, given what it saw", not "where would the robot have gone".
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from relayd.config.checks import loads_toml
from relayd.config.load import parse_settings
from relayd.config.model import Settings
from relayd.config.params import brain_params
from relayd.core.brain import Brain
from relayd.core.events import Action, Decision, ScanResult
from relayd.core.geometry import wrap_deg
from relayd.core.vocab import Mode
from relayd.record.reader import Recording, action_doc


class OverrideError(ValueError):
    """A --set that does not name a config key or does not validate."""


def parse_override(text: str) -> tuple[str, Any]:
    """`section.key=value` with a TOML value (`2.0`, `"ignore"`, `[1, 2]`); bare words are strings."""
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not key or "." not in key:
        raise OverrideError(f"{text!r}: expected SECTION.KEY=VALUE, e.g. control.kp=2.0")
    raw = raw.strip()
    try:
        value = loads_toml(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return key, value


def apply_overrides(config: Mapping[str, Any], overrides: Sequence[tuple[str, Any]]) -> Settings:
    """The recorded config with `overrides` applied, validated as `relayd run` would."""
    doc: dict[str, Any] = _deep_copy(config)
    for key, value in overrides:
        node = doc
        parts = key.split(".")
        for part in parts[:-1]:
            nxt = node.get(part)
            if not isinstance(nxt, dict):
                raise OverrideError(f"{key}: no section {part!r} in the recorded config")
            node = nxt
        if parts[-1] not in node:
            raise OverrideError(f"{key}: no key {parts[-1]!r} in [{'.'.join(parts[:-1])}]")
        node[parts[-1]] = value
    from relayd.config.model import ConfigError

    try:
        return parse_settings(doc)
    except ConfigError as exc:
        raise OverrideError("; ".join(exc.errors)) from None


def _deep_copy(node: Any) -> Any:
    if isinstance(node, dict):
        return {k: _deep_copy(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_deep_copy(v) for v in node]
    return node


def make_brain(settings: Settings) -> Brain:
    """The brain exactly as `relayd.daemon.Daemon` builds it."""
    return Brain(brain_params(settings), mode=Mode(settings.control.mode))


@dataclass(slots=True)
class Comparison:
    """How one brain's actions compare with the recorded ones, event by event."""

    events: int = 0
    actions: int = 0
    divergences: int = 0
    first: dict[str, Any] | None = None
    max_wheel_diff_mm_s: float = 0.0
    max_bearing_diff_deg: float = 0.0
    diverged_seqs: list[int] = field(default_factory=list)


def _decisions(actions: Sequence[Action]) -> list[Decision]:
    return [a for a in actions if isinstance(a, Decision)]


def _bearings(actions: Sequence[Action]) -> list[float]:
    return [a.estimate.bearing_deg for a in actions if isinstance(a, ScanResult)]


def _diff(a: float, b: float) -> float:
    d = abs(a - b)
    return 0.0 if math.isnan(d) else d


def _angle_diff(a: float, b: float) -> float:
    return _diff(0.0, wrap_deg(a - b))


def compare(recording: Recording, brain: Brain) -> Comparison:
    """Feed every recorded event to `brain`, in order; compare what it returns with the record."""
    out = Comparison()
    for step in recording.steps:
        replayed = brain.handle(step.event)
        out.events += 1
        out.actions += len(step.actions)
        docs = [action_doc(a) for a in replayed]
        if docs == step.docs:
            continue
        out.divergences += 1
        out.diverged_seqs.append(step.seq)
        if out.first is None:
            out.first = {
                "t": step.event.t,
                "seq": step.seq,
                "event": type(step.event).__name__,
                "recorded": step.docs,
                "replayed": docs,
            }
        for rec, rep in zip(_decisions(step.actions), _decisions(replayed), strict=False):
            out.max_wheel_diff_mm_s = max(
                out.max_wheel_diff_mm_s,
                _diff(rec.left_mm_s, rep.left_mm_s),
                _diff(rec.right_mm_s, rep.right_mm_s),
            )
        for rb, pb in zip(_bearings(step.actions), _bearings(replayed), strict=False):
            out.max_bearing_diff_deg = max(out.max_bearing_diff_deg, _angle_diff(rb, pb))
    return out
