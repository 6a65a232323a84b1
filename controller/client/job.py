"""G-code jobs of any length, run on the robot a daemon runs.

```python
from controller.client import Robot
from controller.client.job import load_gcode, run_job

with Robot() as robot:
    job = load_gcode(robot, "part.gcode")   # checked whole against the daemon's robot
    print(f"{job.lines} lines, about {job.planned_s:.0f} s")
    result = run_job(robot, job, wait=True, on_progress=lambda p: print(p.line, end="\\r"))
```

`load_gcode` takes the robot from the daemon (its description: the `[gcode]` frame, limits,
geometry, tension rule, planner; never a robot file of the client's own), interprets the job
from the robot's set-point, checks every motion of it and plans it on the daemon's planner:
a bad line anywhere is refused (`JobInputError`, naming the line) before anything moves.
`iter_job` / `run_job` stream it (`Streamer`): its chunks as a path and appends paced by the
daemon's queue (`controller.client.stream.Pacer`), resting at the job's waits (G4, M400, M114,
M18/M84). Cancelling brakes the robot to a hold, as everywhere in the library.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

from controller.client.errors import Refused, WaitTimeout
from controller.client.gcode import check_loaded, job_warnings, parse_file, plan, read_lines
from controller.client.stream import MOTION_STATES, Pacer, RobotLeft, finish
from controller.core.gcode import Line
from controller.core.gcode_job import (
    Chunk,
    Disarm,
    Dwell,
    Estop,
    Job,
    JobPlan,
    Motion,
    Shaping,
    Step,
    Sync,
    chunks,
)
from controller.service import keys

if TYPE_CHECKING:
    from controller.client.robot import Robot

Vec3 = tuple[float, float, float]

SENT_DECIMALS = 7
"""Coordinates go to the daemon rounded to 0.1 um (shorter payloads; far below any limit)."""
_POINT_JSON_MAX = 3 * len("-12345.1234567, ") + 2
"""The longest JSON text of a rounded point inside +-1e4 m ("[x, y, z], ")."""
REST_POLL_S = 0.2
"""How often the streamer asks the daemon's status while it waits for rest, and how often a
dwell reports that it waits (each query costs the daemon a status snapshot: not more often
than a person needs; the pace of appends is `Pacer`'s)."""


def chunk_points(max_points: int, decode_limit_bytes: int) -> int:
    """Points per path command of a job: as many as keep its payload within the daemon's fast
    (C) JSON decoder, `decode_limit_bytes` (a longer payload is decoded by the pure-Python
    scanner, tens of times slower, on the daemon's Zenoh thread), at most `max_points`."""
    return max(1, min(max_points, (decode_limit_bytes - 256) // _POINT_JSON_MAX))


def job_chunk_points() -> int:
    """The points per path command every job is sent in (`chunk_points` for this daemon's
    limits)."""
    from controller.core.commands import C_DECODE_MAX_BYTES, MAX_PATH_POINTS_SENT

    return chunk_points(MAX_PATH_POINTS_SENT, C_DECODE_MAX_BYTES)


class JobLink(Protocol):
    """What the streamer needs of the daemon (`RobotJobLink`; a fake in tests)."""

    def path(self, points_m: Sequence[Vec3], speed_mps: float, append: bool) -> Any:
        """Send a path command; raises Refused with the daemon's reason."""

    def status(self) -> dict[str, Any]:
        """The daemon's status."""

    def command(self, verb: str, payload: dict[str, Any] | None = None) -> Any:
        """Send a verb with `payload` (none: disarm, estop); raises Refused."""


class RobotJobLink:
    """`JobLink` over a `Robot` (its session, prefix, timeout and query function)."""

    def __init__(self, robot: Robot) -> None:
        self.robot = robot

    def path(self, points_m: Sequence[Vec3], speed_mps: float, append: bool) -> Any:
        """Send a path command (`append` as the JSON flag); raises Refused."""
        nd = SENT_DECIMALS
        payload: dict[str, Any] = {
            "points_m": [[round(p[0], nd), round(p[1], nd), round(p[2], nd)] for p in points_m],
            "speed_mps": speed_mps,
        }
        if append:
            payload["append"] = True
        return self.robot.query(keys.command("path"), payload)

    def status(self) -> dict[str, Any]:
        """The daemon's status ({} if it is not an object)."""
        st = self.robot.query(keys.STATUS)
        return st if isinstance(st, dict) else {}

    def command(self, verb: str, payload: dict[str, Any] | None = None) -> Any:
        """Send `verb` with `payload` (None: without one); raises Refused."""
        return self.robot.query(keys.command(verb), payload)


class Streamer:
    """Sends a job's steps (`gcode_job.chunks`) to the daemon in order: the first chunk (and
    the first after a wait) as a path, the others as appends paced by the daemon's queue as
    every stream is (`Pacer`: sent while less than `LOW_WATER_S` of motion is queued, a full
    queue waited out); each wait (G4, M400, M114, M18/M84) lets the robot come to rest first.
    Counts the lines and moves sent. `steps`/`rest_steps` yield at every poll while they wait;
    `send`/`rest` call `on_wait` there instead. Raises Refused when the daemon refuses a chunk
    or the robot leaves the motion states during the job, DaemonAbsent when it stops
    answering."""

    def __init__(
        self,
        robot: JobLink,
        *,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.robot = robot
        self.clock = clock
        self.sleep = sleep
        self.on_wait: Callable[[], None] = lambda: None
        """Called at every poll while the streamer waits (for room, for rest, in a dwell)."""
        self.pacer = Pacer(robot.status, refused=Refused, sleep=sleep)
        self.fresh = True
        self.line = 0
        self.moves = 0
        self.chunks = 0

    @property
    def full_waits(self) -> int:
        """Chunks refused for a full queue and sent again."""
        return self.pacer.progress.retries

    def _drive(self, steps: Generator[None, None, Any]) -> Any:
        while True:
            try:
                next(steps)
            except StopIteration as stop:
                return stop.value
            self.on_wait()

    def send(self, step: Step) -> str | None:
        """Send one step; returns the M114 report of a `Sync` that has one (after the rest).
        Raises Refused (a refused chunk, the robot gone from the motion states)."""
        report: str | None = self._drive(self.steps(step))
        return report

    def rest(self, deadline_s: float = math.inf) -> None:
        """Wait until the robot rests at the end of what was sent (HOLDING); the next chunk
        then starts a path. Raises Refused if it leaves the motion states, and WaitTimeout if
        it still moves at `deadline_s` (of `clock`)."""
        self._drive(self.rest_steps(deadline_s))

    def steps(self, step: Step) -> Generator[None, None, str | None]:
        """`send`, yielding at every poll while it waits."""
        if isinstance(step, Chunk):
            append = not self.fresh
            try:
                yield from self.pacer.steps(
                    lambda: self.robot.path(step.points_m, step.speed_mps, append=append), append
                )
            except RobotLeft as exc:
                raise Refused(_gone(exc.status, self.line)) from None
            self.fresh = False
            self.chunks += 1
            self.line = step.last_line
            self.moves += step.moves
            return None
        yield from self.rest_steps()
        self.line = step.line_no
        if isinstance(step, Dwell):
            end = self.clock() + step.duration_s
            while (left := end - self.clock()) > 0.0:
                yield
                self.sleep(min(left, REST_POLL_S))
        elif isinstance(step, Disarm):
            self.robot.command("disarm")
        elif isinstance(step, Estop):
            self.robot.command("estop")
        elif isinstance(step, Sync):
            return step.report
        elif isinstance(step, Shaping):
            self.robot.command(
                "shaper",
                {
                    "type": step.type,
                    "frequency_hz": step.frequency_hz,
                    "damping_ratio": step.damping_ratio,
                },
            )
        return None

    def rest_steps(self, deadline_s: float = math.inf) -> Generator[None, None, None]:
        """`rest`, yielding at every poll while it waits."""
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
                yield
                self.sleep(REST_POLL_S)
        self.fresh = True


def _gone(status: dict[str, Any], line: int) -> str:
    """Why a job ends when the robot left the motion states: its state and reason."""
    why = f" ({status['reason']})" if status.get("reason") else ""
    return f"the robot went {status.get('state')}{why} during the job (line {line})"


# --------------------------------------------------------------------------------------------
# Jobs on a Robot


@dataclass(frozen=True)
class GcodeJob:
    """A G-code job checked whole against the daemon's robot from its set-point, and planned on
    the daemon's planner: `file` (its name), the interpreted `job`, its `plan` (duration),
    `warnings` (what cannot be meant on this robot, e.g. a file in metres) and the robot's
    `max_accel_mps2` (a job asking less is still flown at it)."""

    file: str
    job: Job
    plan: JobPlan
    warnings: tuple[str, ...]
    max_accel_mps2: float

    @property
    def lines(self) -> int:
        """The job's lines."""
        return self.job.lines

    @property
    def moves(self) -> int:
        """The job's moves."""
        return self.job.moves

    @property
    def planned_s(self) -> float:
        """The planned duration (s)."""
        return self.plan.duration_s


def load_gcode(robot: Robot, file: str, parsed: Sequence[Line] | None = None) -> GcodeJob:
    """The job in `file` (`-`: standard input; `.gz`: gzipped), or its lines `parsed` already
    (`gcode.parse_file`), interpreted with the robot the daemon runs from the robot's
    set-point, checked whole and planned.

    Raises JobInputError (the file, or the line that cannot run or leaves the robot's
    limits; nothing sent), Refused (the robot is not HOLDING; the daemon serves no robot
    description), DaemonAbsent.
    """
    lines = parse_file(file, read_lines(file)) if parsed is None else parsed
    cfg = robot.description().config
    st = robot.status()
    if st.state != "HOLDING" or st.setpoint_m is None:
        why = f" ({st.reason})" if st.reason else ""
        raise Refused(f"the robot is {st.state}{why}: a job starts from HOLDING (arm, home)")
    job = check_loaded(file, lines, cfg, st.setpoint_m)
    return GcodeJob(
        file, job, plan(job, cfg), tuple(job_warnings(job, cfg)), cfg.limits.max_accel_mps2
    )


@dataclass(frozen=True)
class JobProgress:
    """How far a job is: the line and moves sent of the job's, the commands sent, the time since
    it began, and `report` (the M114 position report of a sync, once the robot rests there);
    `waiting` is True while the job waits (for room in the queue, for rest, in a dwell)."""

    line: int
    lines: int
    moves: int
    total_moves: int
    chunks: int
    elapsed_s: float
    planned_s: float
    report: str | None = None
    waiting: bool = False


@dataclass(frozen=True)
class JobResult:
    """A job sent whole: lines, moves and commands, the time it took to send (with `done`: to
    run to its end, at rest) and the planned duration."""

    lines: int
    moves: int
    chunks: int
    elapsed_s: float
    planned_s: float
    done: bool


def iter_job(
    robot: Robot,
    job: GcodeJob,
    *,
    wait: bool = False,
    wait_timeout_s: float = math.inf,
    brake: bool = True,
    clock: Callable[[], float] = time.monotonic,
) -> Generator[JobProgress, None, JobResult]:
    """Stream `job` to the daemon, yielding the progress after every step and at every poll
    while it waits; returns the result (with `wait`, once the robot rests at the job's end).

    Raises (while iterating) Refused (a chunk refused; the robot left the motion states),
    WaitTimeout (with `wait`: still running after `wait_timeout_s`), DaemonAbsent. Closing the
    iterator early, or an exception meanwhile other than those, brakes the robot to a hold
    (with `brake`).
    """
    streamer = Streamer(RobotJobLink(robot), clock=clock)
    t0 = clock()
    ends = [a.points_m[-1] for a in job.job.actions if isinstance(a, Motion) and a.points_m]
    motion = robot.expect_motion(ends[-1:] or [job.job.start_m])

    def progress(report: str | None = None, waiting: bool = False) -> JobProgress:
        return JobProgress(
            streamer.line,
            job.lines,
            streamer.moves,
            job.moves,
            streamer.chunks,
            clock() - t0,
            job.planned_s,
            report,
            waiting,
        )

    try:
        for step in chunks(job.job.actions, job_chunk_points()):
            steps = streamer.steps(step)
            while True:
                try:
                    next(steps)
                except StopIteration as stop:
                    report = stop.value
                    break
                yield progress(waiting=True)
            yield progress(report)
            if isinstance(step, (Estop, Disarm)):
                robot.forget_motion(motion)
            if isinstance(step, Estop):
                break
        streamer.line = job.lines
        if wait:
            for _ in streamer.rest_steps(clock() + wait_timeout_s):
                yield progress(waiting=True)
            robot.forget_motion(motion)
    except (Refused, WaitTimeout):
        raise
    except BaseException as exc:  # GeneratorExit too: the caller gave up on the job
        if brake:
            robot.brake_if_moving(None if isinstance(exc, GeneratorExit) else exc)
        raise
    return JobResult(job.lines, streamer.moves, streamer.chunks, clock() - t0, job.planned_s, wait)


def run_job(
    robot: Robot,
    job: GcodeJob,
    *,
    wait: bool = False,
    wait_timeout_s: float = math.inf,
    on_progress: Callable[[JobProgress], None] | None = None,
    brake: bool = True,
) -> JobResult:
    """`iter_job` with a callback: `on_progress` gets each progress; returns the result.
    Raises as `iter_job`; an exception in `on_progress` brakes the robot to a hold (with
    `brake`) and is raised."""
    steps = iter_job(robot, job, wait=wait, wait_timeout_s=wait_timeout_s, brake=brake)
    try:
        while True:
            prog = next(steps)
            if on_progress is not None:
                on_progress(prog)
    except StopIteration as stop:
        result: JobResult = stop.value
        return result
    except (Refused, WaitTimeout):
        raise
    except BaseException as exc:  # the callback's (or a Ctrl-C): brake first, saying so on it
        if brake:
            robot.brake_if_moving(exc)
        raise
    finally:
        steps.close()


def finish_job(steps: Generator[JobProgress, None, JobResult]) -> JobResult:
    """Run a job's iterator to its end without looking at its progress."""
    return finish(steps)
