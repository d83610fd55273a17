"""Secrets in relayd's settings: where each comes from (an environment variable or a
file, never the TOML), reading it at start-up, and the API token's minimum length.

Apart from relayd.config.model's models so that each room stays readable; relayd.config.model
re-exports every name here.
"""

from __future__ import annotations

import contextlib
import os
import stat
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from relayd.config.checks import ConfigError

if TYPE_CHECKING:
    from relayd.config.model import Settings


def secret_file_warnings(settings: Settings) -> list[str]:
    """Secret files that work but are exposed: readable by every user of the machine, or a
    symbolic link (whoever may change the link chooses the secret). `relayd run` logs these,
    check-config prints them."""
    files = [(ref.key, ref.file) for ref in secret_refs(settings).values() if ref.file]
    if settings.api.enabled and settings.api.tls_key:
        files.append(("api.tls_key", settings.api.tls_key))
    out = []
    for key, path in files:
        try:
            st = os.lstat(path)
        except OSError:
            continue  # unreadable or missing: secret_file_errors says so
        if stat.S_ISLNK(st.st_mode):
            out.append(
                f"{key}: {path} is a symbolic link (to {os.readlink(path)}); name the file itself"
            )
            with contextlib.suppress(OSError):
                st = os.stat(path)
        if st.st_mode & stat.S_IROTH:
            out.append(
                f"{key}: {path} can be read by every user of this machine "
                f"(mode {stat.S_IMODE(st.st_mode):04o}); `chmod 600 {path}` (or 640 with "
                "relayd's group)"
            )
    return out


def secret_file_errors(settings: Settings) -> list[str]:
    """Secret and TLS files that cannot be used now (check-config: `relayd run` would refuse
    to start): unreadable, an API token too short, a certificate that is not one."""
    errors = []
    for owner, ref in secret_refs(settings).items():
        if ref.file is not None:
            try:
                value = resolve_secret(ref, {})
                if owner == "api" and value is not None:
                    check_api_token(ref, value)
            except ConfigError as exc:
                errors.extend(exc.errors)
    if settings.api.enabled:
        from relayd.config.tls import tls_context

        try:
            tls_context(settings.api)
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
            # A FIFO or a device would block the read (check-config once hung on a FIFO).
            if not stat.S_ISREG(os.stat(ref.file).st_mode):
                raise ConfigError([f"{ref.key}: {ref.file} is not a regular file"])
            value = Path(ref.file).read_text(encoding="utf-8").strip()
        except OSError as exc:
            raise ConfigError(
                [f"{ref.key}: cannot read {ref.file}: {exc.strerror or exc}"]
            ) from None
        if not value:
            raise ConfigError([f"{ref.key}: {ref.file} is empty"])
        return value
    return None


#: The API token guards the wheels; anything shorter is guessable across the bridge.
MIN_API_TOKEN_CHARS = 16
#: ... and one of few different characters ("aaaaaaaaaaaaaaaa") is no secret either.
MIN_API_TOKEN_DISTINCT = 6


def check_api_token(ref: SecretRef, token: str) -> str:
    """The token, or ConfigError naming its key when it is too short to be a secret."""
    if len(token) < MIN_API_TOKEN_CHARS:
        raise ConfigError(
            [
                f"{ref.key}: the API token has {len(token)} characters; "
                f"at least {MIN_API_TOKEN_CHARS} are needed (e.g. `openssl rand -hex 16`)"
            ]
        )
    if len(set(token)) < MIN_API_TOKEN_DISTINCT:
        raise ConfigError(
            [
                f"{ref.key}: the API token has only {len(set(token))} different characters; "
                f"a guessable token is refused (make one with `openssl rand -hex 16`)"
            ]
        )
    return token


def secret_refs(settings: Settings) -> dict[str, SecretRef]:
    """Where each secret in use comes from, by owner: "ap.rear", "ap.front", "api"."""
    refs: dict[str, SecretRef] = {}
    for name, ap in (("rear", settings.ap.rear), ("front", settings.ap.front)):
        if ap is not None and ap.enabled:
            key = f"ap.{name}.password_file" if ap.password_file else f"ap.{name}.password_env"
            refs[f"ap.{name}"] = SecretRef(key, ap.password_env, ap.password_file)
    api = settings.api
    if api.enabled:
        key = "api.token_file" if api.token_file else "api.token_env"
        refs["api"] = SecretRef(key, api.token_env, api.token_file)
    return refs
