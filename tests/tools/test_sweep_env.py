"""The sweep child's environment (relayd/sweep/task.py): a fixed hash seed, and compiled
modules cached in a private directory when the environment forbids writing them beside
the sources, so a sweep does not compile relayd afresh for every run."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from relayd.sweep.task import child_env


def test_the_hash_seed_is_fixed_unless_given() -> None:
    assert child_env({})["PYTHONHASHSEED"] == "0"
    assert child_env({"PYTHONHASHSEED": "7"})["PYTHONHASHSEED"] == "7"


def test_no_bytecode_beside_the_sources_becomes_one_private_cache() -> None:
    env = child_env({"PYTHONDONTWRITEBYTECODE": "1", "PATH": "/bin"})
    assert "PYTHONDONTWRITEBYTECODE" not in env
    cache = Path(env["PYTHONPYCACHEPREFIX"])
    assert cache.is_dir()
    assert cache.stat().st_mode & 0o077 == 0  # the worker's own (mkdtemp)
    assert env["PATH"] == "/bin"
    # Every run of this worker shares it.
    assert child_env({"PYTHONDONTWRITEBYTECODE": "1"})["PYTHONPYCACHEPREFIX"] == str(cache)


def test_an_environment_that_writes_bytecode_or_names_a_cache_is_kept() -> None:
    assert "PYTHONPYCACHEPREFIX" not in child_env({})
    given = {"PYTHONDONTWRITEBYTECODE": "1", "PYTHONPYCACHEPREFIX": "/somewhere"}
    env = child_env(given)
    assert env["PYTHONDONTWRITEBYTECODE"] == "1"
    assert env["PYTHONPYCACHEPREFIX"] == "/somewhere"


@pytest.mark.parametrize("method", ["spawn", "fork"])
def test_the_cache_is_removed_when_a_multiprocessing_worker_exits(
    tmp_path: Path, method: str
) -> None:
    # Dask's local workers are multiprocessing children; a forked one ends without atexit.
    code = (
        "import multiprocessing as mp, sys\n"
        "def work(q):\n"
        "    from relayd.sweep.task import child_env\n"
        "    q.put(child_env({'PYTHONDONTWRITEBYTECODE': '1'})['PYTHONPYCACHEPREFIX'])\n"
        "if __name__ == '__main__':\n"
        f"    ctx = mp.get_context({method!r}); q = ctx.Queue()\n"
        "    p = ctx.Process(target=work, args=(q,)); p.start()\n"
        "    print(q.get(timeout=60)); p.join(60)\n"
    )
    script = tmp_path / "worker.py"
    script.write_text(code, encoding="utf-8")
    out = subprocess.run(
        [sys.executable, str(script)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
        env=dict(os.environ),
    )
    cache = Path(out.stdout.strip())
    assert cache.name.startswith("relayd-sweep-pycache-")
    assert not cache.exists()
