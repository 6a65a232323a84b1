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
import gzip
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol

from controller.cli import exitcodes
from controller.cli.pathstream import MOTION_STATES, Pacer, RobotLeft
from controller.core.gcode import GcodeError, Line, parse_lines
from controller.core.gcode_job import (
    INCH_M,
    MM_M,
    Chunk,
    Disarm,
    Dwell,
    Estop,
    GcodeFrame,
    Job,
    JobPlan,
    Motion,
    Step,
    Sync,
    check_job,
    chunks,
    dry_run_step_s,
    interpret,
    plan_job,
)

Vec3 = tuple[float, float, float]


class JobInputError(ValueError):
    """The file cannot be read, or its G-code cannot run as written (the message names the
    line); nothing was sent."""


# ------------------------------------------------------------------------------- reading
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
    from controller.cli.pathcheck import RobotRules

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


def motion_bbox_m(job: Job) -> tuple[Vec3, Vec3]:
    """The bounding box ((min x, y, z), (max x, y, z)) of the job's motions (where the job
    goes, its start left out; the start alone for a job without motion). Raises nothing."""
    lo = [math.inf] * 3
    hi = [-math.inf] * 3
    for act in job.actions:
        if isinstance(act, Motion):
            for p in act.points_m:
                for i in range(3):
                    lo[i] = min(lo[i], p[i])
                    hi[i] = max(hi[i], p[i])
    if lo[0] == math.inf:
        return job.start_m, job.start_m
    return (lo[0], lo[1], lo[2]), (hi[0], hi[1], hi[2])


def job_warnings(job: Job, cfg: Any) -> list[str]:
    """What about the job cannot be meant on this robot (`controller.core.scale`: motions a
    few millimetres across on a metre-scale robot, a file written in metres). Raises
    nothing."""
    from controller.core.scale import tiny_job_problem
    from controller.core.workspace import Workspace

    lo, hi = motion_bbox_m(job)
    extent = max(h - low for low, h in zip(lo, hi, strict=True))
    why = tiny_job_problem(extent, Workspace.from_limits(cfg.limits, cfg.geometry).box())
    return [] if why is None else [why]


def warn(messages: Sequence[str]) -> None:
    """Print each warning on stderr ("cablebot: warning: ...")."""
    for m in messages:
        print(f"cablebot: warning: {m}", file=sys.stderr, flush=True)


def plan(job: Job, cfg: Any) -> JobPlan:
    """Plan `job` on the daemon's planner for `cfg`, its acceleration lowered to the job's."""
    from controller.service.control.base import make_planner

    dt = dry_run_step_s(job, 1.0 / cfg.loop.rate_hz)
    return plan_job(job, make_planner(cfg, max_accel_mps2=job.accel_mps2), dt)


# ------------------------------------------------------------------------------- reports
def summary(job: Job, planned: JobPlan, start_from: str = "--from") -> dict[str, Any]:
    """The dry run's figures as one JSON-ready dict (`start_from` says where the start came
    from; `bbox_m` is the box of the job's motions, `motion_bbox_m`)."""
    lo, hi = motion_bbox_m(job)
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
SENT_DECIMALS = 7
"""Coordinates go to the daemon rounded to 0.1 um (shorter payloads; far below any limit)."""
_POINT_JSON_MAX = 3 * len("-12345.1234567, ") + 2
"""The longest JSON text of a rounded point inside +-1e4 m ("[x, y, z], ")."""


def chunk_points(max_points: int, decode_limit_bytes: int) -> int:
    """Points per path command of a job: as many as keep its payload within the daemon's fast
    (C) JSON decoder, `decode_limit_bytes` (a longer payload is decoded by the pure-Python
    scanner, tens of times slower, on the daemon's Zenoh thread), at most `max_points`."""
    return max(1, min(max_points, (decode_limit_bytes - 256) // _POINT_JSON_MAX))


REST_POLL_S = 0.2
"""How often the streamer asks the daemon's status while it waits for rest, and how often a
dwell calls `on_wait` (each query costs the daemon a status snapshot: not more often than a
person needs; the pace of appends is `pathstream.Pacer`'s)."""


class RobotLink(Protocol):
    """What the streamer needs of the daemon (`ZenohRobot`; a fake in tests)."""

    def path(self, points_m: Sequence[Vec3], speed_mps: float, append: bool) -> Any:
        """Send a path command; raises client.Refused with the daemon's reason."""

    def status(self) -> dict[str, Any]:
        """The daemon's status."""

    def command(self, verb: str) -> Any:
        """Send a verb without payload (disarm, estop); raises client.Refused."""


class Streamer:
    """Sends a job's steps (`gcode_job.chunks`) to the daemon in order: the first chunk (and
    the first after a wait) as a path, the others as appends paced by the daemon's queue as
    every stream is (`pathstream.Pacer`: sent while less than `LOW_WATER_S` of motion is
    queued, a full queue waited out); each wait (G4, M400, M114, M18/M84) lets the robot come
    to rest first. Counts the lines and moves sent. Raises client.Refused when the daemon
    refuses a chunk or the robot leaves the motion states during the job,
    client.DaemonAbsent when it stops answering."""

    def __init__(
        self,
        robot: RobotLink,
        *,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        from controller.cli.client import Refused

        self.robot = robot
        self.clock = clock
        self.sleep = sleep
        self.on_wait: Callable[[], None] = lambda: None
        """Called at every poll while the streamer waits (for room, for rest, in a dwell)."""
        self.pacer = Pacer(robot.status, refused=Refused, sleep=sleep, on_poll=self._waiting)
        self.fresh = True
        self.line = 0
        self.moves = 0
        self.chunks = 0

    @property
    def full_waits(self) -> int:
        """Chunks refused for a full queue and sent again."""
        return self.pacer.progress.retries

    def _waiting(self) -> None:
        self.on_wait()

    def send(self, step: Step) -> str | None:
        """Send one step; returns the M114 report of a `Sync` that has one (after the rest).
        Raises client.Refused (a refused chunk, the robot gone from the motion states)."""
        from controller.cli.client import Refused

        if isinstance(step, Chunk):
            append = not self.fresh
            try:
                self.pacer.send(
                    lambda: self.robot.path(step.points_m, step.speed_mps, append=append), append
                )
            except RobotLeft as exc:
                raise Refused(_gone(exc.status, self.line)) from None
            self.fresh = False
            self.chunks += 1
            self.line = step.last_line
            self.moves += step.moves
            return None
        self.rest()
        self.line = step.line_no
        if isinstance(step, Dwell):
            end = self.clock() + step.duration_s
            while (left := end - self.clock()) > 0.0:
                self.on_wait()
                self.sleep(min(left, REST_POLL_S))
        elif isinstance(step, Disarm):
            self.robot.command("disarm")
        elif isinstance(step, Estop):
            self.robot.command("estop")
        elif isinstance(step, Sync):
            return step.report
        return None

    def rest(self, deadline_s: float = math.inf) -> None:
        """Wait until the robot rests at the end of what was sent (HOLDING); the next chunk
        then starts a path. Raises client.Refused if it leaves the motion states, and
        client.WaitTimeout if it still moves at `deadline_s` (of `clock`)."""
        from controller.cli.client import Refused, WaitTimeout

        if not self.fresh:
            while True:
                if self.clock() > deadline_s:
                    raise WaitTimeout(f"the job is still running (line {self.line})")
                st = self.robot.status()
                state = st.get("state")
                if state not in MOTION_STATES:
                    raise Refused(_gone(st, self.line))
                self.pacer.progress.take(st.get("path"))
                if state == "HOLDING":
                    break
                self.on_wait()
                self.sleep(REST_POLL_S)
        self.fresh = True


def _gone(status: dict[str, Any], line: int) -> str:
    """Why a job ends when the robot left the motion states: its state and reason."""
    why = f" ({status['reason']})" if status.get("reason") else ""
    return f"the robot went {status.get('state')}{why} during the job (line {line})"


class ZenohRobot:
    """`RobotLink` over the CLI's Zenoh session (`controller.cli.client.query`)."""

    def __init__(self, session: Any, args: argparse.Namespace) -> None:
        self.session = session
        self.args = args

    def _key(self, suffix: str) -> str:
        return f"{self.args.prefix}/{suffix}"

    def path(self, points_m: Sequence[Vec3], speed_mps: float, append: bool) -> Any:
        """Send a path command (`append` as the JSON flag); raises client.Refused."""
        from controller.cli.client import query

        nd = SENT_DECIMALS
        payload = {
            "points_m": [[round(p[0], nd), round(p[1], nd), round(p[2], nd)] for p in points_m],
            "speed_mps": speed_mps,
        }
        if append:
            payload["append"] = True
        return query(self.session, self._key("cmd/path"), payload, self.args.timeout)

    def status(self) -> dict[str, Any]:
        """The daemon's status ({} if it is not an object)."""
        from controller.cli.client import query

        st = query(self.session, self._key("status"), None, self.args.timeout)
        return st if isinstance(st, dict) else {}

    def command(self, verb: str) -> Any:
        """Send `verb` without a payload; raises client.Refused."""
        from controller.cli.client import query

        return query(self.session, self._key(f"cmd/{verb}"), None, self.args.timeout)


def cmd_stream(args: argparse.Namespace) -> int:
    """`gcode FILE`: check the job from the robot's set-point and stream it to the daemon."""
    from controller.cli import client
    from controller.cli.daemon_robot import daemon_robot
    from controller.cli.formats import is_tty
    from controller.core.commands import C_DECODE_MAX_BYTES, MAX_PATH_POINTS_SENT

    try:
        lines = parse_file(args.file, read_lines(args.file))
    except JobInputError as exc:
        return _fail(str(exc))

    def body(session: Any) -> int:
        # The daemon that flies the job is the authority on the robot: its [gcode] table,
        # limits and planner interpret and check the job (a --config must agree with it).
        cfg = daemon_robot(session, args.prefix, args.timeout, args.config).config
        robot = ZenohRobot(session, args)
        st = robot.status()
        state = st.get("state")
        start = st.get("setpoint_m")
        if state != "HOLDING" or start is None:
            why = f" ({st.get('reason')})" if st.get("reason") else ""
            raise client.Refused(
                f"the robot is {state}{why}: a job starts from HOLDING (arm, home)"
            )
        try:
            job = check_loaded(args.file, lines, cfg, start)
        except JobInputError as exc:
            raise client.InputError(str(exc)) from None
        warn(job_warnings(job, cfg))
        planned = plan(job, cfg)
        if job.accel_mps2 < cfg.limits.max_accel_mps2:
            print(
                f"cablebot: the job asks for {job.accel_mps2:g} m/s^2; the daemon flies at its "
                f"max_accel_mps2 {cfg.limits.max_accel_mps2:g} m/s^2",
                file=sys.stderr,
                flush=True,
            )
        progress = client.StatusLine(sys.stdout, enabled=is_tty(sys.stdout) and not args.json)
        streamer = Streamer(robot)
        t0 = time.monotonic()

        def show() -> None:
            now = time.monotonic()
            el = now - t0
            progress.show(
                f"gcode: line {streamer.line}/{job.lines}  moves {streamer.moves}/{job.moves}  "
                f"elapsed {_hms(el)}  remaining ~{_hms(planned.duration_s - el)}",
                now,
            )

        streamer.on_wait = show
        try:
            # SIGTERM and SIGHUP stop the job as Ctrl-C does while it streams (a job cut off
            # where its sender died is not the job asked for) and while --wait follows it.
            with client.signals_interrupt():
                per_chunk = chunk_points(MAX_PATH_POINTS_SENT, C_DECODE_MAX_BYTES)
                for step in chunks(job.actions, per_chunk):
                    report = streamer.send(step)
                    if report is not None and not args.json:  # M114, once the robot rests
                        progress.clear()
                        print(f"M114 (line {streamer.line}): {report}", flush=True)
                    show()
                    if isinstance(step, Estop):
                        break
                streamer.line = job.lines
                if args.wait:
                    streamer.rest(time.monotonic() + args.wait_timeout)
        except KeyboardInterrupt:
            progress.clear()
            return client._interrupted(session, args)
        finally:
            progress.clear()
        result = {
            "sent": True,
            "done": bool(args.wait),
            "lines": job.lines,
            "moves": streamer.moves,
            "chunks": streamer.chunks,
            "elapsed_s": round(time.monotonic() - t0, 3),
            "planned_s": round(planned.duration_s, 3),
        }
        if args.json:
            print(json.dumps(result), flush=True)
        else:
            what = "done" if args.wait else "sent"
            print(
                f"gcode: {what}: {job.lines} lines, {streamer.moves} moves in {streamer.chunks} "
                f"commands, {_hms(result['elapsed_s'])} (planned {_hms(planned.duration_s)})",
                flush=True,
            )
        return exitcodes.OK

    return client.run_with_session(args, body)
