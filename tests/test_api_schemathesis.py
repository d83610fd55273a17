"""Property-based API test: schemathesis generates requests from /openapi.json.

The app is served on an ephemeral 127.0.0.1 port from a background event loop (schemathesis
calls it synchronously with requests). Every response must be a non-5xx, match the status
codes, content types and schemas the document declares, reject what the schema forbids and
accept what it allows. /events is excluded: it is an endless stream (tests/test_api.py covers it).
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from schemathesis import GenerationMode

from drivers.clock import Clock
from relayd.api import make_app, start_api
from relayd.api.demo import populate
from relayd.state import Mode, RelayState

TOKEN = "schemathesis-token"
#: Per operation; bounded so the whole test runs in seconds on a loaded 2-core machine.
MAX_EXAMPLES = 25


class AcceptingControls:
    """Keeps the robot in manual mode so every valid drive command is accepted (200)."""

    def __init__(self) -> None:
        self.calls = 0

    def set_mode(self, mode: Mode) -> None:
        self.calls += 1

    def manual_drive(self, left_mm_s: float, right_mm_s: float) -> None:
        self.calls += 1


@pytest.fixture(scope="module")
def base_url() -> Iterator[str]:
    loop = asyncio.new_event_loop()
    ready = threading.Event()
    box: dict[str, object] = {}

    async def serve() -> None:
        clock = Clock()
        state = RelayState()
        populate(state, clock)
        state.mode = Mode.MANUAL
        app = make_app(state, AcceptingControls(), clock=clock, token=TOKEN, healthz_max_age_s=3600)
        runner, port = await start_api(app, "127.0.0.1", 0)
        box["runner"], box["port"] = runner, port
        ready.set()

    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    asyncio.run_coroutine_threadsafe(serve(), loop).result(10)
    assert ready.wait(10)
    try:
        yield f"http://127.0.0.1:{box['port']}"
    finally:
        runner = box["runner"]
        asyncio.run_coroutine_threadsafe(runner.cleanup(), loop).result(10)  # type: ignore[attr-defined]
        loop.call_soon_threadsafe(loop.stop)
        thread.join(5)
        loop.close()


def test_every_operation_conforms_to_openapi(base_url: str) -> None:
    schema = schemathesis.openapi.from_url(f"{base_url}/openapi.json").exclude(path="/events")
    operations = [result.ok() for result in schema.get_all_operations()]  # type: ignore[union-attr]
    labels = {op.label for op in operations}
    assert {"GET /status", "GET /healthz", "GET /metrics", "POST /api/mode", "POST /api/drive"} <= labels

    for operation in operations:
        # Negative data only exists for operations that take input (the POST bodies).
        modes = list(GenerationMode) if operation.method.upper() == "POST" else [GenerationMode.POSITIVE]
        for mode in modes:
            @settings(max_examples=MAX_EXAMPLES, deadline=None, database=None,
                      suppress_health_check=list(HealthCheck))
            @given(case=operation.as_strategy(mode))
            def check(case: schemathesis.Case) -> None:
                case.call_and_validate(base_url=base_url, headers={"Authorization": f"Bearer {TOKEN}"})

            check()
