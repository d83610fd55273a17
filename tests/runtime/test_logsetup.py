"""relayd's log pipeline (relayd/runtime/logsetup.py) against what an operator and an attacker do.

- A task failing inside the airOS login (an injected exception while the login form,
  password included, is in the frame's locals) is logged by the supervisor with its
  traceback, in JSON and on the console, and the password appears nowhere.
- aiohttp's, asyncio's and Python warnings' lines come out as the same JSON as
  relayd's own, each with its syslog priority prefix (journald's `-p` filter).
- A malformed HTTP request is one INFO line without a traceback, and a flood of them
  stays a few lines; wrong or missing API tokens warn once, then once a minute with a
  count (the API under test is a real server on loopback).
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import json
import logging
import re
import warnings
from collections.abc import Iterator
from typing import Any

import aiohttp
import pytest
import structlog

from drivers.airos.client import AirOsClient
from drivers.airos.fake import FakeAirOs
from relayd.api import make_app
from relayd.api.app import CONTEXT, start_api
from relayd.runtime.logsetup import setup_logging
from relayd.runtime.state import RelayState
from relayd.runtime.supervisor import Supervisor
from tests.support import ManualClock, until

PASSWORD = "Pl41ntext-AP-pa55word"
TOKEN = "a-good-long-api-token-0123456789"
_LINE = re.compile(r"^<(\d)>(\{.*\})$")


@contextlib.contextmanager
def captured(fmt: str = "json", level: str = "info") -> Iterator[io.StringIO]:
    buf = io.StringIO()
    old_structlog = structlog.get_config()
    root = logging.getLogger()
    old_handlers, old_level = root.handlers[:], root.level
    setup_logging(level, fmt, stream=buf)
    try:
        yield buf
    finally:
        structlog.configure(**old_structlog)
        root.handlers[:] = old_handlers
        root.setLevel(old_level)
        logging.captureWarnings(False)


def json_lines(text: str) -> list[tuple[int, dict[str, Any]]]:
    """Every line as (priority, event); asserts each has the prefix and is one JSON object."""
    out = []
    for line in text.splitlines():
        m = _LINE.match(line)
        assert m, f"not a <N>{{json}} line: {line!r}"
        out.append((int(m.group(1)), json.loads(m.group(2))))
    return out


# --- no frame locals ---------------------------------------------------------------------


@pytest.mark.parametrize("fmt", ["json", "console"])
async def test_exception_during_login_never_logs_the_password(fmt: str) -> None:
    radio = FakeAirOs("ubnt", PASSWORD)
    url = await radio.start()
    client = AirOsClient(url, "ubnt", PASSWORD, firmware=6)
    real_request = client._request

    async def request(method: str, path: str, **kw: Any) -> Any:
        if method == "POST" and path == "/login.cgi":
            # The login form (username, password) is built and in _login_v6's locals now.
            raise RuntimeError("injected fault during login")
        return await real_request(method, path, **kw)

    client._request = request  # type: ignore[method-assign]
    supervisor = Supervisor(RelayState())
    supervisor.add("ap.rear", client.login, device="ap.rear")
    try:
        with captured(fmt) as buf:
            supervisor.start()
            await until(
                lambda: "injected fault during login" in buf.getvalue(), "the failure logged"
            )
            await supervisor.stop(0.5)
        text = buf.getvalue()
    finally:
        await client.close(0.1)
        await radio.stop()
    assert "task_failed" in text and "_login_v6" in text, text  # the traceback is there...
    assert PASSWORD not in text, text  # ...without the frames' locals


# --- one pipeline, priority prefix ---------------------------------------------------------


def test_foreign_lines_are_json_with_a_priority_prefix() -> None:
    # setup_logging runs inside catch_warnings, so it is its own captureWarnings that
    # routes the warning (pytest's per-test catch_warnings would undo one made before).
    with warnings.catch_warnings(), captured("json", "debug") as buf:
        warnings.simplefilter("always")
        structlog.get_logger("relayd.test").info("own_line", answer=42)
        structlog.get_logger("relayd.test").debug("own_debug")
        logging.getLogger("aiohttp.server").error("an aiohttp error %s", "here")
        logging.getLogger("asyncio").warning("an asyncio warning")
        logging.getLogger("aiohttp.web").info("an aiohttp info")
        logging.getLogger("asyncio").debug("asyncio debug chatter stays out")
        warnings.warn("a deprecated thing", DeprecationWarning, stacklevel=1)
    lines = json_lines(buf.getvalue())
    by_event = {e["event"].split("\n")[0]: (prio, e) for prio, e in lines}
    assert by_event["own_line"][0] == 6 and by_event["own_line"][1]["answer"] == 42
    assert by_event["own_debug"][0] == 7  # log.level = debug reaches relayd's own loggers
    assert by_event["an aiohttp error here"][0] == 3
    assert by_event["an asyncio warning"][0] == 4
    assert by_event["an aiohttp info"][0] == 6
    assert not any("chatter" in e["event"] for _, e in lines)  # the root stays at info
    warning = [(p, e) for p, e in lines if "a deprecated thing" in e["event"]]
    assert warning and warning[0][0] == 4 and warning[0][1]["logger"] == "py.warnings", lines
    for _, e in lines:
        assert e["timestamp"] and e["level"], e


async def test_asyncio_loop_errors_come_out_as_json() -> None:
    with captured("json") as buf:
        loop = asyncio.get_running_loop()
        loop.call_exception_handler({"message": "something asyncio noticed"})
    ((prio, event),) = json_lines(buf.getvalue())
    assert (
        prio == 3 and "something asyncio noticed" in event["event"] and event["logger"] == "asyncio"
    )


# --- malformed requests and wrong tokens ----------------------------------------------------


async def _raw(port: int, data: bytes) -> bytes:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(data)
        await writer.drain()
        return await asyncio.wait_for(reader.read(4096), 5.0)
    finally:
        writer.close()
        with contextlib.suppress(OSError):
            await writer.wait_closed()


class _Controls:
    def set_mode(self, mode: Any) -> None:
        raise AssertionError("not reached")

    def manual_drive(self, left_mm_s: float, right_mm_s: float) -> None:
        raise AssertionError("not reached")


async def test_malformed_requests_are_info_without_traceback_and_rate_limited() -> None:
    clock = ManualClock(1000.0)
    with captured("json") as buf:
        server, port = await start_api(
            make_app(RelayState(), _Controls(), clock=clock, token=TOKEN), "127.0.0.1", 0
        )
        try:
            for _ in range(20):
                answer = await _raw(port, b"GET /status HTTP/1.1\r\nHost: x\r\nBad Header\r\n\r\n")
                assert b" 400 " in answer.split(b"\r\n")[0], answer
        finally:
            await server.cleanup()
    lines = [(p, e) for p, e in json_lines(buf.getvalue()) if "malformed" in e["event"]]
    assert 1 <= len(lines) <= 2, lines  # 20 requests, one line (two if 10 s went by)
    prio, event = lines[0]
    assert prio == 6 and event["level"] == "info" and "exception" not in event, event
    assert "127.0.0.1" in event["event"] and "header" in event["event"].lower(), event


async def test_wrong_token_warnings_are_rate_limited_with_a_count() -> None:
    clock = ManualClock(1000.0)
    with captured("json") as buf:
        app = make_app(RelayState(), _Controls(), clock=clock, token=TOKEN)
        # The log's rate limit alone, without the backoff that would refuse most of these.
        app[CONTEXT].auth_free_failures = 10**6
        server, port = await start_api(app, "127.0.0.1", 0)
        try:
            async with aiohttp.ClientSession() as session:

                async def post(token: str | None) -> int:
                    headers = {"Authorization": f"Bearer {token}"} if token else {}
                    async with session.post(
                        f"http://127.0.0.1:{port}/api/mode",
                        json={"mode": "follow"},
                        headers=headers,
                    ) as resp:
                        return resp.status

                for _ in range(30):
                    assert await post("wrong-token-guess") == 401
                first = buf.getvalue()
                clock.advance(61.0)
                assert await post("wrong-token-guess") == 401
                assert await post(None) == 401
        finally:
            await server.cleanup()
    failed = [e for _, e in json_lines(first) if e["event"] == "api_auth_failed"]
    assert len(failed) == 1 and failed[0]["count"] == 1, failed
    everything = json_lines(buf.getvalue())
    failed = [e for _, e in everything if e["event"] == "api_auth_failed"]
    assert [e["count"] for e in failed] == [1, 30]  # the 29 held back and the one a minute later
    missing = [(p, e) for p, e in everything if e["event"] == "api_auth_missing"]
    assert len(missing) == 1 and missing[0][0] == 4
    assert TOKEN not in buf.getvalue()


def test_the_command_line_keeps_rich_out_of_the_process() -> None:
    """relayd never renders with rich; a dev install has it, and structlog would load it
    (about 3 MB of the daemon's memory). The command line blocks it, and an exception
    still logs with its traceback."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from relayd import cli\n"
        "sys.argv = ['relayd', 'check-config', '/nonexistent.toml']\n"
        "rc = cli.main()\n"
        "import structlog\n"
        "from relayd.runtime.logsetup import StdStream, setup_logging\n"
        "setup_logging('info', 'console', stream=StdStream('stdout'))\n"
        "try:\n"
        "    1 / 0\n"
        "except ZeroDivisionError:\n"
        "    structlog.get_logger('t').exception('boom')\n"
        "print('RICH', sys.modules.get('rich'), 'RC', rc)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert "RICH None RC 2" in out.stdout, (out.stdout, out.stderr)
    assert "ZeroDivisionError: division by zero" in out.stdout
