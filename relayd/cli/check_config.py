"""`relayd check-config FILE`: validate a config and print the effective settings.

Exit 2 lists every error at once (schema, cross-key rules, unreadable secret files);
warnings (a placeholder device path) go to stderr without failing the check.
"""

from __future__ import annotations

import argparse
import os
import sys

from relayd.config.load import config_warnings, load_settings
from relayd.config.model import ConfigError, secret_file_errors
from relayd.config.tomlwriter import render_settings


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="the TOML config to check")


def _report(path: str, errors: list[str]) -> int:
    print(f"{path}: {len(errors)} error(s)", file=sys.stderr)
    for line in errors:
        print(f"  {line}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    try:
        settings = load_settings(args.file)
    except ConfigError as exc:
        return _report(args.file, exc.errors)
    errors = secret_file_errors(settings)
    if errors:
        return _report(args.file, errors)
    for line in config_warnings(settings):
        print(f"{args.file}: warning: {line}", file=sys.stderr)
    sys.stdout.write(render_settings(settings, os.environ))
    return 0
