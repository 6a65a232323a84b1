"""`cablebot gcode FILE|-`: run a G-code job (docs/gcode.md).

- `cablebot gcode FILE --dry-run [--config FILE] [--from X Y Z] [--json]` plans the whole job
  offline with the robot's limits on the daemon's planner, from the robot's power-up pose (or
  `--from`), and prints its duration, length, moves, bounding box and what is not driven or
  unsupported.
- `cablebot gcode FILE [--config FILE] [--wait]` takes the robot from the daemon
  (`controller.cli.daemon_robot`; a `--config` must describe the same robot), checks the job
  from the robot's set-point and streams it to the daemon as a path and appends, resting at the
  job's waits; a progress line on a terminal; Ctrl-C, SIGTERM and SIGHUP stop the job and brake
  to a hold.

`FILE` may be gzipped (`.gz`); `-` reads standard input. Exit codes: `controller.cli.exitcodes`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from typing import Any

from controller.cli import exitcodes
from controller.client.gcode import (
    JobInputError,
    check_loaded,
    frame_of,
    job_warnings,
    load_job,
    parse_file,
    plan,
    read_lines,
)
from controller.client.job import (
    REST_POLL_S,
    SENT_DECIMALS,
    JobLink,
    RobotJobLink,
    Streamer,
    chunk_points,
    iter_job,
    load_gcode,
)
from controller.core.gcode_job import Job, JobPlan

Vec3 = tuple[float, float, float]

# Reading, checking and planning a job, and streaming it, are the client library's
# (`controller.client.gcode`, `controller.client.job`); importable from here too.
__all__ = [
    "REST_POLL_S",
    "SENT_DECIMALS",
    "JobInputError",
    "JobLink",
    "RobotJobLink",
    "Streamer",
    "check_loaded",
    "chunk_points",
    "cmd_dry_run",
    "cmd_stream",
    "dry_run_start",
    "format_summary",
    "frame_of",
    "job_warnings",
    "load_job",
    "parse_file",
    "plan",
    "read_lines",
    "summary",
    "warn",
]


def warn(messages: Sequence[str]) -> None:
    """Print each warning on stderr ("cablebot: warning: ...")."""
    for m in messages:
        print(f"cablebot: warning: {m}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------------------- reports
def summary(job: Job, planned: JobPlan, start_from: str = "--from") -> dict[str, Any]:
    """The dry run's figures as one JSON-ready dict (`start_from` says where the start came
    from; `bbox_m` is the box of the job's motions, `Job.bbox_m`)."""
    lo, hi = job.bbox_m
    return {
        "duration_s": round(planned.duration_s, 3),
        "motion_s": round(planned.motion_s, 3),
        "moves": job.moves,
        "lines": job.lines,
        "path_m": round(job.path_m, 6),
        "start_m": list(job.start_m),
        "start_from": start_from,
        "bbox_m": [list(lo), list(hi)],
        "accel_mps2": job.accel_mps2,
        "not_driven": dict(sorted(job.not_driven.items())),
        "unsupported": dict(sorted(job.unsupported.items())),
    }


def _hms(s: float) -> str:
    s = max(0.0, s)
    h, rem = divmod(round(s), 3600)
    m, sec = divmod(rem, 60)
    return f"{h}h{m:02d}m{sec:02d}s" if h else f"{m}m{sec:02d}s"


def _codes(table: dict[str, int]) -> str:
    return ", ".join(f"{k} ({v})" for k, v in sorted(table.items())) or "none"


def format_summary(s: dict[str, Any]) -> str:
    """The dry run's figures for a person."""
    lo, hi = s["bbox_m"]
    box = "  ".join(f"{a}={lo[i]:+.4f}..{hi[i]:+.4f}" for i, a in enumerate("xyz"))
    start = "  ".join(f"{a}={v:+.4f}" for a, v in zip("xyz", s["start_m"], strict=True))
    return "\n".join(
        [
            f"start      {start} m ({s.get('start_from', '--from')})",
            f"duration   {_hms(s['duration_s'])} ({s['duration_s']:.1f} s)",
            f"path       {s['path_m']:.3f} m in {s['moves']} moves ({s['lines']} lines)",
            f"bbox       {box} m",
            f"not driven {_codes(s['not_driven'])}",
            f"unsupported {_codes(s['unsupported'])}",
        ]
    )


def _fail(msg: str) -> int:
    print(f"cablebot: {msg}", file=sys.stderr)
    return exitcodes.REFUSED


def _config(path: str | None) -> Any:
    from controller.service.config import load_config

    return load_config(path)


def dry_run_start(cfg: Any, given: Sequence[float] | None) -> tuple[Vec3, str]:
    """Where the dry run starts, and what that point is: `given` (`--from`), else where the
    real run starts on a robot just started, its power-up pose, else (a robot without one)
    the G-code origin. Raises JobInputError when `--from` is not finite or is a point the
    robot may not be at (the reason blamed on `--from`, not on a line of the job)."""
    from controller.core.workspace import Workspace

    if given is None:
        pup = cfg.homing.power_up_position_m
        if pup is not None:
            return (float(pup[0]), float(pup[1]), float(pup[2])), "the robot's power-up pose"
        return tuple(cfg.gcode.origin_m), "the G-code origin: the robot has no power-up pose"
    start = (float(given[0]), float(given[1]), float(given[2]))
    if not all(math.isfinite(v) for v in start):
        raise JobInputError(f"--from: expected three finite numbers, got {list(given)}")
    why = Workspace.from_limits(cfg.limits, cfg.geometry).check_point(start)
    if why is not None:
        xyz = ", ".join(f"{v:g}" for v in start)
        raise JobInputError(f"--from {xyz}: the robot cannot start there: {why}")
    return start, "--from"


def cmd_dry_run(args: argparse.Namespace) -> int:
    """`gcode FILE --dry-run`: plan offline and print the figures."""
    from controller.service.config import ConfigError

    try:
        cfg = _config(args.config)
    except (ConfigError, OSError) as exc:
        return _fail(str(exc))
    try:
        start, start_from = dry_run_start(cfg, args.start)
        job = load_job(args.file, cfg, start)
    except JobInputError as exc:
        return _fail(str(exc))
    warnings = job_warnings(job, cfg)
    warn(warnings)
    s = summary(job, plan(job, cfg), start_from)
    if args.json:
        s["warnings"] = warnings
    print(json.dumps(s) if args.json else format_summary(s), flush=True)
    return exitcodes.OK


# ------------------------------------------------------------------------------- streaming
def cmd_stream(args: argparse.Namespace) -> int:
    """`gcode FILE`: check the job from the robot's set-point and stream it to the daemon."""
    from controller.cli import client
    from controller.cli.daemon_robot import daemon_robot
    from controller.cli.formats import is_tty

    try:
        lines = parse_file(args.file, read_lines(args.file))
    except JobInputError as exc:
        return _fail(str(exc))

    def body(session: Any) -> int:
        robot = client.robot_of(args, session)
        # The daemon that flies the job is the authority on the robot: its [gcode] table,
        # limits and planner interpret and check the job (a --config must agree with it).
        daemon_robot(robot, args.config)
        job = load_gcode(robot, args.file, lines)
        warn(job.warnings)
        if job.job.accel_mps2 < job.max_accel_mps2:
            print(
                f"cablebot: the job asks for {job.job.accel_mps2:g} m/s^2; the daemon flies at"
                f" its max_accel_mps2 {job.max_accel_mps2:g} m/s^2",
                file=sys.stderr,
                flush=True,
            )
        progress = client.StatusLine(sys.stdout, enabled=is_tty(sys.stdout) and not args.json)
        try:
            # SIGTERM and SIGHUP stop the job as Ctrl-C does while it streams (a job cut off
            # where its sender died is not the job asked for) and while --wait follows it.
            with client.signals_interrupt():
                steps = iter_job(
                    robot, job, wait=args.wait, wait_timeout_s=args.wait_timeout, brake=False
                )
                while True:
                    try:
                        prog = next(steps)
                    except StopIteration as stop:
                        result = stop.value
                        break
                    if prog.report is not None and not args.json:  # M114, once at rest
                        progress.clear()
                        print(f"M114 (line {prog.line}): {prog.report}", flush=True)
                    progress.show(
                        f"gcode: line {prog.line}/{prog.lines}  moves {prog.moves}/"
                        f"{prog.total_moves}  elapsed {_hms(prog.elapsed_s)}  remaining"
                        f" ~{_hms(prog.planned_s - prog.elapsed_s)}",
                        time.monotonic(),
                    )
        except KeyboardInterrupt:
            progress.clear()
            return client._interrupted(robot, args)
        finally:
            progress.clear()
        if args.json:
            out = {
                "sent": True,
                "done": result.done,
                "lines": result.lines,
                "moves": result.moves,
                "chunks": result.chunks,
                "elapsed_s": round(result.elapsed_s, 3),
                "planned_s": round(result.planned_s, 3),
            }
            print(json.dumps(out), flush=True)
        else:
            what = "done" if result.done else "sent"
            print(
                f"gcode: {what}: {result.lines} lines, {result.moves} moves in {result.chunks} "
                f"commands, {_hms(round(result.elapsed_s, 3))} (planned {_hms(result.planned_s)})",
                flush=True,
            )
        return exitcodes.OK

    return client.run_with_session(args, body)
