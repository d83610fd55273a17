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


def test_scheduler_addresses() -> None:
    from relayd.cli.argtypes import scheduler_address

    assert scheduler_address("tcp://10.0.0.5:8786") == "tcp://10.0.0.5:8786"
    assert scheduler_address("host:8786") == "tcp://host:8786"
    assert scheduler_address("tcp://[::1]:8786") == "tcp://[::1]:8786"
    for bad, why in (
        ("garbage", "is not tcp://HOST:PORT"),
        ("http://host:8787", "web address"),
        ("tls://host:8786", "tls:// is not supported"),
        ("inproc://x", "inproc:// is not supported"),
        ("tcp://host", "is not tcp://HOST:PORT"),
        ("tcp://host:99999", "is not tcp://HOST:PORT"),
        ("tcp://:8786", "is not tcp://HOST:PORT"),
    ):
        with pytest.raises(argparse.ArgumentTypeError, match=why):
            scheduler_address(bad)


@pytest.mark.parametrize("address", ["garbage", "http://127.0.0.1:1", "tls://h:1", "inproc://x"])
def test_sweep_refuses_a_scheduler_address_it_cannot_use(
    address: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as done:
        main(["sweep", "--scenario", "corridor", "--scheduler", address])
    assert done.value.code == 2
    err = capsys.readouterr().err
    assert "argument --scheduler:" in err and "Traceback" not in err
