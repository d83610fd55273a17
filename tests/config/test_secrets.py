"""No secret leaves relayd: not over HTTP, not in the logs.

One whole run of a real in-process `Daemon` on a `FakeRig`, configured as `relayd run`
reads it (AP password and API token in files), with the front radio given a *wrong*
password so a refused login happens too. Logging is set up as the daemon's own
(`relayd.runtime.logsetup`, JSON, debug level) into a buffer for the whole run: start-up,
logins, a session expiry and re-login, API requests with no, wrong and right tokens,
bad input, a mode change, shutdown. Then every HTTP answer and the whole log are
searched for the three secrets: the real password, the wrong one and the token
(also for each one's URL-encoded and base64 forms, in case one is logged that way).
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import io
import json
import logging
import urllib.parse
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import aiohttp
import structlog

from relayd.config.load import load_settings
from relayd.daemon import Daemon
from relayd.fakes.rig import FakeRig
from relayd.runtime.logsetup import setup_logging
from tests.support import until

WRONG_AP_PASSWORD = "Wr0ng-pa55word-for-the-front-radio"


def _forms(secret: str) -> set[str]:
    """The secret and the encodings a careless log line might carry it in."""
    return {
        secret,
        urllib.parse.quote(secret, safe=""),
        urllib.parse.quote_plus(secret),
        base64.b64encode(secret.encode()).decode().rstrip("="),
        base64.b64encode(f"ubnt:{secret}".encode()).decode().rstrip("="),
    }


@contextlib.contextmanager
def captured_logs() -> Iterator[io.StringIO]:
    """relayd's own logging (JSON, debug) into a buffer; the previous set-up restored after."""
    buf = io.StringIO()
    old_structlog = structlog.get_config()
    root = logging.getLogger()
    old_handlers, old_level = root.handlers[:], root.level
    setup_logging("debug", "json", stream=buf)
    root.setLevel(logging.DEBUG)  # aiohttp's and asyncio's debug lines too
    try:
        yield buf
    finally:
        structlog.configure(**old_structlog)
        root.handlers[:] = old_handlers
        root.setLevel(old_level)


async def _exchange(
    session: aiohttp.ClientSession, method: str, url: str, **kw: Any
) -> tuple[int, str]:
    async with session.request(method, url, **kw) as resp:
        body = await resp.text()
        return resp.status, "\n".join(f"{k}: {v}" for k, v in resp.headers.items()) + "\n" + body


async def test_no_secret_in_any_answer_or_log_line(tmp_path: Path) -> None:
    rig = FakeRig(tmp_path)
    await rig.start()
    answers: dict[str, tuple[int, str]] = {}
    try:
        with captured_logs() as logs:
            path = rig.write_config(
                secrets_in_files=True,
                scan={"samples": 5, "width_deg": 60.0},
                ap={"rear": {"poll_s": 0.2}, "front": {"poll_s": 0.2}},
                control={"mode": "hold"},
            )
            wrong = tmp_path / "front-ap-password"
            wrong.write_text(WRONG_AP_PASSWORD + "\n", encoding="utf-8")
            text = path.read_text(encoding="utf-8")
            # The front radio's password_file is the second one in the file: point it elsewhere.
            head, sep, tail = text.partition("[ap.front]")
            path.write_text(
                head + sep + tail.replace(str(tmp_path / "relay1-ap-password"), str(wrong), 1),
                encoding="utf-8",
            )
            settings = load_settings(path)
            assert settings.ap.front is not None and settings.ap.front.password_file == str(wrong)
            assert rig.ap_password not in path.read_text(encoding="utf-8")

            daemon = Daemon(settings, env={})
            task = asyncio.create_task(daemon.run())
            try:
                rear, front = daemon.pollers["rear"], daemon.pollers["front"]
                await until(
                    lambda: (
                        rear.state == "ok"
                        and front.state == "auth_failed"
                        and daemon.state.scan_count >= 1
                    ),
                    "rear up, front refused, a scan",
                )
                relogins = rear.counters["relogins"]
                rig.rear.expire_sessions()
                await until(lambda: rear.counters["relogins"] > relogins, "a re-login")
                base = f"http://127.0.0.1:{daemon.api_port}"
                good = {"Authorization": f"Bearer {rig.api_token}"}
                async with aiohttp.ClientSession() as s:
                    for name in (
                        "/status",
                        "/metrics",
                        "/openapi.json",
                        "/healthz",
                        "/",
                        "/no/such/page",
                        "/static/app.js",
                    ):
                        answers[f"GET {name}"] = await _exchange(s, "GET", base + name)
                    answers["GET /events"] = await _first_event(s, base + "/events")
                    for label, headers in (
                        ("no token", {}),
                        ("wrong token", {"Authorization": "Bearer not-the-token"}),
                        ("AP password as token", {"Authorization": f"Bearer {rig.ap_password}"}),
                        ("token, no Bearer", {"Authorization": rig.api_token}),
                        (
                            "basic auth",
                            {
                                "Authorization": "Basic "
                                + base64.b64encode(f"ubnt:{rig.api_token}x".encode()).decode()
                            },
                        ),
                    ):
                        answers[f"mode, {label}"] = await _exchange(
                            s, "POST", base + "/api/mode", json={"mode": "follow"}, headers=headers
                        )
                        answers[f"drive, {label}"] = await _exchange(
                            s,
                            "POST",
                            base + "/api/drive",
                            json={"left_mm_s": 1, "right_mm_s": 1},
                            headers=headers,
                        )
                    answers["mode, bad body"] = await _exchange(
                        s, "POST", base + "/api/mode", data="{not json", headers=good
                    )
                    answers["mode, bad value"] = await _exchange(
                        s, "POST", base + "/api/mode", json={"mode": rig.api_token}, headers=good
                    )
                    answers["drive, not manual"] = await _exchange(
                        s,
                        "POST",
                        base + "/api/drive",
                        json={"left_mm_s": 1, "right_mm_s": 1},
                        headers=good,
                    )
                    answers["drive, bad field"] = await _exchange(
                        s, "POST", base + "/api/drive", json={"left_mm_s": "x"}, headers=good
                    )
                    answers["mode, right token"] = await _exchange(
                        s, "POST", base + "/api/mode", json={"mode": "manual"}, headers=good
                    )
                    answers["drive, right token"] = await _exchange(
                        s,
                        "POST",
                        base + "/api/drive",
                        json={"left_mm_s": 0, "right_mm_s": 0},
                        headers=good,
                    )
                    answers["mode, back to hold"] = await _exchange(
                        s, "POST", base + "/api/mode", json={"mode": "hold"}, headers=good
                    )
                    answers["GET /status (again)"] = await _exchange(s, "GET", base + "/status")
            finally:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
    finally:
        await rig.stop()

    # The run did what the test claims it did (otherwise the search below proves little).
    codes = {k: v[0] for k, v in answers.items()}
    assert codes["GET /status"] == codes["GET /metrics"] == codes["GET /openapi.json"] == 200
    assert all(
        codes[f"mode, {label}"] == 401
        for label in ("no token", "wrong token", "AP password as token")
    )
    assert codes["mode, bad body"] == codes["mode, bad value"] == 400
    assert codes["drive, not manual"] == 409 and codes["mode, right token"] == 200
    assert codes["drive, right token"] == codes["mode, back to hold"] == 200
    assert codes["GET /no/such/page"] == 404
    status = json.loads(_body(answers["GET /status"][1]))
    assert status["health"]["ap.front"]["connected"] is False
    assert "login refused" in status["health"]["ap.front"]["last_error"]
    log_text = logs.getvalue()
    for event in (
        "airos_auth_failed",
        "airos_session_expired",
        "airos_logged_in",
        "mode_changed",
        "robot_connected",
        "shutting_down",
        "stopped",
    ):
        assert f'"event": "{event}"' in log_text or f'"event":"{event}"' in log_text, event
    # A whole run's worth (the ten refused tokens are two lines: they are rate-limited).
    assert len(log_text.splitlines()) > 20
    assert '"api_auth_failed"' in log_text and '"api_auth_missing"' in log_text

    secrets = {
        "AP password": rig.ap_password,
        "wrong AP password": WRONG_AP_PASSWORD,
        "API token": rig.api_token,
    }
    leaks = [
        (what, where)
        for what, secret in secrets.items()
        for form in _forms(secret)
        for where, (_, text) in [*answers.items(), ("logs", (0, log_text))]
        if form in text
    ]
    assert leaks == []


def _body(exchange: str) -> str:
    """The body part of `_exchange`'s text: headers are `Key: value` lines, then the body."""
    lines = exchange.split("\n")
    for i, line in enumerate(lines):
        if line.startswith("{"):
            return "\n".join(lines[i:])
    raise AssertionError("no JSON body")


async def _first_event(s: aiohttp.ClientSession, url: str) -> tuple[int, str]:
    async with s.get(url) as resp:
        chunks = []
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(1.0):
                async for chunk in resp.content.iter_any():
                    chunks.append(chunk.decode("utf-8", "replace"))
                    if sum(map(len, chunks)) > 2000:
                        break
        return resp.status, "".join(chunks)
