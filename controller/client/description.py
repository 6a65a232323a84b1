"""The robot a daemon runs, as every client takes it: the daemon is the authority on its robot.

A client that needs the robot's description (its `[gcode]` table, limits, geometry, the tension
rule, the planner's settings) takes it from the daemon it talks to, on `<prefix>/robot`
(docs/zenoh.md), never from a file of its own: a job interpreted with another robot's G-code
origin lands somewhere else.

Keys that name files on the daemon's machine (`[zenoh] config_file`, a drive family's file
options such as the CiA 402 `eds`) are the daemon's own: a client neither reads those files nor
needs them (it may run on another machine), so they are left out of the configuration a client
builds.
"""

from __future__ import annotations

import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import controller.client.transport as transport
from controller.client.errors import DaemonAbsent, Refused
from controller.service import keys

if TYPE_CHECKING:  # the configuration's modules load when a description is read, not before
    from controller.service.config import RobotConfig

ROBOT_KEY = keys.ROBOT
"""The daemon's robot description: `<prefix>/robot`."""


class NoDescription(Refused):
    """The daemon answers but serves no robot description (a daemon older than the client)."""


@dataclass(frozen=True)
class RobotDescription:
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
    from controller.service.config import ConfigError, parse_config

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(source, "", f"not valid TOML: {exc}") from None
    return parse_config(_drop_host_files(data), source, text)


def fetch_description(
    session: Any,
    prefix: str,
    timeout_s: float,
    query: Callable[[Any, str, Any, float], Any] = transport.query,
) -> RobotDescription:
    """The robot the daemon on `prefix` runs, from its `<prefix>/robot` description (`query`
    sends the queries).

    Raises DaemonAbsent when no daemon answers, NoDescription (a Refused) when it serves no
    description (an older daemon), Refused when its description cannot be used.
    """
    from controller.service.config import ConfigError, robot_digest

    prefix = prefix.rstrip("/")
    try:
        reply = query(session, f"{prefix}/{ROBOT_KEY}", None, timeout_s)
    except DaemonAbsent:
        query(session, f"{prefix}/{keys.STATUS}", None, timeout_s)  # no daemon: DaemonAbsent
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
    return RobotDescription(prefix, str(reply.get("name", cfg.name)), source, digest, text, cfg)
