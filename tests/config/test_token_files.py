"""An API token must be a secret, and a token file must be a file (check-config never hangs);
secret files others can read are warned about; a TLS key behind a pass phrase is refused."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from relayd.cli import main
from relayd.config.checks import ConfigError
from relayd.config.secrets import SecretRef, check_api_token, resolve_secret
from tests.support import skip_or_fail

REF = SecretRef("api.token_file", None, "x")


@pytest.mark.parametrize("token", ["aaaaaaaaaaaaaaaa", "abababababababababab", "0123401234012340"])
def test_a_guessable_token_is_refused_naming_the_key(token: str) -> None:
    with pytest.raises(ConfigError, match=r"api\.token_file: the API token has only"):
        check_api_token(REF, token)


def test_a_random_token_passes() -> None:
    assert check_api_token(REF, "3f9c0a1be27d4c58") == "3f9c0a1be27d4c58"


def test_a_fifo_as_token_file_is_refused_without_blocking(tmp_path: Path) -> None:
    fifo = tmp_path / "token"
    os.mkfifo(fifo)
    with pytest.raises(ConfigError, match="is not a regular file"):
        resolve_secret(SecretRef("api.token_file", None, str(fifo)), {})


def _config(tmp_path: Path, token: Path) -> Path:
    cfg = tmp_path / "relayd.toml"
    cfg.write_text(f'[api]\ntoken_file = "{token}"\n[control]\nrear_link = "ignore"\n')
    return cfg


def test_a_token_file_others_can_read_is_a_warning(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    token = tmp_path / "token"
    token.write_text("3f9c0a1be27d4c58a1\n")
    token.chmod(0o644)
    assert main(["check-config", str(_config(tmp_path, token))]) == 0
    err = capsys.readouterr().err
    assert f"warning: api.token_file: {token} can be read by every user" in err
    assert "mode 0644" in err and "chmod 600" in err
    token.chmod(0o600)
    assert main(["check-config", str(_config(tmp_path, token))]) == 0
    assert "api.token_file" not in capsys.readouterr().err


def test_a_token_file_that_is_a_symlink_is_a_warning(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    real = tmp_path / "real-token"
    real.write_text("3f9c0a1be27d4c58a1\n")
    real.chmod(0o600)
    link = tmp_path / "token"
    link.symlink_to(real)
    assert main(["check-config", str(_config(tmp_path, link))]) == 0
    err = capsys.readouterr().err
    assert f"warning: api.token_file: {link} is a symbolic link (to {real})" in err


def test_a_tls_key_with_a_pass_phrase_is_refused_without_a_prompt(tmp_path: Path) -> None:
    openssl = shutil.which("openssl")
    if openssl is None:
        skip_or_fail("the openssl CLI is needed to make a test key")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(
        [
            openssl,
            "req",
            "-x509",
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:prime256v1",
            "-keyout",
            str(key),
            "-out",
            str(cert),
            "-days",
            "1",
            "-subj",
            "/CN=relay1",
            "-passout",
            "pass:secret",
        ],
        check=True,
        capture_output=True,
    )
    assert b"ENCRYPTED" in key.read_bytes()
    cfg = tmp_path / "relayd.toml"
    cfg.write_text(
        f'[api]\ntls_cert = "{cert}"\ntls_key = "{key}"\n[control]\nrear_link = "ignore"\n'
    )
    # No terminal and no stdin: the old code prompted (on a terminal, for ever) or crashed.
    proc = subprocess.run(
        [sys.executable, "-m", "relayd", "check-config", str(cfg)],
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
        start_new_session=True,
    )
    assert proc.returncode == 2, proc.stderr
    assert "api.tls_key:" in proc.stderr and "pass phrase" in proc.stderr
    assert "Traceback" not in proc.stderr and "Enter PEM" not in proc.stderr
