"""A whole motion checked before the robot moves: the rules of a robot (workspace, cable
lengths, the tension rule along every leg) as the daemon applies them to each command, for
every point of a G-code job or a path at once, so that a bad point anywhere is refused before
anything is sent. The rules are those of the robot the daemon runs (its description,
`controller.client.description`), never of a file of the client's own.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

from controller.client.errors import InputError
from controller.core.gcode_job import motion_failure
from controller.core.statics import TensionCheck
from controller.core.workspace import Workspace

if TYPE_CHECKING:
    from controller.client.link import RobotLink

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class RobotRules:
    """What a robot allows along a motion: its workspace, its tension rule (None without
    `[payload]`) and the step at which legs are sampled for tension, as the daemon's."""

    workspace: Workspace
    tension: TensionCheck | None
    tension_step_m: float

    @classmethod
    def of(cls, cfg: Any) -> RobotRules:
        """The rules of a robot configuration (`RobotConfig`). Raises nothing for a valid
        one."""
        from controller.service.config import tension_check
        from controller.service.control.base import tension_sample_step_m

        chk = (
            None
            if cfg.tension is None or cfg.payload is None
            else tension_check(cfg.payload, cfg.tension, cfg.geometry, cfg.reels)
        )
        return cls(Workspace.from_limits(cfg.limits, cfg.geometry), chk, tension_sample_step_m(cfg))

    def failure(
        self, points: Sequence[Vec3], start_m: Sequence[float] | None
    ) -> tuple[int, str] | None:
        """The first of `points` (flown in order from `start_m`, None: from wherever the robot
        is then) that the robot refuses, as (0-based index, reason), or None. Raises
        nothing."""
        if not points:
            return None
        return motion_failure(points, start_m, self.workspace, self.tension, self.tension_step_m)


def speed_refusal(
    speed_mps: float | None, max_speed_mps: float, what: str = "--speed"
) -> str | None:
    """Why a requested speed is refused: above the robot's `limits.max_speed_mps` (the daemon
    would fly it at the maximum; a speed above it is likely a unit mistake), or None (also for
    no speed asked). Raises nothing."""
    if speed_mps is None or speed_mps <= max_speed_mps:
        return None
    return (
        f"{what} {speed_mps:g} m/s is above the robot's limits.max_speed_mps"
        f" ({max_speed_mps:g} m/s): give at most {max_speed_mps:g} (the unit is m/s)"
    )


def path_refusal(
    rules: RobotRules,
    points: Sequence[Vec3],
    start_m: Sequence[float] | None,
    file: str,
    line_of: Sequence[int] | None,
    whole: str = "file",
) -> str | None:
    """Why the robot would refuse the path file `file` (its `points`, flown from `start_m`),
    naming the file's line of the first bad point (`line_of[i]`; without line numbers, the
    point's position in the file from 1), or None. `whole` names what was checked whole (a
    "file", a "path" a program gave). Raises nothing."""
    failure = rules.failure(points, start_m)
    if failure is None:
        return None
    i, why = failure
    where = f"line {line_of[i]}" if line_of is not None else f"point {i + 1}"
    p = points[i]
    return (
        f"{file} {where}: refused: point [{p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}]: {why}"
        f" (the whole {whole} is checked first: nothing was sent)"
    )


class PathFile(NamedTuple):
    """A path as read from a file (or given by a program: `whole` "path"): its name, points,
    their line numbers (None: JSON, whose points are named by position) and whether it appends
    to the path in progress."""

    file: str
    points: list[list[float]]
    line_of: list[int] | None
    append: bool
    whole: str = "file"


def check_with_robot(
    robot: RobotLink,
    speed_mps: float | None,
    path: PathFile | None,
    *,
    speed_option: str = "--speed",
) -> None:
    """Before anything is sent, with the robot the daemon runs (`robot.description()`): refuse
    a speed above its `limits.max_speed_mps` (`speed_refusal`, naming `speed_option`) and any
    point of a whole path (`path_refusal`, flown from the robot's set-point when it holds and
    the path does not append).

    A daemon that serves no robot description (older than this client) is not pre-checked:
    it checks each command itself, as it always did.

    Raises InputError with the reason, DaemonAbsent or Refused (`robot.description()`).
    """
    from controller.client.description import NoDescription

    try:
        cfg = robot.description().config
    except NoDescription:
        return
    why = speed_refusal(speed_mps, float(cfg.limits.max_speed_mps), speed_option)
    if why is not None:
        raise InputError(why)
    if path is None:
        return
    start = None
    if not path.append:
        st = robot.status()
        if st.state == "HOLDING":
            start = st.setpoint_m
    pts = [(p[0], p[1], p[2]) for p in path.points]
    why = path_refusal(RobotRules.of(cfg), pts, start, path.file, path.line_of, path.whole)
    if why is not None:
        raise InputError(why)
