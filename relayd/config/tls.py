"""The status API's TLS context, built from `[api] tls_cert` and `tls_key`.

Here, in the config package, because `check-config` builds it to prove the files are
usable (relayd.config.secrets) and the daemon builds it before any device moves; neither
needs the HTTP server for that.
"""

from __future__ import annotations

import ssl

from relayd.config.checks import ConfigError
from relayd.config.model import ApiSettings


def tls_context(api: ApiSettings) -> ssl.SSLContext | None:
    """The server TLS context of `api.tls_cert`/`api.tls_key`; None without them.

    ConfigError names the key whose file cannot be read or used, so `relayd run` exits 2
    before any device moves (the token would otherwise cross the radio in clear text).
    """
    if api.tls_cert is None or api.tls_key is None:
        return None
    for key, path in (("api.tls_cert", api.tls_cert), ("api.tls_key", api.tls_key)):
        try:
            with open(path, "rb") as f:
                f.read(1)
        except OSError as exc:
            raise ConfigError([f"{key}: cannot read {path}: {exc.strerror or exc}"]) from None
    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        # The callback is asked only for an encrypted key: without it OpenSSL prompts for
        # the pass phrase on the terminal (or fails with a traceback under systemd).
        ctx.load_cert_chain(api.tls_cert, api.tls_key, password=_no_passphrase)
    except _EncryptedKey:
        raise ConfigError(
            [
                f"api.tls_key: {api.tls_key} is protected by a pass phrase, which relayd "
                "cannot ask for at start (under systemd nobody can type it); write the key "
                f"without one: `openssl pkey -in {api.tls_key} -out <new file>`, readable "
                "by relayd only"
            ]
        ) from None
    except ssl.SSLError as exc:
        raise ConfigError(
            [
                f"api.tls_cert, api.tls_key: {api.tls_cert} and {api.tls_key} are not a "
                f"PEM certificate and its private key: {exc.reason or exc}"
            ]
        ) from None
    return ctx


class _EncryptedKey(Exception):
    """The key file asked for a pass phrase."""


def _no_passphrase() -> bytes:
    raise _EncryptedKey
