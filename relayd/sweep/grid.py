"""The sweep grid: scenarios x relay counts x `--set` values x seeds, one `RunSpec` per run.

A `--set KEY=V1,V2,...` key is a dotted path into the scenario document
(`radio.exponent`, `leader.speed_m_s`, `relay.0.control.threshold_b_dbm`). A key that
is not a scenario field but is a key of the daemon's `[control]` or `[scan]` section
(`threshold_b_dbm`, `samples`) is short for `control.KEY` / `scan.KEY`: the scenario's
tables of that name go to every relay's config. Every combination is validated before
anything runs, so a typo fails the sweep at once and names the key.

Each run's parameters (the whole scenario document after the overrides, the relay
count, the seed, the length) are hashed: a finished run is skipped on re-run only when
its recorded hash matches, so editing a scenario file re-runs what it changes.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import re
from dataclasses import dataclass, field
from typing import Any

from relayd.sim.scenario import Scenario, ScenarioError, load_scenario, parse_scenario


class GridError(ValueError):
    """A grid that cannot be run; the message names the option and the key."""


@dataclass(frozen=True, slots=True)
class SetAxis:
    """One `--set`: the key as given (the runs.csv column), its dotted path, its values."""

    key: str
    path: tuple[str, ...]
    values: tuple[Any, ...]


@dataclass(frozen=True, slots=True)
class RunSpec:
    """Everything one run needs; `doc` is the scenario document with the overrides applied."""

    scenario: str
    relays: int
    seed: int
    params: tuple[tuple[str, Any], ...]
    doc: dict[str, Any] = field(compare=False, hash=False)
    seconds: float | None = None
    speed: float | None = None

    @property
    def run_id(self) -> str:
        """The run's folder under DIR/runs/, readable and unique in the grid."""
        parts = [_safe(self.scenario), f"relays-{self.relays}"]
        if self.params:
            parts.append(",".join(f"{_safe(k)}={_safe(_fmt(v))}" for k, v in self.params))
        parts.append(f"seed-{self.seed}")
        return "/".join(parts)

    @property
    def digest(self) -> str:
        """A hash of what determines the results: the parameters and relayd's version (not
        the pace: results do not depend on it). Code changed without a version bump is
        not seen: sweep into a fresh --out after changing the simulator."""
        from relayd import __version__

        blob = json.dumps(
            {
                "doc": self.doc,
                "relays": self.relays,
                "seed": self.seed,
                "seconds": self.seconds,
                "relayd": __version__,
            },
            sort_keys=True,
            default=str,
        )
        return hashlib.sha256(blob.encode()).hexdigest()[:16]

    def payload(self) -> dict[str, Any]:
        """What the worker gets: plain JSON, no objects that need this module to unpickle."""
        return {
            "run_id": self.run_id,
            "scenario_doc": self.doc,
            "relays": self.relays,
            "seed": self.seed,
            "seconds": self.seconds,
            "speed": self.speed,
            "digest": self.digest,
        }


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._=+-]", "_", text)


def _fmt(v: Any) -> str:
    return json.dumps(v) if not isinstance(v, str) else v


def parse_value(text: str) -> Any:
    """A `--set` value: an int, a float, true/false, or else the text itself."""
    t = text.strip()
    if t.lower() in ("true", "false"):
        return t.lower() == "true"
    for conv in (int, float):
        try:
            return conv(t)
        except ValueError:
            pass
    return t


def _config_sections() -> dict[str, set[str]]:
    from relayd.config.model import ControlSettings, ScanSettings

    return {"control": set(ControlSettings.model_fields), "scan": set(ScanSettings.model_fields)}


def parse_set(text: str) -> SetAxis:
    """`KEY=V1,V2,...` -> a SetAxis; a bare daemon key becomes control.KEY or scan.KEY."""
    key, sep, values = text.partition("=")
    key = key.strip()
    if not sep or not key or not values.strip():
        raise GridError(f"--set {text!r}: expected KEY=V1,V2,...")
    path = tuple(key.split("."))
    if path[0] not in Scenario.model_fields:
        owners = [
            sec for sec, keys in _config_sections().items() if path[0] in keys and len(path) == 1
        ]
        if not owners:
            raise GridError(
                f"--set {key}: not a scenario key, nor a key of the daemon's [control] or [scan]"
            )
        path = (owners[0], *path)
    vals = tuple(parse_value(v) for v in values.split(","))
    return SetAxis(key, path, vals)


def apply_override(doc: dict[str, Any], path: tuple[str, ...], value: Any) -> None:
    """Set doc[path] = value, walking dicts by key and lists by index; creates missing tables."""
    node: Any = doc
    for i, part in enumerate(path[:-1]):
        if isinstance(node, list):
            node = node[_index(path, i, len(node))]
            continue
        if part not in node or node[part] is None:
            node[part] = {}
        node = node[part]
    last = path[-1]
    if isinstance(node, list):
        node[_index(path, len(path) - 1, len(node))] = value
    elif isinstance(node, dict):
        node[last] = value
    else:
        raise GridError(f"--set {'.'.join(path)}: {'.'.join(path[:-1])} is not a table")


def _index(path: tuple[str, ...], i: int, n: int) -> int:
    try:
        k = int(path[i])
    except ValueError:
        raise GridError(
            f"--set {'.'.join(path)}: {path[i]!r} must be an index into a list"
        ) from None
    if not 0 <= k < n:
        raise GridError(f"--set {'.'.join(path)}: index {k} out of range (list has {n})")
    return k


def scenario_doc(sc: Scenario) -> dict[str, Any]:
    """The scenario as a plain JSON document that parse_scenario accepts again."""
    doc: dict[str, Any] = json.loads(sc.model_dump_json())
    return doc


def build_grid(
    scenarios: list[str],
    relays: list[int] | None,
    seeds: list[int],
    sets: list[SetAxis],
    *,
    seconds: float | None = None,
    speed: float | None = None,
) -> list[RunSpec]:
    """Every run of the grid, in a fixed order (scenario, set values, relays, seed).

    relays None: each scenario's own default count.
    """
    if not scenarios:
        raise GridError("--scenario: at least one")
    if not seeds:
        raise GridError("--seeds: at least one seed")
    keys = [a.key for a in sets]
    if len(set(keys)) != len(keys):
        raise GridError("--set: each key at most once")
    specs: list[RunSpec] = []
    seen_names: dict[str, str] = {}
    for name in scenarios:
        try:
            base = load_scenario(name)
        except ScenarioError as exc:
            raise GridError(f"--scenario {name}: " + "; ".join(exc.errors)) from None
        if base.name in seen_names and seen_names[base.name] != name:
            raise GridError(f"--scenario {name}: another scenario is also named {base.name!r}")
        seen_names[base.name] = name
        for combo in itertools.product(*(a.values for a in sets)):
            doc = scenario_doc(base)
            for axis, v in zip(sets, combo, strict=True):
                apply_override(doc, axis.path, v)
            params = tuple((a.key, v) for a, v in zip(sets, combo, strict=True))
            for n in relays if relays is not None else [base.relays]:
                try:
                    sc = parse_scenario(copy.deepcopy(doc)).with_relays(n)
                except ScenarioError as exc:
                    where = ", ".join(f"{k}={v}" for k, v in params) or "no --set"
                    raise GridError(
                        f"--scenario {name} ({where}, {n} relays): " + "; ".join(exc.errors)
                    ) from None
                run_doc = scenario_doc(sc)
                for seed in seeds:
                    specs.append(RunSpec(sc.name, n, seed, params, run_doc, seconds, speed))
    return specs
