"""The pure core imports only pure things: checked in a fresh interpreter.

As aioesphomeapi's own lazy-import test does: importing the decision core must not
load an event loop, an HTTP stack, a serial port, a validation library or the logger, so
the core can be read, tested and reused without them (docs/ARCHITECTURE.md).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

FORBIDDEN = ("asyncio", "aiohttp", "serial", "serial_asyncio_fast", "pydantic", "structlog")
CORE_MODULES = (
    "relayd.core.brain",
    "relayd.core.events",
    "relayd.core.vocab",
    "relayd.core.geometry",
    "relayd.core.control.law",
    "relayd.core.avoid.escape",
    "relayd.core.recovery.machine",
    "relayd.core.link.retreat",
    "relayd.core.scan.tracker",
)


def _loaded_after_import(module: str) -> set[str]:
    code = f"import json, sys\nimport {module}\nprint(json.dumps(sorted(sys.modules)))\n"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    return set(json.loads(out))


@pytest.mark.parametrize("module", CORE_MODULES)
def test_the_core_loads_no_io_library(module: str) -> None:
    loaded = _loaded_after_import(module)
    bad = sorted(m for m in loaded if m.split(".")[0] in FORBIDDEN)
    assert not bad, f"import {module} loads {bad[:8]}"


def test_the_check_sees_a_forbidden_import() -> None:
    """The check itself works: the runtime's bus does load asyncio."""
    assert "asyncio" in _loaded_after_import("relayd.runtime.bus")
