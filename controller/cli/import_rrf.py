"""`cablebot import-rrf CONFIG [CONFIG ...] [-o ROBOT.TOML]`: a cablebot robot file from a
RepRapFirmware Hangprinter configuration.

The files are read in order as RepRapFirmware runs them (`config.g`, then `config-override.g`
where the machine keeps its calibration), by `controller.core.rrf`; the robot file is written by
`controller.core.rrf_robot`, to stdout or to `-o` (never over an existing file without
`--force`; written whole or not at all). On stderr: what the import assumed, and every line or
parameter it did not map with the reason (the file lists them too). The file is then checked as
`cablebot check-config` checks it.

Exit 0: written and valid. 1: a file could not be read or imported (each line at fault is named,
nothing is written), or the robot file was written but does not pass the configuration check
(its problems are listed).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import tomllib
from pathlib import Path
from typing import Any

from controller.cli import exitcodes

MAX_INPUT_BYTES = 1_000_000
"""A RepRapFirmware configuration file is a few kilobytes; a larger file is something else."""

_ME = "cablebot: import-rrf"


class InputError(ValueError):
    """A configuration file that cannot be read as text (missing, binary, too large)."""


def read_config_text(path: str) -> tuple[str, str | None]:
    """The text of the configuration file at `path` and a note when it was not UTF-8 (then
    it is read as Latin-1: only comments carry such bytes in a configuration).

    Raises InputError when it cannot be read, is larger than `MAX_INPUT_BYTES`, is UTF-16 or
    holds NUL bytes (a binary file)."""
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_INPUT_BYTES + 1)
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if len(raw) > MAX_INPUT_BYTES:
        raise InputError(f"{path}: larger than {MAX_INPUT_BYTES:,} bytes: not a config.g")
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise InputError(f"{path}: UTF-16 text: save it as UTF-8 (or ASCII) first")
    raw = raw.removeprefix(b"\xef\xbb\xbf")  # a UTF-8 byte order mark
    if b"\0" in raw:
        raise InputError(f"{path}: a binary file, not a RepRapFirmware configuration")
    try:
        return raw.decode("utf-8"), None
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        note = f"{path}: not UTF-8 (byte 0x{raw[exc.start]:02x} on line {line}): read as Latin-1"
        return raw.decode("latin-1"), note


def check_robot_text(text: str, source: str) -> list[str]:
    """The problems `cablebot check-config` would report for the robot file `text` (none: it
    passes). Raises nothing."""
    from controller.cli.configs import describe
    from controller.service.config import ConfigError, parse_config

    try:
        describe(parse_config(tomllib.loads(text), source))
    except ConfigError as exc:
        return [str(e) for e in exc.errors]
    except (ValueError, tomllib.TOMLDecodeError) as exc:
        return [f"{source}: {exc}"]
    return []


def _write_whole(out: Path, text: str) -> None:
    """Write `text` to `out` through a temporary file in its directory, so that `out` is
    either the whole file or untouched. Raises OSError."""
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", dir=out.parent if str(out.parent) else ".")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, out)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def cmd_import_rrf(args: argparse.Namespace) -> int:
    """`cablebot import-rrf`: read, map, write, check (see the module docstring)."""
    from controller.core.rrf import RrfError, read_rrf
    from controller.core.rrf_robot import robot_draft, robot_toml

    def err(msg: str) -> None:
        print(msg, file=sys.stderr)

    files: list[tuple[str, str]] = []
    notes: list[str] = []
    try:
        for path in args.config:
            text, note = read_config_text(path)
            files.append((path, text))
            if note:
                notes.append(note)
        cfg = read_rrf(files)
    except InputError as exc:
        err(f"{_ME}: {exc}; nothing written")
        return exitcodes.REFUSED
    except RrfError as exc:
        for problem in exc.problems:
            err(f"{_ME}: {problem}")
        err(f"{_ME}: not imported, nothing written")
        return exitcodes.REFUSED
    draft = robot_draft(cfg, name=args.name)
    text = robot_toml(draft, [path for path, _ in files])
    to_stdout = args.output in (None, "-")
    out = None if to_stdout else Path(args.output)
    if out is not None and out.exists() and not args.force:
        err(f"{_ME}: {out} exists; --force to overwrite it (nothing written)")
        return exitcodes.REFUSED

    sources = ", ".join(path for path, _ in files)
    err(
        f"import-rrf: {sources}: a Hangprinter with {cfg.n} anchors ({' '.join(cfg.letters)}), "
        f"the last on top"
    )
    for note in notes + list(draft.remarks):
        err(f"import-rrf: note: {note}")
    if draft.unmapped:
        err(f"import-rrf: not mapped ({len(draft.unmapped)}; the robot file lists them too):")
        for item in draft.unmapped:
            err(f"  {item}")
    if out is None:
        sys.stdout.write(text)
        sys.stdout.flush()
        where, shown = "the robot file to stdout", "<stdout>"
    else:
        try:
            _write_whole(out, text)
        except OSError as exc:
            err(f"{_ME}: cannot write {out}: {exc.strerror or exc}")
            return exitcodes.REFUSED
        where, shown = str(out), str(out)
    err(f"import-rrf: wrote {where}: robot {draft.name.value!r}, {len(draft.reels)} reels")
    problems = check_robot_text(text, shown)
    if problems:
        for p in problems:
            err(f"{_ME}: {p}")
        err(f"{_ME}: the robot file was written but does not pass check-config: edit it")
        return exitcodes.REFUSED
    err(f"import-rrf: {shown} passes check-config")
    return exitcodes.OK


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `import-rrf`."""
    p = sub.add_parser(
        "import-rrf",
        help="write a robot file from a RepRapFirmware Hangprinter config.g",
        description=(
            "Write a cablebot robot file from a RepRapFirmware Hangprinter configuration "
            "(M669 K6): anchors, spools, pulley blocks, line flex, Z limits, speeds. What is "
            "not mapped is listed on stderr, with the reason, and at the end of the file."
        ),
    )
    p.add_argument(
        "config",
        nargs="+",
        metavar="CONFIG",
        help="config.g, then any file it runs that holds settings (config-override.g), in order",
    )
    p.add_argument(
        "-o",
        "--output",
        default=None,
        metavar="ROBOT.TOML",
        help="the robot file to write (default: stdout)",
    )
    p.add_argument(
        "--name", default=None, help="the robot's name (default: M550's, or hangprinter)"
    )
    p.add_argument("--force", action="store_true", help="overwrite the output file if it exists")
    p.set_defaults(func=cmd_import_rrf)
