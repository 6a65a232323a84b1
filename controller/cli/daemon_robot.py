"""The robot a daemon runs, as every client takes it: the daemon is the authority on its robot.

A client verb that needs the robot's description (its `[gcode]` table, limits, geometry, the
tension rule, the planner's settings) takes it from the daemon it talks to, on
`<prefix>/robot` (docs/zenoh.md), never from a file of its own: a job interpreted with another
robot's G-code origin lands somewhere else. A robot file the user names as well (`--config`)
must describe the same robot; one that differs is refused, naming both robots and what
differs.

No argparse here: `fetch_robot`, `check_agrees` and `daemon_robot` take a Zenoh session, a
prefix and a timeout, so any client (the CLI verbs, a client library) uses them alike.

Keys that name files on the daemon's machine (`[zenoh] config_file`, a drive family's file
options such as the CiA 402 `eds`) are the daemon's own: a client neither reads those files
nor compares them (it may run on another machine).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from controller.cli.session import DaemonAbsent, InputError, Refused, query
from controller.service.config import ConfigError, RobotConfig, parse_config, robot_digest
from controller.service.textfile import NotUtf8Error, read_text

ROBOT_KEY = "robot"
"""The daemon's robot description: `<prefix>/robot`."""
MAX_DIFFERENCES = 6
"""The most differences a refusal lists (then "and N more")."""


class NoDescription(Refused):
    """The daemon answers but serves no robot description (a daemon older than the client)."""


class RobotMismatch(InputError):
    """A robot file given to a client describes another robot than the daemon runs; the
    message names both robots and what differs. Nothing was sent."""


@dataclass(frozen=True)
class DaemonRobot:
    """The robot a daemon runs: its name, where the daemon loaded it from, the TOML text as
    loaded, the digest of that text, and the validated configuration a client uses."""

    prefix: str
    name: str
    source: str
    digest: str
    text: str
    config: RobotConfig


def _drop_host_files(data: dict[str, Any]) -> dict[str, Any]:
    """`data` without the keys that name files on the daemon's machine."""
    from drivers import registry

    out = dict(data)
    zen = out.get("zenoh")
    if isinstance(zen, Mapping) and "config_file" in zen:
        out["zenoh"] = {k: v for k, v in zen.items() if k != "config_file"}
    drive = out.get("drive")
    if isinstance(drive, Mapping):
        try:
            fam = registry.family(str(drive.get("kind", "odrive")))
        except registry.UnknownFamilyError:
            return out
        paths = {o.name for o in fam.options if o.kind == "path"}
        out["drive"] = {k: v for k, v in drive.items() if k not in paths}
    return out


def robot_from_text(text: str, source: str) -> RobotConfig:
    """The configuration a client uses of a robot's TOML text: validated as the daemon does,
    the keys that name files on the daemon's machine left out. Raises ConfigError (naming
    `source`) when the text is not a valid robot."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(source, "", f"not valid TOML: {exc}") from None
    return parse_config(_drop_host_files(data), source, text)


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


def fetch_robot(session: Any, prefix: str, timeout_s: float) -> DaemonRobot:
    """The robot the daemon on `prefix` runs, from its `<prefix>/robot` description.

    Raises DaemonAbsent when no daemon answers, NoDescription (a Refused) when it serves no
    description (an older daemon), Refused when its description cannot be used.
    """
    prefix = prefix.rstrip("/")
    try:
        reply = query(session, f"{prefix}/{ROBOT_KEY}", None, timeout_s)
    except DaemonAbsent:
        query(session, f"{prefix}/status", None, timeout_s)  # no daemon: DaemonAbsent
        raise NoDescription(
            f"the daemon on {prefix} serves no robot description ({prefix}/{ROBOT_KEY}): it is"
            " older than this client; update it"
        ) from None
    if not isinstance(reply, dict) or not isinstance(reply.get("toml"), str):
        raise Refused(f"the daemon on {prefix} sent no robot description: {str(reply)[:120]}")
    text: str = reply["toml"]
    digest = robot_digest(text)
    if reply.get("digest") != digest:
        raise Refused(
            f"the robot description of the daemon on {prefix} does not match its digest"
            f" ({reply.get('digest')} sent, {digest} received)"
        )
    source = str(reply.get("source", "?"))
    try:
        cfg = robot_from_text(text, f"the robot of the daemon on {prefix} ({source})")
    except ConfigError as exc:
        raise Refused(f"cannot use the daemon's robot description: {exc}") from None
    return DaemonRobot(prefix, str(reply.get("name", cfg.name)), source, digest, text, cfg)


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
    e.g. ("gcode.origin_m", (0.0, 0.0, 0.0), (-0.1075, -0.1075, 0.1)). Where each was loaded
    from is not a difference. Raises nothing."""
    out: list[tuple[str, Any, Any]] = []
    _diff(dataclasses.replace(a, source=""), dataclasses.replace(b, source=""), "", out)
    return out


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
        + (f" and {more} more settings" if more > 0 else "")
        + ". The daemon's robot is the one that moves: leave out --config, or give its file"
    )


_FIRST = ("name", "reels", "limits", "gcode", "payload", "tension", "homing")
"""The settings a refusal names first: those that decide where and how the robot moves."""


def _importance(diff: tuple[str, Any, Any]) -> int:
    top = diff[0].split(".")[0].split("[")[0]
    return _FIRST.index(top) if top in _FIRST else len(_FIRST)


def daemon_robot(
    session: Any, prefix: str, timeout_s: float, config_path: str | None = None
) -> DaemonRobot:
    """The robot the daemon on `prefix` runs (`fetch_robot`), checked against the robot file
    at `config_path` when one is given (`check_agrees`).

    Raises DaemonAbsent, Refused (`fetch_robot`), InputError (the file cannot be read or is
    not valid) and RobotMismatch (it describes another robot).
    """
    robot = fetch_robot(session, prefix, timeout_s)
    if config_path is not None:
        check_agrees(robot, load_robot_file(config_path), config_path)
    return robot


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
        daemon_robot(session, prefix, timeout_s, config_path)
    except DaemonAbsent:
        return
