"""Loading relayd's config: TOML file -> validated Settings, every problem in one pass.

`load_settings` reads the file (unreadable, non-UTF-8 and malformed TOML each get a
clear error) and hands the document to `parse_settings`, which runs the schema
(relayd.config.model's models) and the cross-key rules (relayd.config.checks) side by side,
so a config with a wrong type *and* inverted thresholds reports both at once.
`config_warnings` names settings that are usable but look wrong (a placeholder
device path); `relayd check-config` prints them and `relayd run` logs them.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from relayd.config.checks import (
    ConfigError,
    ap_rules,
    avoidance_rules,
    control_rules,
    cross_section_rules,
    loads_toml,
    message,
    pantilt_rules,
    undecodable,
    validation_messages,
    with_defaults,
)
from relayd.config.model import (
    ApiSettings,
    AvoidanceSettings,
    ControlSettings,
    FoxgloveSettings,
    PanTiltSettings,
    Settings,
)
from relayd.config.secrets import secret_file_warnings

DEFAULT_CONFIG_PATH = Path("/etc/relayd/relayd.toml")


def semantic_problems(data: Mapping[str, Any]) -> list[str]:
    """The cross-key rules on a raw config document, whatever else is wrong with it."""
    control = with_defaults(ControlSettings, data.get("control"))
    problems = [
        *control_rules(control),
        *pantilt_rules(with_defaults(PanTiltSettings, data.get("pantilt"))),
        *avoidance_rules(with_defaults(AvoidanceSettings, data.get("avoidance"))),
        *cross_section_rules(data, control),
        *_port_rules(data),
    ]
    ap = data.get("ap")
    for side in ("rear", "front"):
        section = ap.get(side) if isinstance(ap, Mapping) else None
        if isinstance(section, Mapping):
            problems += ap_rules(side, section)
    return [message(p) for p in problems]


def _port_rules(data: Mapping[str, Any]) -> list[tuple[str, str]]:
    """The live Foxglove server and the API cannot share a port (the second would fail to bind)."""
    api, fox = data.get("api"), data.get("foxglove")
    if not isinstance(fox, Mapping) or fox.get("enabled") is not True:
        return []
    api = api if isinstance(api, Mapping) else {}
    api_port = api.get("port", ApiSettings().port)
    fox_port = fox.get("port", FoxgloveSettings().port)
    if api.get("enabled", True) is True and fox_port == api_port and fox_port != 0:
        return [
            (
                "foxglove.port",
                f"{fox_port} is also api.port; give the live Foxglove server its own port",
            )
        ]
    return []


def parse_settings(data: Mapping[str, Any]) -> Settings:
    """Validate a config document: every schema error and every cross-key rule, in one pass."""
    semantic = semantic_problems(data)
    try:
        settings = Settings.model_validate(data)
        schema: list[str] = []
    except ValidationError as exc:
        schema = validation_messages(exc, Settings)
    # A model's own validator may have raised the same rule: report it once.
    texts = {m.split(": ", 1)[1] for m in semantic}
    errors = [m for m in schema if m.split(": ", 1)[-1] not in texts] + semantic
    if errors:
        raise ConfigError(errors)
    return settings


def load_settings(path: str | os.PathLike[str]) -> Settings:
    """Read and validate a TOML config, or raise ConfigError naming every bad key."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise ConfigError([f"{p}: cannot read: {exc.strerror or exc}"]) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError([undecodable(raw, exc)]) from None
    try:
        data = loads_toml(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError([f"{p}: not valid TOML: {exc}"]) from None
    return parse_settings(data)


def config_warnings(settings: Settings) -> list[str]:
    """Usable but suspicious settings: check-config prints them, `relayd run` logs them."""
    out = []
    for key, section in (("robot.port", settings.robot), ("pantilt.port", settings.pantilt)):
        if section.enabled and "XXXX" in section.port:
            out.append(
                f"{key}: {section.port!r} looks like a placeholder (XXXX): use your adapter's "
                "serial, or the udev name (/dev/relay/base, /dev/relay/servo)"
            )
    return out + secret_file_warnings(settings)
