"""Property-based API test: schemathesis generates requests from a real daemon's /openapi.json.

A `Daemon` driving a `FakeRig` runs on a background event loop (schemathesis calls it
synchronously with requests), API on an ephemeral 127.0.0.1 port. It starts in manual
mode and has finished a scan, so /status carries every optional part (last scan, links,
all devices) for the response schemas to be checked against, and every valid drive
command is accepted (200) and sent to the fake robot. POST /api/mode runs last, so its
mode switches cannot turn later drive commands into 409s. Every response must be a
non-5xx, match the status codes, content types and schemas the document declares,
reject what the schema forbids and accept what it allows. /events is excluded: it is an
endless stream (tests/api/test_app.py covers it).
"""

from __future__ import annotations

import asyncio
import contextlib
import tempfile
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from schemathesis import GenerationMode

from drivers.arcos.codec import Command
from relayd.config.load import parse_settings
from relayd.daemon import Daemon
from relayd.fakes.rig import FakeRig
from tests.support import until

#: Per operation and generation mode; bounded so the test runs in seconds on a loaded 2-core machine.
MAX_EXAMPLES = 25
#: Generous: the first scan takes a few seconds, longer on a shared machine.
READY_TIMEOUT_S = 40.0


@dataclass
class Served:
    base_url: str
    token: str
    rig: FakeRig
    daemon: Daemon


@pytest.fixture(scope="module")
def served() -> Iterator[Served]:
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, name="daemon-loop", daemon=True)
    thread.start()
    box: dict[str, object] = {}

    async def start(work: Path) -> Served:
        rig = FakeRig(work)
        box["rig"] = rig
        await rig.start()
        daemon = Daemon(
            parse_settings(rig.config_doc(api_port=0, control={"mode": "manual"})), env=rig.env
        )
        task = asyncio.create_task(daemon.run(), name="daemon")
        box["task"] = task

        def ready() -> bool:
            if task.done():
                task.result()  # a start-up failure, with its own error
            return (
                daemon.api_port is not None
                and daemon.state.last_scan is not None
                and daemon.state.health_now()["robot"].connected
            )

        await until(
            ready, "the daemon serving, scanned, the robot connected", READY_TIMEOUT_S, poll_s=0.1
        )
        return Served(f"http://127.0.0.1:{daemon.api_port}", rig.api_token, rig, daemon)

    async def stop() -> None:
        task = box.get("task")
        if isinstance(task, asyncio.Task):
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        rig = box.get("rig")
        if isinstance(rig, FakeRig):
            await rig.stop()

    with tempfile.TemporaryDirectory(prefix="relayd-st-") as work:
        try:
            yield asyncio.run_coroutine_threadsafe(start(Path(work)), loop).result(
                READY_TIMEOUT_S + 10
            )
        finally:
            asyncio.run_coroutine_threadsafe(stop(), loop).result(30)
            loop.call_soon_threadsafe(loop.stop)
            thread.join(5)
            loop.close()


def test_every_operation_conforms_to_openapi(served: Served) -> None:
    base_url = served.base_url
    schema = schemathesis.openapi.from_url(f"{base_url}/openapi.json").exclude(path="/events")
    operations = [result.ok() for result in schema.get_all_operations()]  # type: ignore[union-attr]
    labels = {op.label for op in operations}
    assert {
        "GET /status",
        "GET /healthz",
        "GET /metrics",
        "POST /api/mode",
        "POST /api/drive",
    } <= labels
    # Mode changes last: until then the daemon stays in manual mode.
    operations.sort(key=lambda op: op.label == "POST /api/mode")
    commands_before = len(served.rig.robot.commands)

    for operation in operations:
        # Negative data only exists for operations that take input (the POST bodies).
        modes = (
            list(GenerationMode)
            if operation.method.upper() == "POST"
            else [GenerationMode.POSITIVE]
        )
        for mode in modes:

            @settings(
                max_examples=MAX_EXAMPLES,
                deadline=None,
                database=None,
                suppress_health_check=list(HealthCheck),
            )
            @given(case=operation.as_strategy(mode))
            def check(case: schemathesis.Case) -> None:
                case.call_and_validate(
                    base_url=base_url, headers={"Authorization": f"Bearer {served.token}"}
                )

            check()

    # The accepted drive commands reached the fake robot as motion.
    moved = [
        arg
        for cmd, arg in served.rig.robot.commands[commands_before:]
        if cmd in (Command.VEL, Command.RVEL) and arg != 0
    ]
    assert moved, "no accepted drive command reached the robot"
