"""The `[fleet]` config of `relayd fleet`: which relays, their tokens, where they started.

    [fleet]
    bind = "127.0.0.1"        # the fleet page; hold-all needs no token here, so keep it local
    port = 8090
    poll_s = 0.5              # each relay's /status, on its own task
    timeout_s = 1.0           # a relay that has not answered by then is shown as not answering

    [[fleet.relay]]           # in chain order: the one nearest the leader first
    name = "relay1"
    url = "http://192.168.1.31:8080"
    token_file = "/etc/relayd/relay1.token"   # or token_env = "...", or token = "..."
    origin = [0.0, 0.0, 0.0]  # where its odometry started: x_m, y_m, heading_deg on a shared map

The chain is also each relay's leader: relay k follows relay k-1 (`follow_keys` gives
each its `[control] leader_url` and `leader_origin` from the URLs and origins here).

Other sections of the file are ignored, so one site file may carry both a robot's
config and the fleet's. Unknown keys inside `[fleet]` are errors, as in relayd.config.model.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any
from urllib.parse import urlsplit

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from relayd.config.checks import loads_toml, undecodable, validation_messages
from relayd.config.model import ConfigError, SecretRef, resolve_secret
from relayd.core.trail.align import frame_between

DEFAULT_PORT = 8090
PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]


def normalise_url(url: str) -> str:
    """ "192.168.1.31:8080" -> "http://192.168.1.31:8080"; a trailing /status or / is dropped."""
    url = url.strip()
    if "://" not in url:
        url = "http://" + url
    url = url.rstrip("/")
    if url.endswith("/status"):
        url = url[: -len("/status")]
    parts = urlsplit(url)
    try:
        parts.port  # noqa: B018 - raises ValueError for a port that is not a number
    except ValueError:
        raise ValueError(f"bad port in {url!r}") from None
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ValueError(f"not an http(s) URL of a relay: {url!r}")
    if parts.query or parts.fragment:
        raise ValueError(f"a relay's base URL has no query or fragment: {url!r}")
    return url


class RelayEntry(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    url: str
    name: str | None = None
    token: str | None = None
    token_file: str | None = None
    token_env: str | None = None
    origin: tuple[Finite, Finite, Finite] | None = None

    @field_validator("url")
    @classmethod
    def _url(cls, v: str) -> str:
        return normalise_url(v)

    @model_validator(mode="after")
    def _one_token(self) -> RelayEntry:
        if sum(x is not None for x in (self.token, self.token_file, self.token_env)) > 1:
            raise ValueError("set at most one of token, token_file or token_env")
        return self


class FleetSection(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    bind: str = "127.0.0.1"
    port: int = Field(DEFAULT_PORT, ge=0, le=65535)
    poll_s: PositiveFloat = 0.5
    timeout_s: PositiveFloat = 1.0
    stale_after_s: PositiveFloat = 2.0
    #: Names (beyond IP addresses and localhost) the page may be reached by: a browser's
    #: Host and Origin must be one of them (DNS rebinding, relayd/api/hostcheck.py).
    allowed_hosts: list[str] = Field(default_factory=list)
    relay: list[RelayEntry] = Field(default_factory=list)


@dataclass(frozen=True, slots=True)
class Relay:
    """One relay as the fleet polls it; `token` is resolved (never logged or served)."""

    name: str
    url: str
    token: str | None = None
    origin: tuple[float, float, float] | None = None

    def __repr__(self) -> str:  # keep the token out of any repr that reaches a log
        return f"Relay(name={self.name!r}, url={self.url!r}, token={'set' if self.token else None})"


@dataclass(frozen=True, slots=True)
class FleetSettings:
    relays: tuple[Relay, ...]
    bind: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    poll_s: float = 0.5
    timeout_s: float = 1.0
    stale_after_s: float = 2.0
    allowed_hosts: tuple[str, ...] = ()


def _unique_names(relays: Sequence[Relay]) -> list[str]:
    seen: set[str] = set()
    errors = []
    for r in relays:
        if r.name in seen:
            errors.append(f"fleet.relay: two relays are named {r.name!r}")
        seen.add(r.name)
    return errors


def parse_fleet(data: Mapping[str, Any], environ: Mapping[str, str] | None = None) -> FleetSettings:
    """The `[fleet]` section of a parsed TOML document, tokens resolved; ConfigError names each problem."""
    environ = os.environ if environ is None else environ
    try:
        section = FleetSection.model_validate(data.get("fleet", {}))
    except ValidationError as exc:
        raise ConfigError([f"fleet.{m}" for m in validation_messages(exc)]) from None
    relays: list[Relay] = []
    errors: list[str] = []
    for i, entry in enumerate(section.relay):
        token = entry.token
        if entry.token_file is not None or entry.token_env is not None:
            key = (
                f"fleet.relay[{i}].token_file"
                if entry.token_file
                else f"fleet.relay[{i}].token_env"
            )
            try:
                token = resolve_secret(SecretRef(key, entry.token_env, entry.token_file), environ)
            except ConfigError as exc:
                errors.extend(exc.errors)
        name = entry.name or urlsplit(entry.url).netloc
        relays.append(Relay(name, entry.url, token, entry.origin))
    errors.extend(_unique_names(relays))
    if errors:
        raise ConfigError(errors)
    return FleetSettings(
        tuple(relays),
        section.bind,
        section.port,
        section.poll_s,
        section.timeout_s,
        section.stale_after_s,
        tuple(section.allowed_hosts),
    )


def load_fleet(
    path: str | os.PathLike[str], environ: Mapping[str, str] | None = None
) -> FleetSettings:
    p = Path(path)
    try:
        raw = p.read_bytes()
        data = loads_toml(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise ConfigError([f"{p}: {undecodable(raw, exc)}"]) from None
    except OSError as exc:
        raise ConfigError([f"{p}: cannot read: {exc.strerror or exc}"]) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError([f"{p}: not valid TOML: {exc}"]) from None
    return parse_fleet(data, environ)


def relay_from_arg(text: str, token: str | None = None) -> Relay:
    """`--relay URL` or `--relay NAME=URL`."""
    name, sep, url = text.partition("=")
    if not sep or "://" in name:
        name, url = "", text
    try:
        clean = normalise_url(url)
    except ValueError as exc:
        raise ConfigError([f"--relay: {exc}"]) from None
    return Relay(name or urlsplit(clean).netloc, clean, token)


def follow_keys(fleet: FleetSettings) -> dict[str, dict[str, object]]:
    """Each relay's `[control]` keys for following the relay ahead of it in the chain: its
    `leader_url` (that relay's API) and, where both have an origin, `leader_origin` (where
    that relay's odometry started, in this one's frame). The first relay follows the person
    and gets none. The same list `[control] leader_url` asks for, read from this file."""
    out: dict[str, dict[str, object]] = {}
    for k, relay in enumerate(fleet.relays):
        keys: dict[str, object] = {}
        if k > 0:
            ahead = fleet.relays[k - 1]
            keys["leader_url"] = ahead.url
            if relay.origin is not None and ahead.origin is not None:
                f = frame_between(relay.origin, ahead.origin)
                keys["leader_origin"] = [round(f.tx_m, 3), round(f.ty_m, 3), round(f.phi_deg, 2)]
        out[relay.name] = keys
    return out
