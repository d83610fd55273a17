"""The suite's leak check (tests/conftest.py) fails a test that leaves a task or timer behind.

Run on tiny probe tests in a separate pytest process with this suite's conftest: a
leak on a test's own loop, on a module-wide loop (where a shared daemon's tasks live
on by design, so only what the test started counts) and on the virtual-time loop
fails; a clean test passes.
"""

from __future__ import annotations

from pathlib import Path

import pytest

pytest_plugins = ["pytester"]

TESTS = Path(__file__).resolve().parents[1]

PROBES = """
import asyncio
import pytest

async def test_leaks_a_task():
    asyncio.get_running_loop().create_task(asyncio.sleep(100))

async def test_leaks_a_timer():
    asyncio.get_running_loop().call_later(100, lambda: None)

@pytest.mark.virtual_time
async def test_leaks_on_virtual_time():
    asyncio.get_running_loop().create_task(asyncio.sleep(100))

@pytest.mark.asyncio(loop_scope="module")
async def test_leaks_on_the_module_loop():
    asyncio.get_running_loop().create_task(asyncio.sleep(100))

@pytest.mark.asyncio(loop_scope="module")
async def test_clean_on_the_module_loop():
    await asyncio.sleep(0)

async def test_clean():
    await asyncio.sleep(0)
"""


def test_every_kind_of_leak_fails_and_clean_tests_pass(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    pytester.makeconftest((TESTS / "conftest.py").read_text())
    pytester.makeini(
        "[pytest]\nasyncio_mode = auto\nasyncio_default_fixture_loop_scope = function\n"
        "markers =\n    virtual_time: probe\n"
    )
    pytester.makepyfile(test_probes=PROBES)
    monkeypatch.setenv("PYTHONPATH", str(TESTS.parent))  # the conftest imports tests.support
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(passed=6, errors=4)
    out = result.stdout.str()
    for name in (
        "test_leaks_a_task",
        "test_leaks_a_timer",
        "test_leaks_on_virtual_time",
        "test_leaks_on_the_module_loop",
    ):
        assert f"ERROR test_probes.py::{name}" in out, out
