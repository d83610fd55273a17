"""The `relayd` command line: one module per subcommand, dispatched by relayd.cli.dispatch.

Each subcommand module exposes `configure(parser)` and `run(args)`, and is imported only
when used, so `relayd check-config` never loads aiohttp and a probe never starts the daemon.
"""

from relayd.cli.dispatch import build_parser, command_tree, main

__all__ = ["build_parser", "command_tree", "main"]
