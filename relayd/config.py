"""relayd's settings: pydantic models for every config key, TOML loading, check-config.

Every key has the paper's default; unknown keys are errors (a typo such as
`kpp = 2` must not silently leave kp at its default on a robot) and come with a
"did you mean" suggestion. Types are strict: `enabled = "off"`, `enabled = 1` and
`kp = "2.5"` are errors, not conversions; an integer is accepted where a float is
expected (`kp = 2` is natural TOML). Floats must be finite. Cross-key rules (threshold
order, distances, `rear_link` needing `[ap.rear]`) run in the same pass as the schema,
so one `check-config` lists every problem. Secrets never live
in the TOML: a section names an environment variable (`password_env`, `token_env`)
or a file (`password_file`, `token_file`) and `resolve_secret` reads it at start-up.
"""

from __future__ import annotations

import ipaddress
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from relayd.config_checks import (
    ap_rules,
    control_rules,
    cross_section_rules,
    message,
    pantilt_rules,
    raise_first,
    undecodable,
    validation_messages,
    with_defaults,
)

DEFAULT_CONFIG_PATH = Path("/etc/relayd/relayd.toml")
BAUD_RATES = (9600, 19200, 38400, 57600, 115200)

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
#: A received signal level: never above 0 dBm at a receiver (a positive value is a sign error).
Dbm = Annotated[float, Field(ge=-120, le=0, allow_inf_nan=False)]


def _list_to_tuple(v: Any) -> Any:
    # TOML has arrays, not tuples: strict mode would refuse every `[a, b, c]`.
    return tuple(v) if isinstance(v, list) else v


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


class RobotSettings(_Section):
    #: What operators call this robot on the live page, /status and the fleet view.
    display_name: Annotated[str, Field(min_length=1, max_length=64)] | None = None
    enabled: bool = True
    port: str = "/dev/relay/base"
    baud: Literal[9600, 19200, 38400, 57600, 115200] = 9600
    subclass: Literal["p3at", "p3at-sh"] | None = None
    lost_after_s: PositiveFloat = 0.5


PulseTriple = Annotated[tuple[
    Annotated[int, Field(ge=400, le=2600)],
    Annotated[int, Field(ge=400, le=2600)],
    Annotated[int, Field(ge=400, le=2600)],
], BeforeValidator(_list_to_tuple)]


def _check_pulses(v: PulseTriple) -> PulseTriple:
    lo, mid, hi = v
    # Decreasing triples are legal: a servo mounted upside down turns the other way.
    if not (lo < mid < hi or lo > mid > hi):
        raise ValueError("pulse widths at -90, 0, +90 degrees must be strictly monotonic")
    return v


class PanTiltSettings(_Section):
    enabled: bool = True
    port: str = "/dev/relay/servo"
    protocol: Literal["maestro", "ssc32"] = "maestro"
    baud: Literal[9600, 19200, 38400, 57600, 115200] = 115200
    scan_channel: Annotated[int, Field(ge=0, le=31)] = 0
    link_channel: Annotated[int, Field(ge=0, le=31)] = 1
    scan_pulse_us: PulseTriple = (1000, 1500, 2000)
    link_pulse_us: PulseTriple = (1000, 1500, 2000)
    limits_deg: Annotated[tuple[Annotated[float, Field(ge=-180, le=180)], Annotated[float, Field(ge=-180, le=180)]],
                          BeforeValidator(_list_to_tuple)] = (-90.0, 90.0)
    speed_deg_s: Annotated[float, Field(gt=0, le=2000)] = 180.0

    _pulses = field_validator("scan_pulse_us", "link_pulse_us")(_check_pulses)

    @field_validator("limits_deg")
    @classmethod
    def _limits_ordered(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not v[0] < v[1]:
            raise ValueError("limits_deg must be [low, high] with low < high")
        return v

    @model_validator(mode="after")
    def _distinct_channels(self) -> PanTiltSettings:
        raise_first(pantilt_rules(self.model_dump()))
        return self


class WifiSettings(_Section):
    enabled: bool = True
    source: Literal["nl80211", "procfs", "iw"] = "nl80211"
    interface: Annotated[str, Field(min_length=1, max_length=15)] = "wlan1"
    procfs_path: str = "/proc/net/wireless"
    sample_hz: Annotated[float, Field(gt=0, le=1000)] = 20.0


class ApSettings(_Section):
    enabled: bool = True
    url: str
    username: str = "ubnt"
    password_env: str | None = None
    password_file: str | None = None
    poll_s: PositiveFloat = 1.0
    timeout_s: PositiveFloat = 2.0
    legacy_tls: bool = False
    #: rear AP only: the MAC of the node behind; None = the strongest station.
    station_mac: str | None = None

    @field_validator("url")
    @classmethod
    def _http(cls, v: str) -> str:
        if not v.startswith(("http://", "https://")):
            raise ValueError("url must start with http:// or https://")
        return v.rstrip("/")

    @model_validator(mode="after")
    def _one_secret_source(self) -> ApSettings:
        raise_first(ap_rules("", self.model_dump()))
        return self


class ApSection(_Section):
    rear: ApSettings | None = None
    front: ApSettings | None = None


class ScanSettings(_Section):
    samples: Annotated[int, Field(ge=3, le=361)] = 25
    width_deg: Annotated[float, Field(gt=0, le=360)] = 180.0
    gamma: PositiveFloat = 10.0
    mode: Literal["step", "continuous"] = "step"
    settle_s: NonNegFloat = 0.05


class ControlSettings(_Section):
    mode: Literal["follow", "hold", "manual"] = "follow"
    threshold_l_dbm: Dbm = -30.0
    threshold_b_dbm: Dbm = -60.0
    hysteresis_db: NonNegFloat = 2.0
    rear_link: Literal["require", "ignore"] = "require"
    kp: NonNegFloat = 1.0
    kd: NonNegFloat = 0.3
    w1: NonNegFloat = 10.0
    w2: Annotated[float, Field(allow_inf_nan=False)] = 150.0
    v_max_mm_s: Annotated[float, Field(gt=0, le=1500)] = 400.0
    threshold_o_m: PositiveFloat = 0.8
    stop_distance_m: NonNegFloat = 0.3
    detect_range_m: PositiveFloat = 3.0
    gamma_o_m: PositiveFloat = 1.0
    alpha_db: NonNegFloat = 30.0
    beta_per_m: NonNegFloat = 1.0
    lost_rssi_dbm: Dbm = -85.0
    manual_deadman_s: PositiveFloat = 0.5
    #: RSSI^b older than this many rear-AP polls is stale (not in the spec; 3 polls).
    rear_stale_polls: Annotated[int, Field(ge=1, le=100)] = 3
    #: "fixed": stop at threshold_b_dbm everywhere; "adaptive": learn the rear hop's
    #: RSSI-to-rate relation and set the limit from it (docs/CONTROL.md section 5.1).
    link_policy: Literal["fixed", "adaptive"] = "fixed"
    #: The throughput the hop behind must carry (Mbit/s, after MAC overhead).
    target_hop_mbps: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] = 10.0
    #: Accepted probability that the hop delivers less than target_hop_mbps where the relay stops.
    outage_probability: Annotated[float, Field(gt=0, lt=0.5, allow_inf_nan=False)] = 0.1
    #: The adaptive limit stays within [threshold_b_min_dbm, threshold_b_max_dbm].
    threshold_b_min_dbm: Dbm = -80.0
    threshold_b_max_dbm: Dbm = -50.0
    #: Share of the PHY rate that reaches the application (802.11 MAC overhead).
    mac_efficiency: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] = 0.5
    #: The model forgets a sample's weight by half over this many rear polls.
    link_half_life_polls: Annotated[float, Field(ge=5, le=10000, allow_inf_nan=False)] = 20.0

    @model_validator(mode="after")
    def _cross_key_rules(self) -> ControlSettings:
        raise_first(control_rules(self.model_dump()))
        return self


class ApiSettings(_Section):
    enabled: bool = True
    #: an IP address (IPv4 or IPv6), not a host name: resolving a name at boot can fail or change
    bind: str = "0.0.0.0"
    port: Annotated[int, Field(ge=0, le=65535)] = 8080
    token_env: str | None = "RELAYD_API_TOKEN"
    token_file: str | None = None

    @model_validator(mode="before")
    @classmethod
    def _one_token_source(cls, data: Any) -> Any:
        # token_env has a default; naming a token_file replaces it unless both were written.
        if isinstance(data, dict) and data.get("token_file") is not None:
            if data.get("token_env") is not None:
                raise ValueError("set at most one of token_env or token_file")
            data = {**data, "token_env": None}
        return data

    @field_validator("bind")
    @classmethod
    def _ip_address(cls, v: str) -> str:
        try:
            ipaddress.ip_address(v)
        except ValueError:
            raise ValueError(f"{v!r} is not an IP address (e.g. 0.0.0.0, 127.0.0.1 or ::)") from None
        return v


class LogSettings(_Section):
    level: Literal["debug", "info", "warning", "error"] = "info"
    format: Literal["json", "console"] = "json"


class Settings(_Section):
    robot: RobotSettings = RobotSettings()
    pantilt: PanTiltSettings = PanTiltSettings()
    wifi: WifiSettings = WifiSettings()
    ap: ApSection = ApSection()
    scan: ScanSettings = ScanSettings()
    control: ControlSettings = ControlSettings()
    api: ApiSettings = ApiSettings()
    log: LogSettings = LogSettings()


class ConfigError(Exception):
    """A config that cannot be used; `errors` lists every problem as 'key.path: message'."""

    def __init__(self, errors: list[str]) -> None:
        super().__init__("\n".join(errors))
        self.errors = errors


def semantic_problems(data: Mapping[str, Any]) -> list[str]:
    """The cross-key rules on a raw config document, whatever else is wrong with it."""
    control = with_defaults(ControlSettings, data.get("control"))
    problems = [*control_rules(control),
                *pantilt_rules(with_defaults(PanTiltSettings, data.get("pantilt"))),
                *cross_section_rules(data, control)]
    ap = data.get("ap")
    for side in ("rear", "front"):
        section = ap.get(side) if isinstance(ap, Mapping) else None
        if isinstance(section, Mapping):
            problems += ap_rules(side, section)
    return [message(p) for p in problems]


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
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError([f"{p}: not valid TOML: {exc}"]) from None
    return parse_settings(data)


def config_warnings(settings: Settings) -> list[str]:
    """Usable but suspicious settings: check-config prints them, `relayd run` logs them."""
    out = []
    for key, section in (("robot.port", settings.robot), ("pantilt.port", settings.pantilt)):
        if section.enabled and "XXXX" in section.port:
            out.append(f"{key}: {section.port!r} looks like a placeholder (XXXX): use your adapter's "
                       "serial, or the udev name (/dev/relay/base, /dev/relay/servo)")
    return out


def secret_file_errors(settings: Settings) -> list[str]:
    """Secret files that cannot be read now (check-config: `relayd run` would refuse to start)."""
    errors = []
    for ref in secret_refs(settings).values():
        if ref.file is not None:
            try:
                resolve_secret(ref, {})
            except ConfigError as exc:
                errors.extend(exc.errors)
    return errors


@dataclass(frozen=True, slots=True)
class SecretRef:
    """Where a secret comes from; `describe()` says so without ever showing it."""

    key: str
    env: str | None
    file: str | None

    def describe(self, environ: Mapping[str, str]) -> str:
        if self.env is not None:
            return f"env {self.env} ({'set' if environ.get(self.env) else 'NOT SET'})"
        if self.file is not None:
            return f"file {self.file} ({'readable' if os.access(self.file, os.R_OK) else 'NOT READABLE'})"
        return "none"


def resolve_secret(ref: SecretRef, environ: Mapping[str, str]) -> str | None:
    """The secret's value, or None when it is not configured; ConfigError if configured but missing."""
    if ref.env is not None:
        value = environ.get(ref.env)
        if not value:
            raise ConfigError([f"{ref.key}: environment variable {ref.env} is not set"])
        return value
    if ref.file is not None:
        try:
            value = Path(ref.file).read_text(encoding="utf-8").strip()
        except OSError as exc:
            raise ConfigError([f"{ref.key}: cannot read {ref.file}: {exc.strerror or exc}"]) from None
        if not value:
            raise ConfigError([f"{ref.key}: {ref.file} is empty"])
        return value
    return None


def secret_refs(settings: Settings) -> dict[str, SecretRef]:
    """Where each secret in use comes from, by owner: "ap.rear", "ap.front", "api"."""
    refs: dict[str, SecretRef] = {}
    for name in ("rear", "front"):
        ap = getattr(settings.ap, name)
        if ap is not None and ap.enabled:
            key = f"ap.{name}.password_file" if ap.password_file else f"ap.{name}.password_env"
            refs[f"ap.{name}"] = SecretRef(key, ap.password_env, ap.password_file)
    api = settings.api
    if api.enabled:
        key = "api.token_file" if api.token_file else "api.token_env"
        refs["api"] = SecretRef(key, api.token_env, api.token_file)
    return refs


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
