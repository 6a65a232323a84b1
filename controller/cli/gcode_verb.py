"""The `cablebot gcode` verb: its arguments, and which of the dry run, streaming
(`controller.cli.gcode`) or the serial line protocol (`controller.cli.gcode_serial`) runs."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from controller.cli import exitcodes
from controller.cli.gcode import cmd_dry_run, cmd_stream
from controller.cli.gcode_serial import cmd_serial


def cmd_gcode(args: argparse.Namespace) -> int:
    """`gcode FILE`: the dry run, or stream the job to the daemon; `gcode --serial`: serve the
    line protocol on a pseudo-terminal."""
    if args.serial is not None:
        if args.file is not None or args.dry_run:
            print("cablebot gcode: --serial takes no FILE and no --dry-run", file=sys.stderr)
            return exitcodes.USAGE
        return cmd_serial(args)
    if args.file is None:
        print("cablebot gcode: a FILE (or - for standard input) is needed", file=sys.stderr)
        return exitcodes.USAGE
    if args.dry_run:
        return cmd_dry_run(args)
    return cmd_stream(args)


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `gcode`."""
    from controller.cli.client import add_connection_arguments

    p = sub.add_parser(
        "gcode",
        help="run a G-code job (slicer or CAM output); --dry-run plans it offline",
        description=(
            "Run a G-code file on the robot: checked whole against the workspace first, then "
            "streamed to the daemon; --dry-run plans it offline with the robot's limits "
            "(docs/gcode.md)."
        ),
    )
    p.add_argument(
        "file", metavar="FILE", nargs="?", help="G-code file (.gz read as gzip), - for stdin"
    )
    p.add_argument(
        "--config",
        default=None,
        metavar="FILE",
        help=(
            "--dry-run: the robot TOML (default built-in); with a daemon its robot is used, and"
            " a FILE that describes another robot is refused"
        ),
    )
    p.add_argument("--dry-run", action="store_true", help="plan offline, no daemon")
    p.add_argument(
        "--from",
        dest="start",
        type=float,
        nargs=3,
        default=None,
        metavar="M",
        help="--dry-run: start here (robot frame, m) instead of the robot's power-up pose",
    )
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument(
        "--serial",
        nargs="?",
        const="",
        default=None,
        metavar="PATH",
        help="serve the RepRap line protocol on a pseudo-terminal (linked at PATH) for hosts",
    )
    p.add_argument("--wait", action="store_true", help="return when the job has been flown")
    p.add_argument(
        "--wait-timeout",
        type=float,
        default=86400.0,
        metavar="S",
        help="--wait: give up after S seconds (default a day)",
    )
    add_connection_arguments(p)
    p.set_defaults(func=cmd_gcode)
