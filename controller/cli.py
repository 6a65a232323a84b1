"""The `cablebot` command line: one entry point, one module per group of subcommands.

Each module in `_MODULES` exposes `register(subparsers)`, which adds its subcommands and sets
`func` on each: a callable taking the parsed namespace and returning the exit code.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

_MODULES: tuple[str, ...] = (
    "controller.daemon",  # run
    "controller.sim_cmd",  # sim
    "controller.client",  # pose, status, move, path, stop, estop, arm, disarm, reset, home
    "controller.offline",  # ipk, fpk
    "controller.demo",  # demo
    "controller.bench",  # bench
)


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser with every registered subcommand."""
    parser = argparse.ArgumentParser(
        prog="cablebot",
        description="Controller service and tools for cable-suspended robots.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in _MODULES:
        module = importlib.import_module(name)
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the `cablebot` command line; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    code: int = args.func(args)
    return code


if __name__ == "__main__":
    sys.exit(main())
