"""An API token must be a secret, and a token file must be a file (check-config never hangs)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from relayd.config.checks import ConfigError
from relayd.config.secrets import SecretRef, check_api_token, resolve_secret

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
