"""The robustness section of report.md: clean share with a Wilson interval, failures by
category, the worst worlds with the command that reproduces each.

A run is clean when the leader reached its goal, the link never broke, nothing collided and
every relay ended on the link rule. It reads runs.csv's per-relay columns (<relay>_reason).
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from relayd.core.vocab import LINK_RULE_ENDS

#: Reasons that end a relay on the paper's stop rule (or still following the leader).
LINK_RULE = frozenset(str(r) for r in LINK_RULE_ENDS)


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of k successes in n trials (95 % by default)."""
    if n == 0:
        return 0.0, 1.0
    p = k / n
    c = (p + z * z / (2 * n)) / (1 + z * z / n)
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, c - h), min(1.0, c + h)


def _reasons(row: dict[str, Any]) -> list[str]:
    return list(_relay_reasons(row).values())


def category(row: dict[str, Any]) -> str:
    """'clean' or the first failure that applies, in order of gravity."""
    if int(float(row.get("collisions") or 0)) > 0:
        return "collision"
    if row.get("link_broken_at_s") not in ("", None):
        return "link broke"
    if str(row.get("goal_reached")) != "True":
        return "leader never arrived"
    for relay, reason in _relay_reasons(row).items():
        if not _on_rule(row, relay, reason):
            return "stuck avoiding" if "avoid" in reason or reason == "obstacle" else "lost"
    return "clean"


def _relay_reasons(row: dict[str, Any]) -> dict[str, str]:
    return {
        k.removesuffix("_reason"): str(v)
        for k, v in row.items()
        if k.endswith("_reason") and v not in ("", None)
    }


def _on_rule(row: dict[str, Any], relay: str, reason: str) -> bool:
    """summary.json's on_link_rule for the relay (its `obstacle` end counts when it was
    still getting somewhere, relayd.sim.summary.ended_on_rule); a runs.csv written before
    that column was kept falls back to the reason alone."""
    flag = row.get(f"{relay}_on_rule")
    if flag in ("", None):
        return reason in LINK_RULE
    return str(flag) == "True"


def _setting(row: dict[str, Any], set_keys: Sequence[str]) -> str:
    return ", ".join(f"{k}={row.get(k, '')}" for k in set_keys)


def kind(row: dict[str, Any]) -> str:
    """A generated world's kind (generated-office-12 -> office), else the scenario's name."""
    name = str(row.get("scenario", ""))
    if name.startswith("generated-"):
        return name.removeprefix("generated-").rsplit("-", 1)[0]
    return name


def _natural(text: str) -> list[tuple[int, float | str]]:
    """A sort key that orders numbers by value ("=9" before "=10", "-75" before "-70")."""
    parts = re.findall(r"-?\d+(?:\.\d+)?|[^-\d]+|-", text)
    out: list[tuple[int, float | str]] = []
    for p in parts:
        try:
            out.append((0, float(p)))
        except ValueError:
            out.append((1, p))
    return out


def _generated_kinds(rows: Sequence[dict[str, Any]]) -> set[str]:
    return {kind(r) for r in rows if str(r.get("scenario", "")).startswith("generated-")}


def _by_setting(ok: Sequence[dict[str, Any]], set_keys: Sequence[str], by_kind: bool) -> list[str]:
    """One row per combination of `--set` values (and per generated kind with `by_kind`):
    the laws side by side on the same worlds."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in ok:
        name = _setting(r, set_keys)
        if by_kind:
            name = f"{kind(r)}{', ' + name if name else ''}"
        groups.setdefault(name, []).append(r)
    cats = sorted({category(r) for r in ok} - {"clean"})
    lines = [
        "| setting | clean | Wilson 95 % | " + " | ".join(cats) + " |",
        "|---|---|---|" + "---|" * len(cats),
    ]
    for name, rs in sorted(groups.items(), key=lambda kv: _natural(kv[0])):
        k = sum(category(r) == "clean" for r in rs)
        lo, hi = wilson(k, len(rs))
        counts = Counter(category(r) for r in rs)
        lines.append(
            f"| {name} | {k}/{len(rs)} ({100 * k / len(rs):.1f} %) | "
            f"{100 * lo:.1f}-{100 * hi:.1f} % | " + " | ".join(str(counts[c]) for c in cats) + " |"
        )
    return [*lines, ""]


def _repro_ref(row: dict[str, Any]) -> str:
    ref = str(row["scenario"])
    if ref.startswith("generated-"):
        ref = "generated:" + ref.removeprefix("generated-").replace("-", ":", 1)
    return ref


def draw_world(row: dict[str, Any], path: Path) -> bool:
    """The run's world (walls, boxes, the leader's planned route, the convoy's start) as a
    map, for the report's worst runs; False when the scenario cannot be loaded here."""
    from relayd.sim.plots import available, plot_map
    from relayd.sim.scenario import ScenarioError, load_scenario
    from relayd.sim.world import World

    if not available():
        return False
    try:
        scenario = load_scenario(_repro_ref(row))
    except (ScenarioError, OSError):
        return False
    # The run's relay count; its --set values are daemon keys and change nothing drawn.
    plot_map(World(scenario.with_relays(int(row["relays"])), int(row["seed"])), [], path)
    return True


def section(
    rows: Sequence[dict[str, Any]], set_keys: Sequence[str] = (), maps: Path | None = None
) -> list[str]:
    """The report's robustness section; with `maps` (the report's folder) each worst run's
    world is drawn to maps/plots/worst-K.png and shown under its line."""
    ok = [r for r in rows if r.get("status") == "ok" and _reasons(r)]
    if not ok:
        return []
    cats = Counter(category(r) for r in ok)
    lo, hi = wilson(cats["clean"], len(ok))
    lines = [
        "## Robustness",
        "",
        f"Clean: {cats['clean']}/{len(ok)} ({100 * cats['clean'] / len(ok):.1f} %), "
        f"Wilson 95 % interval {100 * lo:.1f}-{100 * hi:.1f} %"
        + (" (every setting pooled; each apart below)." if set_keys else "."),
        "",
        "| outcome | runs |",
        "|---|---|",
        *(f"| {c} | {n} |" for c, n in sorted(cats.items())),
        "",
    ]
    by_kind = len(_generated_kinds(ok)) > 1
    if set_keys or by_kind:
        lines += _by_setting(ok, set_keys, by_kind)
    worst = sorted(ok, key=lambda r: float(r.get("min_e2e_mbps") or 0))
    worst = [r for r in worst if category(r) != "clean"][:5] or worst[:5]
    lines += [
        "Worst runs (the failures, else all runs; lowest minimum end-to-end throughput first):",
        "",
    ]
    for k, r in enumerate(worst, 1):
        setting = _setting(r, set_keys)
        lines.append(
            f"- {r['scenario']} seed {r['seed']}{', ' + setting if setting else ''} "
            f"({category(r)}): "
            f"`relayd sim --scenario {_repro_ref(r)} --relays {r['relays']} --seed {r['seed']}`"
            + (" with that setting in the scenario (--save-scenario, then edit)" if setting else "")
        )
        png = Path("plots") / f"worst-{k}.png"
        if maps is not None and draw_world(r, maps / png):
            lines += [
                "",
                f"  ![{r['scenario']}: the world and the leader's route]({png.as_posix()})",
                "",
            ]
    return [*lines, ""]
