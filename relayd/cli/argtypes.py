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


def scheduler_address(text: str) -> str:
    """A Dask scheduler's address, `tcp://HOST:PORT` or `HOST:PORT` (tcp:// is added).

    Other schemes are refused here with the reason, not left to Dask's tracebacks:
    http:// is the dashboard, not the scheduler; tls:// needs a security configuration
    relayd sweep does not set up; inproc:// is another process's memory.
    """
    value = text.strip()
    scheme, sep, rest = value.partition("://")
    if not sep:
        scheme, rest = "tcp", value
    if scheme in ("http", "https"):
        raise argparse.ArgumentTypeError(
            f"{text!r} is a web address (the dashboard's?); the scheduler listens on "
            "tcp://HOST:8786"
        )
    if scheme != "tcp":
        raise argparse.ArgumentTypeError(
            f"{text!r}: {scheme}:// is not supported; give tcp://HOST:PORT (reach a remote "
            "cluster through an SSH tunnel for encryption)"
        )
    host, colon, port = rest.rpartition(":")
    host = host.strip("[]")
    if not colon or not host or "/" in rest or not port.isdigit() or not 0 < int(port) < 65536:
        raise argparse.ArgumentTypeError(f"{text!r} is not tcp://HOST:PORT")
    return f"tcp://{rest}"
