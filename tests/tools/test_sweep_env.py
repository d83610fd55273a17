"""The sweep child's environment (relayd/sweep/task.py): a fixed hash seed, and compiled
modules cached in the user's cache directory when the environment forbids writing them
beside the sources, so a sweep does not compile relayd afresh for every worker or run."""

from __future__ import annotations

from pathlib import Path

from relayd.sweep.task import child_env


def test_the_hash_seed_is_fixed_unless_given() -> None:
    assert child_env({})["PYTHONHASHSEED"] == "0"
    assert child_env({"PYTHONHASHSEED": "7"})["PYTHONHASHSEED"] == "7"


def test_no_bytecode_beside_the_sources_becomes_the_users_cache(tmp_path: Path) -> None:
    base = {"PYTHONDONTWRITEBYTECODE": "1", "XDG_CACHE_HOME": str(tmp_path), "PATH": "/bin"}
    env = child_env(base)
    assert "PYTHONDONTWRITEBYTECODE" not in env
    cache = Path(env["PYTHONPYCACHEPREFIX"])
    assert cache == tmp_path / "relayd" / "pycache"
    assert cache.is_dir()
    assert cache.stat().st_mode & 0o077 == 0  # the user's own
    assert env["PATH"] == "/bin"
    assert child_env(base)["PYTHONPYCACHEPREFIX"] == str(cache)  # every run shares it


def test_without_a_writable_cache_directory_nothing_changes(tmp_path: Path) -> None:
    blocked = tmp_path / "a-file"
    blocked.write_text("not a directory", encoding="utf-8")
    env = child_env({"PYTHONDONTWRITEBYTECODE": "1", "XDG_CACHE_HOME": str(blocked)})
    assert env["PYTHONDONTWRITEBYTECODE"] == "1"
    assert "PYTHONPYCACHEPREFIX" not in env


def test_an_environment_that_writes_bytecode_or_names_a_cache_is_kept() -> None:
    assert "PYTHONPYCACHEPREFIX" not in child_env({})
    given = {"PYTHONDONTWRITEBYTECODE": "1", "PYTHONPYCACHEPREFIX": "/somewhere"}
    env = child_env(given)
    assert env["PYTHONDONTWRITEBYTECODE"] == "1"
    assert env["PYTHONPYCACHEPREFIX"] == "/somewhere"
