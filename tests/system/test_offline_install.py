"""The offline install of docs/DEPLOY.md section 1.1, done for real.

A wheelhouse is built from a copy of this checkout with `pip wheel -w wheelhouse .`
(pip's own configuration and index: on a developer machine or CI the index is
reachable, as it is for installing the dev tools). Then, as on the robot laptop, a
fresh venv installs relayd with `pip install --no-index --find-links wheelhouse relayd`,
with pip's configuration files switched off so that nothing but the wheelhouse can
supply a package (the venv is made without pip of its own, which would take longer
than the install: this process's pip installs into it). The installed `relayd` must run: its version, check-config on the
example config, and an import of every runtime module with the live page's files.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from relayd import __version__
from tests.support import skip_or_fail

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
BUILD_TIMEOUT_S = 600
INSTALL_TIMEOUT_S = 300


def _run(
    args: list[str], timeout_s: float, env: dict[str, str] | None = None, cwd: Path | None = None
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        args, capture_output=True, text=True, timeout=timeout_s, env=env, cwd=cwd, check=False
    )


def _source_copy(dest: Path) -> Path:
    """The checkout's files (tracked and new, not ignored), so the build writes nothing here."""
    listed = _run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], 30, cwd=ROOT
    )
    if listed.returncode != 0:
        pytest.skip("not a git checkout: cannot tell sources from build output")
    for name in filter(None, listed.stdout.split("\0")):
        src = ROOT / name
        if src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)
    return dest


def _canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def test_wheelhouse_installs_relayd_without_an_index(tmp_path: Path) -> None:
    source = _source_copy(tmp_path / "src")
    wheelhouse = tmp_path / "wheelhouse"
    built = _run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "-w", str(wheelhouse), "."],
        BUILD_TIMEOUT_S,
        cwd=source,
    )
    if built.returncode != 0:
        skip_or_fail(
            f"cannot build the wheelhouse here (no package index?): {built.stderr[-1500:]}"
        )

    # Every runtime dependency is in it, as a wheel.
    wheels = {_canonical(p.name.split("-")[0]) for p in wheelhouse.glob("*.whl")}
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    for dep in deps:
        assert _canonical(re.split(r"[<>=!~\[; ]", dep, maxsplit=1)[0]) in wheels, dep
    assert "relayd" in wheels

    # The robot: a fresh venv, pip's config files off, the wheelhouse and nothing else.
    # Without its own pip (bootstrapping one costs ~15 s): this process's pip installs into
    # it with --python, the same resolver reading the same wheelhouse the robot's would.
    venv = tmp_path / "venv"
    made = _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], 120)
    assert made.returncode == 0, made.stderr
    env = {k: v for k, v in os.environ.items() if not k.startswith("PIP_")}
    env["PIP_CONFIG_FILE"] = os.devnull
    installed = _run(
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            str(venv / "bin" / "python"),
            "install",
            "--quiet",
            "--no-index",
            "--find-links",
            str(wheelhouse),
            "relayd",
        ],
        INSTALL_TIMEOUT_S,
        env=env,
        cwd=tmp_path,
    )
    assert installed.returncode == 0, installed.stdout + installed.stderr

    relayd = venv / "bin" / "relayd"
    version = _run([str(relayd), "--version"], 60, env=env)
    assert version.returncode == 0 and version.stdout.strip() == f"relayd {__version__}", version
    checked = _run([str(relayd), "check-config", str(ROOT / "config" / "relayd.toml")], 60, env=env)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    probe = (
        "import importlib.resources as r, relayd.daemon, relayd.api.app, drivers.arcos.driver, "
        "drivers.wifi.sources, drivers.airos.poller; "
        "assert (r.files('relayd') / 'api' / 'static' / 'index.html').is_file()"
    )
    imported = _run([str(venv / "bin" / "python"), "-c", probe], 120, env=env, cwd=tmp_path)
    assert imported.returncode == 0, imported.stderr
