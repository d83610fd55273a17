"""`relayd check-config FILE`: validate a config and print the effective settings."""

from __future__ import annotations

import argparse
import os
import sys

from relayd.config import ConfigError, load_settings, render_settings


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="the TOML config to check")


def run(args: argparse.Namespace) -> int:
    try:
        settings = load_settings(args.file)
    except ConfigError as exc:
        print(f"{args.file}: {len(exc.errors)} error(s)", file=sys.stderr)
        for line in exc.errors:
            print(f"  {line}", file=sys.stderr)
        return 2
    sys.stdout.write(render_settings(settings, os.environ))
    return 0
