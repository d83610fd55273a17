"""argparse value types the subcommands share, so each option says the same thing on bad input."""

from __future__ import annotations

import argparse


def positive_float(text: str) -> float:
    """A number > 0; anything else is the option's usage error, naming the value."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return v


def speed(text: str) -> float | None:
    """A pace over wall time, or 'max': as fast as the CPU goes (virtual time never waits)."""
    return None if text == "max" else positive_float(text)
