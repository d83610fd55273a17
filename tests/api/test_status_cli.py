"""`relayd status` against a real app on a loopback port, and against nothing."""

from __future__ import annotations

import argparse
import io
import json
import socket
from dataclasses import replace

from drivers.transport.clock import Clock
from drivers.transport.health import LinkState
from relayd.api import make_app, start_api
from relayd.api.demo import DemoControls, populate
from relayd.cli import main
from relayd.cli import status as status_cmd
from relayd.runtime.state import RelayState


def _args(url: str, *, as_json: bool = False) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    status_cmd.configure(parser)
    return parser.parse_args([url, *(["--json"] if as_json else []), "--timeout", "2"])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
    return port


async def test_status_table_and_json() -> None:
    clock = Clock()
    state = RelayState()
    populate(state, clock)
    servo = state.health["servo"]
    state.health["servo"] = replace(
        servo, state=LinkState.DOWN, last_error="no answer to GET_POSITION"
    )
    runner, port = await start_api(
        make_app(state, DemoControls(state), clock=clock, token=None), "127.0.0.1", 0
    )
    try:
        out, err = io.StringIO(), io.StringIO()
        assert await status_cmd.run(_args(f"127.0.0.1:{port}"), out, err) == 0
        table = out.getvalue()
        assert "follow / driving" in table
        assert "relay-demo" in table
        assert "< -30 dBm (ok to drive)" in table  # RSSI^l against threshold_l
        assert "-52.0 dBm > -60 dBm (ok to drive)" in table  # RSSI^b against threshold_b
        assert "L 180 mm/s  R 220 mm/s" in table
        assert "0.65 m" in table  # nearest front sonar
        assert "servo" in table and "DOWN" in table and "no answer to GET_POSITION" in table
        assert "link front" in table

        out = io.StringIO()
        assert (
            await status_cmd.run(_args(f"http://127.0.0.1:{port}/status", as_json=True), out, err)
            == 0
        )
        doc = json.loads(out.getvalue())
        assert doc["robot"] == "relay-demo" and len(doc["sonar_mm"]) == 16
    finally:
        await runner.cleanup()


async def test_unreachable_robot_is_a_clear_message_and_exit_1() -> None:
    port = _free_port()
    out, err = io.StringIO(), io.StringIO()
    assert await status_cmd.run(_args(f"http://127.0.0.1:{port}"), out, err) == 1
    assert out.getvalue() == ""
    assert f"cannot reach http://127.0.0.1:{port}/status" in err.getvalue()


def test_cli_entry_point_exit_code() -> None:
    # Through the real dispatcher: `relayd status URL` with nothing listening.
    assert main(["status", f"http://127.0.0.1:{_free_port()}", "--timeout", "1"]) == 1


def test_status_url_normalisation() -> None:
    assert status_cmd.status_url("http://10.0.0.5:8080") == "http://10.0.0.5:8080/status"
    assert status_cmd.status_url("10.0.0.5:8080/") == "http://10.0.0.5:8080/status"
    assert status_cmd.status_url("http://r1/status") == "http://r1/status"


def test_format_tolerates_a_sparse_document() -> None:
    text = status_cmd.format_status(
        {"mode": "hold", "state": "stopped", "reason": "starting", "situation": 0, "thresholds": {}}
    )
    assert "hold / stopped" in text and "RSSI^l leader" in text


def test_format_names_the_robot_as_the_operators_do() -> None:
    doc = {
        "mode": "hold",
        "state": "stopped",
        "reason": "hold",
        "situation": 0,
        "thresholds": {},
        "display_name": "relay 2 (east)",
        "robot": "Pioneer",
    }
    first = status_cmd.format_status(doc).splitlines()[0]
    assert first.startswith("robot") and "relay 2 (east) / Pioneer" in first
    first = status_cmd.format_status({**doc, "display_name": None}).splitlines()[0]
    assert "Pioneer  (relayd" in first
