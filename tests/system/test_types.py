"""mypy, strict (pyproject's [tool.mypy]: relayd/ and drivers/), as one test of the suite.

scripts/test used to run mypy before pytest; on a fresh machine (no .mypy_cache) that
was some 20 s of one core with the whole suite waiting on it. As a test it runs on one
pytest-xdist worker beside the others (tests/conftest.py hands this file out first), and
a type error still fails the run, with mypy's report as the failure.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support import skip_or_fail

ROOT = Path(__file__).resolve().parents[2]
#: A cold run (no cache) on a loaded 2-core machine takes about a minute at worst.
MYPY_TIMEOUT_S = 300


@pytest.mark.timeout(MYPY_TIMEOUT_S + 30)
def test_mypy_strict_is_clean() -> None:
    if importlib.util.find_spec("mypy") is None:
        skip_or_fail("mypy is not installed (pip install -e '.[dev]')")
    # The files and flags come from pyproject.toml, read from the checkout's root.
    done = subprocess.run(
        [sys.executable, "-m", "mypy"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=MYPY_TIMEOUT_S,
        check=False,
    )
    if done.returncode != 0:
        pytest.fail(f"mypy exit {done.returncode}:\n{done.stdout}{done.stderr}", pytrace=False)
    assert done.stdout.startswith("Success:"), done.stdout
