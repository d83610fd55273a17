"""The shared option types: one message for a bad number, whichever subcommand reads it."""

from __future__ import annotations

import argparse

import pytest

from relayd.cli import main
from relayd.cli.argtypes import positive_float, speed


def test_positive_float_and_speed() -> None:
    assert positive_float("2.5") == 2.5
    assert speed("max") is None and speed("10") == 10.0
    for bad, why in (
        ("abc", "not a number"),
        ("0", "must be > 0"),
        ("-1", "must be > 0"),
        ("nan", "must be > 0"),
    ):
        with pytest.raises(argparse.ArgumentTypeError, match=why):
            positive_float(bad)


@pytest.mark.parametrize(
    "argv",
    [
        ["sim", "--seconds", "abc"],
        ["sweep", "--scenario", "corridor", "--seconds", "abc"],
        ["calibrate", "path-loss", "--from", "x.mcap", "--hop-m", "abc"],
    ],
)
def test_each_subcommand_names_the_bad_number(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert "not a number: 'abc'" in capsys.readouterr().err
