"""The robot a daemon runs, as every client takes it: the daemon is the authority on its robot.

A client verb that needs the robot's description (its `[gcode]` table, limits, geometry, the
tension rule, the planner's settings) takes it from the daemon it talks to, on
`<prefix>/robot` (docs/zenoh.md), never from a file of its own: a job interpreted with another
robot's G-code origin lands somewhere else. A robot file the user names as well (`--config`)
must describe the same robot; one that differs is refused, naming both robots and what
differs.

Fetching the description is the client library's (`controller.client.description`,
`RobotLink.description`); comparing it with a robot file the user gives is the command line's
(a program that uses the library takes the daemon's robot and names no file). Keys that name
files on the daemon's machine are left out of both (a client may run on another machine).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

from controller.cli.session import DaemonAbsent, InputError
from controller.client.description import (
    ROBOT_KEY,
    NoDescription,
    RobotDescription,
    fetch_description,
    robot_from_text,
)
from controller.client.link import QueryFn, RobotLink
from controller.client.transport import query
from controller.service.config import ConfigError, RobotConfig
from controller.service.textfile import NotUtf8Error, read_text

__all__ = [
    "MAX_DIFFERENCES",
    "ROBOT_KEY",
    "DaemonRobot",
    "NoDescription",
    "RobotMismatch",
    "check_agrees",
    "check_config_with_daemon",
    "daemon_robot",
    "fetch_robot",
    "load_robot_file",
    "robot_differences",
    "robot_from_text",
]

MAX_DIFFERENCES = 6
"""The most differences a refusal lists (then "and N more")."""

DaemonRobot = RobotDescription
"""The robot a daemon runs (`controller.client.description.RobotDescription`)."""


class RobotMismatch(InputError):
    """A robot file given to a client describes another robot than the daemon runs; the
    message names both robots and what differs. Nothing was sent."""


def fetch_robot(
    session: Any, prefix: str, timeout_s: float, query_fn: QueryFn = query
) -> RobotDescription:
    """The robot the daemon on `prefix` runs (`controller.client.description`). Raises
    DaemonAbsent, NoDescription (a Refused; an older daemon), Refused."""
    return fetch_description(session, prefix, timeout_s, query_fn)


def load_robot_file(path: str) -> RobotConfig:
    """A robot file read as a client reads a daemon's description (`robot_from_text`), so the
    two compare. Raises InputError when it cannot be read, is not UTF-8 or is not valid."""
    try:
        text = read_text(path)
    except OSError as exc:
        raise InputError(f"--config {path}: cannot read: {exc.strerror or exc}") from None
    except NotUtf8Error as exc:
        raise InputError(f"--config {path}: {exc} (TOML files must be UTF-8)") from None
    try:
        return robot_from_text(text, path)
    except ConfigError as exc:
        raise InputError(str(exc)) from None


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    return bool(a == b)


def _diff(a: Any, b: Any, path: str, out: list[tuple[str, Any, Any]]) -> None:
    """Append (key path, value in a, value in b) for every leaf where `a` and `b` differ."""
    if dataclasses.is_dataclass(a) and type(a) is type(b):
        for f in dataclasses.fields(a):
            if f.compare:
                name = f"{path}.{f.name}" if path else f.name
                _diff(getattr(a, f.name), getattr(b, f.name), name, out)
        return
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        for k in sorted(set(a) | set(b), key=str):
            _diff(a.get(k), b.get(k), f"{path}.{k}", out)
        return
    if (
        isinstance(a, tuple)
        and isinstance(b, tuple)
        and len(a) == len(b)
        and any(dataclasses.is_dataclass(x) for x in a)
    ):
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _diff(x, y, f"{path}[{i}]", out)
        return
    if not _same(a, b):
        out.append((path, a, b))


def robot_differences(a: RobotConfig, b: RobotConfig) -> list[tuple[str, Any, Any]]:
    """Every setting in which two robots differ, as (key path, value in `a`, value in `b`):
    e.g. ("gcode.origin_m", (0.0, 0.0, 0.0), (-0.1075, -0.1075, 0.1)), named by the robot
    file's keys ("reels[1].gear_ratio": a reel's model holds its keys). Where each was loaded
    from is not a difference. Raises nothing."""
    out: list[tuple[str, Any, Any]] = []
    _diff(dataclasses.replace(a, source=""), dataclasses.replace(b, source=""), "", out)
    return [(key.replace(".reel.", "."), x, y) for key, x, y in out]


def _value_text(v: Any) -> str:
    if isinstance(v, tuple):
        return "[" + ", ".join(_value_text(x) for x in v) + "]"
    if isinstance(v, float):
        return format(v, "g")
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def check_agrees(robot: DaemonRobot, config: RobotConfig, path: str) -> None:
    """Refuse a robot file (`config`, read from `path`) that describes another robot than the
    daemon's. Raises RobotMismatch naming both robots and up to `MAX_DIFFERENCES` settings
    that differ (in `path`, at the daemon)."""
    diffs = sorted(robot_differences(config, robot.config), key=_importance)
    if not diffs:
        return
    shown = ", ".join(
        f"{key} ({_value_text(mine)} in --config, {_value_text(theirs)} at the daemon)"
        for key, mine, theirs in diffs[:MAX_DIFFERENCES]
    )
    more = len(diffs) - MAX_DIFFERENCES
    raise RobotMismatch(
        f"--config {path} (robot {config.name!r}) is not the robot the daemon on"
        f" {robot.prefix} runs ({robot.name!r}, from {robot.source}): they differ in {shown}"
        + (f" and {more} more setting{'s' if more > 1 else ''}" if more > 0 else "")
        + ". The daemon's robot is the one that moves: leave out --config, or give its file"
    )


_FIRST = ("name", "reels", "limits", "gcode", "payload", "tension", "homing")
"""The settings a refusal names first: those that decide where and how the robot moves."""


def _importance(diff: tuple[str, Any, Any]) -> int:
    top = diff[0].split(".")[0].split("[")[0]
    return _FIRST.index(top) if top in _FIRST else len(_FIRST)


def daemon_robot(robot: RobotLink, config_path: str | None = None) -> RobotDescription:
    """The robot the daemon runs (`robot.description()`), checked against the robot file at
    `config_path` when one is given (`check_agrees`).

    Raises DaemonAbsent, Refused (NoDescription: an older daemon), InputError (the file cannot
    be read or is not valid) and RobotMismatch (it describes another robot).
    """
    desc = robot.description()
    if config_path is not None:
        check_agrees(desc, load_robot_file(config_path), config_path)
    return desc


def check_config_with_daemon(
    session: Any, prefix: str, timeout_s: float, config_path: str | None
) -> None:
    """For a verb that takes the robot from the daemon's status as it comes and a robot file
    as a fallback (`view`, `record`): refuse a `config_path` that describes another robot than
    the daemon on `prefix` runs. Nothing to check without a file, or while no daemon answers
    (the verb waits for one).

    Raises InputError (the file cannot be read), RobotMismatch, Refused (the daemon's
    description cannot be used)."""
    if config_path is None:
        return
    try:
        daemon_robot(RobotLink(session=session, prefix=prefix, timeout_s=timeout_s), config_path)
    except DaemonAbsent:
        return
