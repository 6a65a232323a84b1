"""A G-code job read, interpreted for a robot, checked whole and planned, before anything is
sent: the file's lines, the robot's `[gcode]` frame, every motion against the robot's rules,
the planned duration on the daemon's own planner. The robot is the daemon's
(`controller.client.job` takes it from the daemon); the offline dry run gives a robot file.
"""

from __future__ import annotations

import gzip
import sys
from collections.abc import Sequence
from typing import Any

from controller.client.errors import InputError
from controller.core.gcode import GcodeError, Line, parse_lines
from controller.core.gcode_job import (
    INCH_M,
    MM_M,
    GcodeFrame,
    Job,
    JobPlan,
    check_job,
    dry_run_step_s,
    interpret,
    plan_job,
)

Vec3 = tuple[float, float, float]


class JobInputError(InputError):
    """The file cannot be read, or its G-code cannot run as written (the message names the
    line); nothing was sent."""


def read_lines(path: str) -> list[str]:
    """The text lines of `path` (gzipped when it ends in `.gz`; `-`: standard input). Raises
    JobInputError when the file cannot be read or is not UTF-8 text (a binary file: the
    first bad byte, its line and column, as every text file the CLI reads)."""
    from controller.service.textfile import NotUtf8Error, decode_utf8

    try:
        if path == "-":
            data = sys.stdin.buffer.read()
        elif path.endswith(".gz"):
            with gzip.open(path, "rb") as fz:
                data = fz.read()
        else:
            with open(path, "rb") as f:
                data = f.read()
    except (OSError, EOFError) as exc:
        raise JobInputError(f"{path}: {exc}") from None
    try:
        text = decode_utf8(data)
    except NotUtf8Error as exc:
        raise JobInputError(f"{path}: {exc}") from None
    lines = text.replace("\r\n", "\n").split("\n")
    if lines and lines[-1] == "":
        lines.pop()  # the newline that ends the last line
    return lines


def parse_file(path: str, lines: Sequence[str]) -> list[Line]:
    """Parse every line. Raises JobInputError naming the file and the first bad line, or
    saying that the file holds no G-code (empty, or only comments and blank lines)."""
    try:
        parsed = list(parse_lines(lines))
    except GcodeError as exc:
        raise JobInputError(f"{path}: {exc}") from None
    if not any(ln.commands for ln in parsed):
        what = "empty" if not any(s.strip() for s in lines) else "only comments and blank lines"
        raise JobInputError(f"{path}: no G-code in it ({what}): nothing to run")
    return parsed


def frame_of(cfg: Any) -> GcodeFrame:
    """The `GcodeFrame` of a robot configuration: its `[gcode]` table and `[limits]`."""
    g = cfg.gcode
    return GcodeFrame(
        origin_m=g.origin_m,
        unit_m=INCH_M if g.units == "inch" else MM_M,
        home_m=g.home_m,
        arc_tolerance_m=g.arc_tolerance_m,
        max_speed_mps=cfg.limits.max_speed_mps,
        max_accel_mps2=cfg.limits.max_accel_mps2,
        rapid_speed_mps=g.rapid_speed_mps,
        m203_per_minute=g.dialect == "reprapfirmware",
    )


def load_job(path: str, cfg: Any, start_m: Sequence[float]) -> Job:
    """Read, parse, interpret and check the job at `path` from `start_m` (robot frame) for the
    robot `cfg`. Raises JobInputError naming the line that cannot run or that leaves the
    workspace or the tension-feasible region."""
    return check_loaded(path, parse_file(path, read_lines(path)), cfg, start_m)


def check_loaded(path: str, lines: Sequence[Line], cfg: Any, start_m: Sequence[float]) -> Job:
    """`load_job` for lines parsed already."""
    from controller.client.pathcheck import RobotRules

    try:
        job = interpret(lines, frame_of(cfg), start_m)
    except GcodeError as exc:
        raise JobInputError(f"{path}: {exc}") from None
    rules = RobotRules.of(cfg)
    failure = check_job(job, rules.workspace, rules.tension, rules.tension_step_m)
    if failure is not None:
        likely = "".join(f"; {w}" for w in job_warnings(job, cfg))  # a file in metres, say
        raise JobInputError(f"{path}: line {failure[0]}: refused: {failure[1]}{likely}")
    return job


def job_warnings(job: Job, cfg: Any) -> list[str]:
    """What about the job cannot be meant on this robot (`controller.core.scale`: motions a
    thousandth of the workspace across, a file written in metres; an M203 read in the other
    dialect's unit). Raises nothing."""
    from controller.core.scale import speed_limit_problem, tiny_job_problem
    from controller.core.workspace import Workspace

    extent = max(h - low for low, h in zip(*job.bbox_m, strict=True))
    why = [tiny_job_problem(extent, Workspace.from_limits(cfg.limits, cfg.geometry).box())]
    if job.speed_limit is not None:
        line_no, limit = job.speed_limit
        per_minute = cfg.gcode.dialect == "reprapfirmware"
        why.append(speed_limit_problem(line_no, limit, job.fastest_feed_mps, per_minute))
    return [w for w in why if w is not None]


def plan(job: Job, cfg: Any) -> JobPlan:
    """Plan `job` on the daemon's planner for `cfg`, its acceleration lowered to the job's."""
    from controller.service.control.base import make_planner

    dt = dry_run_step_s(job, 1.0 / cfg.loop.rate_hz)
    return plan_job(job, make_planner(cfg, max_accel_mps2=job.accel_mps2), dt)
