"""The import contract in pyproject.toml ([tool.importlinter]) holds, and would catch a breach.

Layers: tools -> daemon -> api, record -> runtime -> config -> core; the core imports no
I/O library and of the drivers only their records; the drivers import nothing of relayd
(docs/ARCHITECTURE.md).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _lint_imports(cwd: Path) -> subprocess.CompletedProcess[str]:
    exe = Path(sys.executable).with_name("lint-imports")
    if not exe.exists():
        pytest.fail("lint-imports is missing: install the dev extra (import-linter)")
    return subprocess.run(
        [str(exe), "--no-cache"], cwd=cwd, capture_output=True, text=True, check=False
    )


def test_the_contract_is_kept() -> None:
    result = _lint_imports(ROOT)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-2000:]
    assert "0 broken" in result.stdout


def test_a_wrong_import_breaks_it(tmp_path: Path) -> None:
    """The core importing the runtime (a layer above it) is reported, naming the import."""
    tree = tmp_path / "tree"
    for name in ("relayd", "drivers"):
        shutil.copytree(ROOT / name, tree / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tree / "pyproject.toml")
    law = tree / "relayd" / "core" / "control" / "law.py"
    law.write_text(law.read_text() + "\nfrom relayd.runtime import bus  # noqa: E402\n")
    result = subprocess.run(
        [str(Path(sys.executable).with_name("lint-imports")), "--no-cache"],
        cwd=tree,
        capture_output=True,
        text=True,
        check=False,
        env={"PYTHONPATH": str(tree), "PATH": "/usr/bin:/bin"},
    )
    assert result.returncode != 0, result.stdout[-2000:]
    assert "relayd.core.control.law -> relayd.runtime.bus" in result.stdout, result.stdout[-3000:]
