"""Every subcommand's --help lists all its options, and a wrong option shows that subcommand's usage.

The command tree is discovered from the parser itself, so a new subcommand is covered
without touching this file. Expected options come from calling the module's
`configure()` on a fresh parser, independently of how `relayd.cli` wires it in.
"""

from __future__ import annotations

import argparse
import importlib

import pytest

from relayd.cli import command_tree, main

TREE = command_tree()


def _expected_options(module: str) -> list[str]:
    fresh = argparse.ArgumentParser()
    importlib.import_module(module).configure(fresh)
    out: list[str] = []
    for action in fresh._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        out.extend(action.option_strings or [action.metavar or action.dest])
    return out


def test_the_tree_has_every_group() -> None:
    paths = {path for path, _ in TREE}
    assert {
        ("run",),
        ("check-config",),
        ("sim",),
        ("status",),
        ("probe", "wifi"),
        ("probe", "pantilt"),
        ("fake", "robot"),
        ("fake", "rig"),
    } <= paths


@pytest.mark.parametrize(
    ("path", "module"),
    [(p, parser.module) for p, parser in TREE],
    ids=[" ".join(p) for p, _ in TREE],
)
def test_help_lists_every_option(
    path: tuple[str, ...], module: str, capsys: pytest.CaptureFixture[str]
) -> None:
    expected = _expected_options(module)
    assert expected, f"{module} adds no options?"
    with pytest.raises(SystemExit) as exc:
        main([*path, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: relayd {' '.join(path)} ")
    for option in expected:
        assert option in out, f"{option} missing from `relayd {' '.join(path)} --help`"


@pytest.mark.parametrize("path", [p for p, _ in TREE], ids=[" ".join(p) for p, _ in TREE])
def test_unknown_option_shows_the_subcommands_usage(
    path: tuple[str, ...], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main([*path, "--no-such-option"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"usage: relayd {' '.join(path)} ")
    assert f"relayd {' '.join(path)}: error:" in err


def test_unknown_option_after_valid_ones_is_named(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["fake", "robot", "--pty", "--bogus"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: relayd fake robot ")
    assert "unrecognized arguments: --bogus" in err


def test_fake_rig_help_gives_every_default_and_says_the_world_persists(
    capsys: pytest.CaptureFixture[str],
) -> None:
    fresh = argparse.ArgumentParser()
    importlib.import_module("relayd.fakes.rig_cmd").configure(fresh)
    for action in fresh._actions:
        if action.default not in (None, False) and not isinstance(action, argparse._HelpAction):
            assert "default" in (action.help or ""), action.option_strings
    with pytest.raises(SystemExit):
        main(["fake", "rig", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "(default: 6 2)" in out and "(default: -55)" in out
    assert "keeps its state while it serves" in out
