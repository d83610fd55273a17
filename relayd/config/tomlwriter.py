"""relayd's settings written out as TOML: config documents for tests and fakes, and
`check-config`'s effective settings with where each secret comes from.

Apart from relayd.config.model because nothing on the daemon's start-up path writes TOML.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from relayd.config.model import Settings, secret_refs


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, (int, float)):
        return repr(v)
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dump_toml(doc: Mapping[str, Any]) -> str:
    """A config document (sections of scalars, lists and sub-tables) as TOML."""
    lines: list[str] = []

    def table(prefix: str, d: Mapping[str, Any]) -> None:
        scalars = {k: v for k, v in d.items() if not isinstance(v, Mapping) and v is not None}
        if scalars or not any(isinstance(v, Mapping) for v in d.values()):
            lines.append(f"[{prefix}]")
            lines.extend(f"{k} = {_toml_value(v)}" for k, v in scalars.items())
            lines.append("")
        for k, v in d.items():
            if isinstance(v, Mapping):
                table(f"{prefix}.{k}", v)

    for name, section in doc.items():
        table(name, section)
    return "\n".join(lines)


def render_settings(settings: Settings, environ: Mapping[str, str]) -> str:
    """The effective settings as TOML, with where each secret comes from (never its value)."""
    lines: list[str] = []

    def section(title: str, values: Mapping[str, Any]) -> None:
        lines.append(f"[{title}]")
        for k, v in values.items():
            if v is not None:
                lines.append(f"{k} = {_toml_value(v)}")
        lines.append("")

    data = settings.model_dump(mode="json")
    for name, values in data.items():
        if name == "ap":
            for side, ap in values.items():
                if ap is not None:
                    section(f"ap.{side}", ap)
        else:
            section(name, values)
    lines.append("# secrets (values never shown):")
    for ref in secret_refs(settings).values():
        lines.append(f"#   {ref.key}: {ref.describe(environ)}")
    return "\n".join(lines) + "\n"
