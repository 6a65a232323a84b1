"""The `cablebot` command line: one entry point, one module per group of subcommands.

Each module in `_MODULES` exposes `register(subparsers)`, which adds its subcommands and sets
`func` on each: a callable taking the parsed namespace and returning the exit code.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence
from typing import Any

_MODULES: tuple[str, ...] = (
    "controller.service.daemon",  # run
    "controller.cli.sim",  # sim
    "controller.cli.client",  # list, pose, status, move, path, stop, estop, arm, disarm, ...
    "controller.cli.offline",  # ipk, fpk
    "controller.cli.statics_cmd",  # statics, workspace
    "controller.cli.modes_cmd",  # modes
    "controller.cli.resonance",  # resonance
    "controller.cli.shaper_cmd",  # shaper
    "controller.cli.configs",  # check-config, init-config
    "controller.cli.import_rrf",  # import-rrf
    "controller.cli.monitor",  # monitor
    "controller.cli.jog",  # jog
    "controller.cli.demo",  # demo
    "controller.cli.bench",  # bench
    "controller.cli.view",  # view
    "controller.cli.record",  # record
    "controller.cli.replay",  # replay
    "controller.cli.plot",  # plot
    "controller.cli.calibrate",  # calibrate collect, calibrate solve
    "controller.cli.gcode_verb",  # gcode
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
    parser.add_argument("--version", action="version", version=f"cablebot {version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in _MODULES:
        module = importlib.import_module(name)
        module.register(sub)
    return parser


def version() -> str:
    """The installed cablebot's version ("unknown" when it runs from a tree not installed)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("cablebot")
    except PackageNotFoundError:
        return "unknown"


def verb_list(parser: argparse.ArgumentParser) -> str:
    """Every verb of the parser with its one-line help, one verb a line, for a bare `cablebot`."""
    verbs = _subcommands(parser)
    if verbs is None:
        return ""
    entries = [(a.dest, " ".join((a.help or "").split())) for a in verbs._choices_actions]
    width = max(len(name) for name, _ in entries)
    return "\n".join(f"  {name:<{width}}  {text}" for name, text in entries)


def _parse(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace:
    """`parser.parse_args(argv)`, with the errors a user can act on: a bare `cablebot` lists the
    verbs, an unknown verb or option gets the closest known one ("did you mean"), and arguments
    a verb does not take are reported with that verb's usage rather than the top-level one.
    Exits 2 (argparse) on a usage error."""
    from controller.core.suggest import closest

    verbs = _subcommands(parser)
    if not argv:
        parser.print_usage(sys.stderr)
        print(
            f"commands:\n{verb_list(parser)}\n`cablebot COMMAND -h` describes one",
            file=sys.stderr,
        )
        parser.exit(2)
    first = next((a for a in argv if not a.startswith("-")), None)
    if first is not None and verbs is not None and first not in verbs.choices:
        hint = closest(first, verbs.choices)
        parser.error(
            f"unknown command {first!r}"
            + (f"; did you mean {hint!r}?" if hint else "; `cablebot -h` lists them")
        )
    args, extras = parser.parse_known_args(argv)
    if extras:
        verb = _innermost(parser, args)
        verb.error(f"unrecognized arguments: {' '.join(extras)}" + _option_hints(verb, extras))
    return args


def _option_hints(parser: argparse.ArgumentParser, extras: list[str]) -> str:
    """ "; did you mean ..." for each unknown option among `extras` close to one of the
    parser's own options, or ""."""
    from controller.core.suggest import closest

    options = [s for a in parser._actions for s in a.option_strings if s.startswith("--")]
    hints = []
    for word in extras:
        typed = word.split("=", 1)[0]
        if not typed.startswith("--"):
            continue
        hint = closest(typed, options)
        if hint is not None:
            hints.append(f"{typed}: did you mean {hint}?")
    return "".join(f"; {h}" for h in hints)


def _subcommands(parser: argparse.ArgumentParser) -> argparse._SubParsersAction[Any] | None:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action
    return None


def _innermost(
    parser: argparse.ArgumentParser, args: argparse.Namespace
) -> argparse.ArgumentParser:
    """The parser of the (sub)command that `args` chose, at the deepest level."""
    while True:
        verbs = _subcommands(parser)
        chosen = None if verbs is None else getattr(args, verbs.dest, None)
        if verbs is None or chosen not in verbs.choices:
            return parser
        parser = verbs.choices[chosen]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the `cablebot` command line; returns the process exit code (`controller.cli.exitcodes`).

    A reader that goes away (`cablebot pose | head`) ends the verb quietly, without a
    traceback; so does Ctrl-C.
    """
    from controller.cli import exitcodes

    parser = build_parser()
    args = _parse(parser, list(sys.argv[1:] if argv is None else argv))
    try:
        code: int = args.func(args)
        sys.stdout.flush()
    except BrokenPipeError:
        _silence_stdout()
        return exitcodes.BROKEN_PIPE
    except KeyboardInterrupt:
        return exitcodes.INTERRUPTED
    return code


def _silence_stdout() -> None:
    """Point stdout at /dev/null so that the interpreter's last flush does not fail again."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        return  # not a real file (tests capture it): nothing to flush at exit
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
    finally:
        os.close(devnull)


if __name__ == "__main__":
    sys.exit(main())
