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
    "controller.calibrate_cmd",  # calibrate collect, calibrate solve
    "controller.demo",  # demo
    "controller.bench",  # bench
)


def add_xyz_arguments(p: argparse.ArgumentParser) -> None:
    """Add the positional X Y Z arguments (metres) to a subcommand's parser."""
    # Three positionals rather than nargs=3 with a tuple metavar: argparse (3.11) crashes
    # formatting some errors for the latter.
    p.add_argument("x", type=float, metavar="X", help="x in m")
    p.add_argument("y", type=float, metavar="Y", help="y in m")
    p.add_argument("z", type=float, metavar="Z", help="z in m")


def xyz_from_args(args: argparse.Namespace) -> list[float]:
    """The [x, y, z] given with `add_xyz_arguments`."""
    return [float(args.x), float(args.y), float(args.z)]


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
