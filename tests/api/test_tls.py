"""The API token's minimum length, and the optional HTTPS of `api.tls_cert`/`api.tls_key`.

The token crosses the radio link in every control request, so it must be long enough
not to be guessed and, with TLS configured, never in clear text. A short token or an
unusable certificate stops `relayd run` with exit 2 naming the key, before a device is
touched. With a certificate (self-signed here, made by the openssl CLI) the API serves
HTTPS only: a client that trusts the certificate gets /status and can drive, a plain
HTTP request gets nothing.
"""

from __future__ import annotations

import json
import shutil
import ssl
import subprocess
from pathlib import Path

import aiohttp
import pytest

from relayd.config.load import parse_settings
from relayd.config.model import ConfigError
from relayd.config.tomlwriter import dump_toml
from relayd.daemon import Daemon
from relayd.fakes.rig import API_TOKEN_ENV, FakeRig
from tests.support import running, skip_or_fail, until
from tests.tools.test_run_cli import SCAN, clean_env, refused

pytestmark = pytest.mark.slow


def self_signed(tmp: Path) -> tuple[Path, Path]:
    """A certificate for 127.0.0.1 and its key, valid for a day."""
    openssl = shutil.which("openssl")
    if openssl is None:
        skip_or_fail("the openssl CLI is needed to make a test certificate")
    cert, key = tmp / "api-cert.pem", tmp / "api-key.pem"
    subprocess.run(
        [
            openssl,
            "req",
            "-x509",
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:prime256v1",
            "-nodes",
            "-keyout",
            str(key),
            "-out",
            str(cert),
            "-days",
            "1",
            "-subj",
            "/CN=relay1",
            "-addext",
            "subjectAltName=IP:127.0.0.1",
        ],
        check=True,
        capture_output=True,
        timeout=60,
    )
    return cert, key


# --- token length ----------------------------------------------------------------------


@pytest.mark.parametrize("where", ["token_file", "token_env"])
async def test_a_short_api_token_is_refused_with_exit_2(tmp_path: Path, where: str) -> None:
    short = "tooShort-123456"  # 15 characters
    async with FakeRig(tmp_path) as rig:
        env = clean_env()
        if where == "token_file":
            config = rig.write_config(secrets_in_files=True, scan=SCAN)
            (tmp_path / f"{rig.name}-api-token").write_text(short + "\n", encoding="utf-8")
        else:
            config = rig.write_config(scan=SCAN)
            env.update(rig.env)
            env[API_TOKEN_ENV] = short
        err = await refused(rig, config, env)
    assert f"api.{where}" in err and "16" in err, err
    assert short not in err


def test_a_16_character_token_is_accepted(tmp_path: Path) -> None:
    settings = parse_settings(
        {
            "robot": {"enabled": False},
            "pantilt": {"enabled": False},
            "wifi": {"enabled": False},
            "control": {"rear_link": "ignore"},
            "api": {"token_env": "T"},
        }
    )
    Daemon(settings, env={"T": "0123456789abcdef"})
    with pytest.raises(ConfigError, match=r"api\.token_env"):
        Daemon(settings, env={"T": "x" * 15})


# --- TLS -------------------------------------------------------------------------------


def test_tls_keys_come_in_pairs() -> None:
    with pytest.raises(ConfigError, match="tls_cert and tls_key"):
        parse_settings({"api": {"tls_cert": "/etc/relayd/api.pem"}})


@pytest.mark.parametrize("broken", ["tls_cert", "tls_key"])
async def test_an_unreadable_certificate_or_key_exits_2_naming_it(
    tmp_path: Path, broken: str
) -> None:
    cert, key = self_signed(tmp_path)
    async with FakeRig(tmp_path) as rig:
        paths = {"tls_cert": str(cert), "tls_key": str(key)}
        paths[broken] = str(tmp_path / "missing.pem")
        config = rig.write_config(secrets_in_files=True, scan=SCAN, api=paths)
        err = await refused(rig, config)
    assert f"api.{broken}" in err and "missing.pem" in err, err


async def test_a_certificate_that_is_not_one_exits_2(tmp_path: Path) -> None:
    cert, key = self_signed(tmp_path)
    async with FakeRig(tmp_path) as rig:
        config = rig.write_config(
            secrets_in_files=True, scan=SCAN, api={"tls_cert": str(key), "tls_key": str(cert)}
        )  # swapped
        err = await refused(rig, config)
    assert "api.tls_cert" in err and "api.tls_key" in err and "private key" in err, err


async def test_the_api_serves_https_with_a_certificate(tmp_path: Path) -> None:
    cert, key = self_signed(tmp_path)
    async with FakeRig(tmp_path) as rig:
        doc = rig.config_doc(
            api_port=0,
            scan=SCAN,
            control={"mode": "hold"},
            api={"tls_cert": str(cert), "tls_key": str(key)},
        )
        (tmp_path / "tls.toml").write_text(
            dump_toml(doc), encoding="utf-8"
        )  # as an operator writes it
        daemon = Daemon(parse_settings(doc), env=rig.env)
        async with running(daemon):
            await until(lambda: daemon.api_port is not None, "the API to bind")
            port = daemon.api_port
            trust = ssl.create_default_context(cafile=str(cert))
            async with aiohttp.ClientSession() as session:
                async with session.get(f"https://127.0.0.1:{port}/status", ssl=trust) as resp:
                    assert resp.status == 200
                    assert (await resp.json())["mode"] == "hold"
                headers = {"Authorization": f"Bearer {rig.api_token}"}
                async with session.post(
                    f"https://127.0.0.1:{port}/api/mode",
                    ssl=trust,
                    headers=headers,
                    data=json.dumps({"mode": "hold"}),
                ) as resp:
                    assert resp.status == 200, await resp.text()
                # A client that does not trust the certificate is refused by its own TLS...
                with pytest.raises(aiohttp.ClientConnectorCertificateError):
                    async with session.get(f"https://127.0.0.1:{port}/status") as resp:
                        pass
                # ...and plain HTTP gets no answer at all: the token never travels in clear.
                with pytest.raises((aiohttp.ClientError, OSError)):
                    async with session.get(
                        f"http://127.0.0.1:{port}/status", timeout=aiohttp.ClientTimeout(total=5)
                    ) as resp:
                        await resp.read()


# --- check-config sees the same problems ------------------------------------------------


def test_check_config_names_a_short_token_file_and_a_bad_certificate(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from relayd.cli import main

    cert, key = self_signed(tmp_path)
    token = tmp_path / "token"
    token.write_text("short\n", encoding="utf-8")
    base = {
        "robot": {"enabled": False},
        "pantilt": {"enabled": False},
        "wifi": {"enabled": False},
        "control": {"rear_link": "ignore"},
    }
    good = tmp_path / "good.toml"
    good_token = tmp_path / "good-token"
    good_token.write_text("0123456789abcdef" * 2 + "\n", encoding="utf-8")
    good.write_text(
        dump_toml(
            {
                **base,
                "api": {"token_file": str(good_token), "tls_cert": str(cert), "tls_key": str(key)},
            }
        ),
        encoding="utf-8",
    )
    assert main(["check-config", str(good)]) == 0
    bad = tmp_path / "bad.toml"
    bad.write_text(
        dump_toml(
            {
                **base,
                "api": {
                    "token_file": str(token),
                    "tls_cert": str(cert),
                    "tls_key": str(tmp_path / "no-key.pem"),
                },
            }
        ),
        encoding="utf-8",
    )
    capsys.readouterr()
    assert main(["check-config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert (
        "api.token_file" in err and "16" in err and "api.tls_key" in err and "no-key.pem" in err
    ), err
    assert "short" not in err.replace("shorter", "")
