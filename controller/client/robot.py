"""`Robot`: one daemon's robot, driven and watched from a program.

```python
from controller.client import Robot

with Robot("tcp/127.0.0.1:7447", prefix="cablebot/default") as robot:
    robot.move((5.0, 3.0, 2.5), speed_mps=1.0)
    robot.wait(timeout_s=60.0)
    print(robot.pose().position_m)
```

Every verb of the daemon's command table is a method returning the daemon's `Reply`, or
raising: `Refused` (the daemon's reason), `DaemonAbsent` (no reply in time), `InputError` (bad
numbers, caught before anything is sent). Motion is followed with `wait`, streamed with
`stream_path` / `iter_path` (any length, paced by the daemon's queue) and, for G-code, with
`controller.client.job`.

Cancelling brakes: an exception (KeyboardInterrupt included) that leaves `wait`, a stream or a
job, or that leaves the `with Robot(...)` block while motion this Robot sent may still run,
sends `stop` first (the robot brakes to a hold), unless `brake=False` was given; a note on the
exception says how the stop went. A `WaitTimeout` from `wait` does not brake by itself (the
robot goes on), but brakes like any other error once it leaves the `with` block.

Threads: a Robot is one Zenoh session. Its methods may be called from several threads at once
(queries are independent; the pose is kept under a lock); the motion it follows (`wait`) is
the last one sent, whichever thread sent it. Callbacks (`on_pose`) run on a Zenoh thread: keep
them short and do not call a blocking method from them. A thread that calls a Robot must not
be a daemon thread (one still inside Zenoh's native code at the interpreter's exit aborts the
process). Resources: the session, its
subscribers and publishers are released by `close()` (or the end of the `with` block); a
Robot made on a session of the caller's (`session=`) leaves that session open.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Generator, Iterable, Mapping, Sequence
from contextlib import closing
from typing import Any

import controller.client.inputs as inputs
import controller.client.transport as transport
from controller.client.arrival import Arrival, ArrivalProgress, follow_arrival
from controller.client.errors import (
    Failed,
    InputError,
    Refused,
    WaitTimeout,
)
from controller.client.feed import Follower
from controller.client.link import QueryFn, RobotLink
from controller.client.model import (
    Pose,
    PretensionResult,
    Reply,
    Status,
)
from controller.client.pathcheck import PathFile, check_with_robot
from controller.client.stream import LOW_WATER_S, StreamProgress, StreamRefused, iter_points
from controller.core.commands import (
    MAX_PATH_POINTS_SENT,
    VERBS,
    CommandError,
    parse_command,
)
from controller.service import keys

ARMED_STATES = frozenset({"ARMING", "HOLDING", "MOVING", "PRETENSIONING"})
"""States in which the motors are armed (or arming): `arm` there is already done."""
ENDED_STATES = frozenset({"FAULT", "ESTOPPED", "DISARMED"})
"""States that end a followed arming, pre-tension or motion."""
ARM_FOLLOW_S = 10.0
"""How long `wait_armed` follows an arming by default (the daemon's own arming limit ends it
sooner)."""
ARM_POLL_S = 0.1
"""How often `wait_armed` asks the daemon how the arming goes (s)."""
PRETENSION_POLL_S = 0.2
"""How often `wait_pretension` asks the daemon how the pre-tension goes (s)."""
SAVE_WAIT_S = 10.0
"""How long `wait_pretension` waits, after the reels came to rest, for the daemon to report
the homing offsets on disk (a loaded host's fsync can take seconds)."""
WAIT_TIMEOUT_S = 120.0
"""How long `wait` and `wait_pretension` wait by default (s)."""


class Motion:
    """The motion a Robot sent last and may follow: its points (the last of them is its end)
    and its pose samples: since just before a single command was sent, or (a stream, a job:
    nothing to follow while it is sent) from when the follow begins (`follower` None until
    then)."""

    def __init__(
        self, points: Sequence[Sequence[float]], follower: Follower[Pose] | None = None
    ) -> None:
        self.points = [list(p) for p in points]
        self.follower = follower

    def close(self) -> None:
        """Stop following its pose samples (idempotent)."""
        if self.follower is not None:
            self.follower.close()


class Robot(RobotLink):
    """The robot a daemon runs, reached over Zenoh: read it (`RobotLink`), command it, follow
    its motion.

    `endpoint` is where the daemon listens (`tcp/HOST:PORT` or `HOST:PORT`; default
    `$CABLEBOT_ENDPOINT`, else `tcp/127.0.0.1:7447`), `prefix` its key prefix (`cablebot/<robot
    name>`; default `$CABLEBOT_PREFIX`, else `cablebot/default`), `zenoh_config` a Zenoh JSON5
    file for this client (TLS certificates, say), `timeout_s` how long a reply or a pose sample
    may take. With `session`, the Robot uses that open Zenoh session instead of opening one
    (and does not close it); `query` replaces the function that sends one query (tools that
    record or replay the traffic).

    Raises UsageError for an endpoint or configuration file that cannot be used, DaemonAbsent
    when nothing accepts the connection (a daemon that is there but does not answer on
    `prefix` shows at the first query instead), InputError for a `timeout_s` that is not a
    number of seconds > 0.
    """

    def __init__(
        self,
        endpoint: str | None = None,
        prefix: str | None = None,
        *,
        zenoh_config: str | None = None,
        timeout_s: float = transport.DEFAULT_TIMEOUT_S,
        session: Any = None,
        query: QueryFn | None = None,
    ) -> None:
        self._motion: Motion | None = None
        super().__init__(
            endpoint,
            prefix,
            zenoh_config=zenoh_config,
            timeout_s=timeout_s,
            session=session,
            query=query,
        )

    def close(self) -> None:
        """`RobotLink.close`; motion in progress goes on (nothing is followed any more)."""
        self.forget_motion()
        super().close()

    def __enter__(self) -> Robot:
        return self

    def __exit__(self, exc_type: Any, exc: BaseException | None, tb: Any) -> None:
        try:
            if exc is not None:
                self.brake_if_moving(exc)
        finally:
            self.close()

    # ---------------------------------------------------------------------------- commanding
    def command(self, verb: str, payload: Mapping[str, Any] | None = None) -> Reply:
        """Send any verb of the command table (`controller.core.commands.VERBS`) with its
        JSON payload; the daemon's reply. The payload is checked as the daemon checks it first.
        Raises InputError (an unknown verb or a payload the daemon would refuse as malformed;
        nothing sent), Refused, DaemonAbsent."""
        if verb not in VERBS:
            raise InputError(f"unknown command {verb!r}; known: {', '.join(VERBS)}")
        body = None if payload is None else dict(payload)
        try:
            parse_command(verb, None if body is None else json.dumps(body, allow_nan=False))
        except (CommandError, ValueError) as exc:
            raise InputError(f"{verb}: {exc}") from None
        return self._send(verb, body)

    def _send(self, verb: str, payload: dict[str, Any] | None) -> Reply:
        reply = Reply.from_reply(verb, self.query(keys.command(verb), payload))
        if verb in ("stop", "estop", "disarm"):
            self.forget_motion()
        return reply

    def move(self, position_m: Sequence[float], *, speed_mps: float | None = None) -> Reply:
        """Move in a straight line to `position_m` (at `speed_mps`, at most the robot's
        `limits.max_speed_mps`; by default the robot's speed). `wait()` follows it. Raises
        InputError (nothing sent: bad numbers, a speed above the robot's maximum), Refused
        (outside the workspace or the limits, not allowed in this state), DaemonAbsent."""
        target = inputs.point(position_m, "move")
        payload: dict[str, Any] = {"position_m": target}
        speed = inputs.speed(speed_mps, "speed_mps")
        if speed is not None:
            check_with_robot(self, speed, None, speed_option="speed_mps")
            payload["speed_mps"] = speed
        return self._motion_command("move", payload, [target])

    def path(
        self,
        points_m: Iterable[Sequence[float]],
        *,
        speed_mps: float | None = None,
        append: bool = False,
    ) -> Reply:
        """Fly through `points_m` (at most `MAX_PATH_POINTS_SENT`; longer: `stream_path`), with
        rounded corners; `append` adds them to the path in progress. `wait()` follows it. The
        whole path is checked first against the daemon's robot (`pathcheck`). Raises
        InputError (nothing sent: bad numbers, a point the robot refuses, a speed above its
        maximum), Refused, DaemonAbsent."""
        pts = inputs.points(points_m, "points_m")
        if len(pts) > MAX_PATH_POINTS_SENT:
            raise InputError(
                f"points_m: {len(pts)} points; one path command takes at most"
                f" {MAX_PATH_POINTS_SENT}: stream_path sends any number"
            )
        payload: dict[str, Any] = {"points_m": pts}
        speed = inputs.speed(speed_mps, "speed_mps")
        check_with_robot(
            self, speed, PathFile("points_m", pts, None, append, "path"), speed_option="speed_mps"
        )
        if speed is not None:
            payload["speed_mps"] = speed
        if append:
            payload["append"] = True
        return self._motion_command("path", payload, pts)

    def send_motion(
        self,
        verb: str,
        payload: dict[str, Any],
        points: Sequence[Sequence[float]],
        *,
        follow: bool = True,
    ) -> Reply:
        """Send a `move` or `path` payload checked already (a path file read by
        `inputs.read_path_file`), to be followed to the last of `points` by `wait()` (unless
        not `follow`: then nothing subscribes to the pose). Raises Refused, DaemonAbsent."""
        if not follow:
            return self._send(verb, payload)
        return self._motion_command(verb, payload, points)

    def _motion_command(
        self, verb: str, payload: dict[str, Any], points: Sequence[Sequence[float]]
    ) -> Reply:
        # Follow the pose from before the command goes: no sample after the reply is missed.
        motion = Motion(points, self._pose_feed().follow())
        try:
            reply = self._send(verb, payload)
        except BaseException:
            motion.close()
            raise
        self._set_motion(motion)
        return reply

    def _set_motion(self, motion: Motion | None) -> None:
        with self._lock:
            old, self._motion = self._motion, motion
        if old is not None and old is not motion:
            old.close()

    def expect_motion(self, points: Sequence[Sequence[float]]) -> Motion:
        """Follow a motion about to be sent other than by this Robot's own methods (a job):
        its end is the last of `points`; `wait()` follows it and a cancel brakes it. Returns
        the motion (for `forget_motion`). Raises nothing."""
        motion = Motion(points)
        self._set_motion(motion)
        return motion

    def forget_motion(self, motion: Motion | None = None) -> None:
        """Stop following the motion sent last (only `motion`, when given): it ended, or the
        robot no longer moves. Raises nothing."""
        with self._lock:
            old = self._motion
            if old is None or (motion is not None and old is not motion):
                return
            self._motion = None
        old.close()

    @property
    def moving(self) -> bool:
        """True while motion this Robot sent may still run (sent, not yet waited to its end,
        stopped or braked)."""
        return self._motion is not None

    def stop(self) -> Reply:
        """Decelerate to a hold. Raises Refused, DaemonAbsent."""
        return self._send("stop", None)

    def estop(self) -> Reply:
        """Emergency stop: the motors are disarmed at once (latched until `reset`). Raises
        Refused, DaemonAbsent."""
        return self._send("estop", None)

    def arm(self) -> Reply:
        """Arm the motors and hold the current pose (state ARMING, then HOLDING: `wait_armed`
        follows it). A robot armed already is a success (`Reply.already_armed`). Raises
        Refused, DaemonAbsent."""
        try:
            return self._send("arm", None)
        except Refused:
            state = self.status().state
            if state not in ARMED_STATES:
                raise
            raw = {"ok": True, "state": state, "already_armed": True}
            return Reply.from_reply("arm", raw)

    def disarm(self) -> Reply:
        """Disarm the motors (they go idle: support the load first). Raises Refused,
        DaemonAbsent."""
        return self._send("disarm", None)

    def reset(self) -> Reply:
        """Clear FAULT or ESTOPPED back to DISARMED. Raises Refused, DaemonAbsent."""
        return self._send("reset", None)

    def home(self, position_m: Sequence[float]) -> Reply:
        """Declare that the effector is now at `position_m` (sets and saves the reel offsets).
        Raises InputError, Refused, DaemonAbsent."""
        return self._send("home", {"position_m": inputs.point(position_m, "home")})

    def pretension(self, position_m: Sequence[float]) -> Reply:
        """Start homing with pre-tension at `position_m`: every reel pulls in torque control
        until they are still, then the effector is declared there (`wait_pretension` follows
        it; needs `[payload]`). Raises InputError, Refused, DaemonAbsent."""
        return self._send("pretension", {"position_m": inputs.point(position_m, "pretension")})

    # ---------------------------------------------------------------------------- following
    def brake_if_moving(self, exc: BaseException | None = None) -> Reply | None:
        """Send `stop` if motion this Robot sent may still run (`moving`); the reply, or None
        when nothing ran or the stop failed. Adds a note saying how the stop went to `exc`.
        Never raises."""
        motion = self._motion
        if motion is None:
            return None
        self.forget_motion(motion)
        try:
            reply = self._send("stop", None)
        except Exception as err:  # the daemon gone, a refusal: say so, never mask `exc`
            if exc is not None:
                exc.add_note(f"braking to a hold: stop not confirmed: {err}")
            return None
        if exc is not None:
            exc.add_note(f"braked to a hold: stop sent, state {reply.state}")
        return reply

    def wait(
        self,
        timeout_s: float = WAIT_TIMEOUT_S,
        *,
        on_progress: Callable[[ArrivalProgress], None] | None = None,
        brake: bool = True,
        cancel: threading.Event | None = None,
    ) -> Pose:
        """Wait until the motion this Robot sent last (`move`, `path`, a stream or job) has
        arrived: HOLDING within 1 mm of its end. Returns the arrival sample. `on_progress`
        gets the distance still to travel with every sample.

        Raises WaitTimeout after `timeout_s` (the robot goes on), Failed when the robot went
        FAULT, ESTOPPED or DISARMED or the motion ended short of its end (stopped by another
        client, replaced), DaemonAbsent when no pose arrives, InputError when nothing was sent
        to wait for, Cancelled soon after another thread sets `cancel`. An exception or
        KeyboardInterrupt meanwhile (Cancelled too) brakes the robot to a hold (with
        `brake`)."""
        motion = self._motion
        wait_s = inputs.positive_s(timeout_s, "timeout_s")
        try:
            samples, arrival = self.arrival()
            pose = follow_arrival(
                samples.get,
                arrival,
                wait_timeout_s=wait_s,
                sample_timeout_s=self.timeout_s,
                status=self.status,
                on_progress=on_progress,
                cancelled=None if cancel is None else cancel.is_set,
            )
        except WaitTimeout:
            raise  # the robot goes on
        except Failed:
            self.forget_motion(motion)  # the robot stopped, or holds where the motion ended
            raise
        except BaseException as exc:
            if brake:
                self.brake_if_moving(exc)
            raise
        self.forget_motion(motion)
        return pose

    def arrival(self) -> tuple[Follower[Pose], Arrival]:
        """The motion sent last, ready to follow: its pose samples (from just before it was
        sent, or from now for a stream or a job) and its arrival rule
        (`controller.client.arrival`). Samples from before the daemon took the command may
        stand HOLDING where a path also ends: unless the status (asked after the samples are
        followed) says the motion is over already, the rule waits to see it move. Raises
        InputError when nothing was sent to follow, DaemonAbsent, Refused."""
        motion = self._motion
        if motion is None:
            raise InputError("nothing to wait for: no motion sent since the last wait or stop")
        if motion.follower is None:
            motion.follower = self._pose_feed().follow()
        return motion.follower, Arrival(motion.points, seen_moving=self.status().state != "MOVING")

    def wait_armed(self, timeout_s: float = ARM_FOLLOW_S) -> Status:
        """Follow an arming (state ARMING) until it ends; returns the status then (still
        ARMING after `timeout_s`: the daemon goes on). Raises Failed when the arming ended in
        FAULT, ESTOPPED or DISARMED, DaemonAbsent."""
        deadline = time.monotonic() + inputs.positive_s(timeout_s, "timeout_s")
        while True:
            st = self.status()
            if st.state in ENDED_STATES:
                raise Failed(f"the arming ended in {st.state}: {st.reason}")
            if st.state != "ARMING" or time.monotonic() >= deadline:
                return st
            time.sleep(ARM_POLL_S)

    def wait_pretension(
        self,
        timeout_s: float = WAIT_TIMEOUT_S,
        *,
        on_progress: Callable[[Status, float], None] | None = None,
    ) -> PretensionResult:
        """Follow a pre-tension until it ends; returns its result (the reels came to rest and
        the robot is homed, HOLDING), once the daemon has said whether the offsets are saved
        (at most `SAVE_WAIT_S` later: then `result.saving` is still True). `on_progress(status,
        elapsed_s)` is called at every status poll. Raises Failed when it ended otherwise
        (FAULT, or another state without homing), WaitTimeout after `timeout_s` (the daemon
        goes on), DaemonAbsent."""
        wait_s = inputs.positive_s(timeout_s, "timeout_s")
        t0 = time.monotonic()
        saving_since: float | None = None
        while True:
            st = self.status()
            result = st.pretension.result
            if st.state != "PRETENSIONING":
                if st.state == "HOLDING" and result is not None and result.ok:
                    now = time.monotonic()
                    if saving_since is None:
                        saving_since = now
                    if not result.saving or now - saving_since >= SAVE_WAIT_S:
                        return result
                    time.sleep(PRETENSION_POLL_S)
                    continue
                raise Failed(f"the pre-tension ended in {st.state}: {st.reason}")
            elapsed = time.monotonic() - t0
            if elapsed > wait_s:
                raise WaitTimeout(f"still pretensioning after {wait_s:g} s (the daemon goes on)")
            if on_progress is not None:
                on_progress(st, elapsed)
            time.sleep(PRETENSION_POLL_S)

    def iter_path(
        self,
        points_m: Iterable[Sequence[float]],
        *,
        speed_mps: float | None = None,
        append: bool = False,
        brake: bool = True,
        low_water_s: float = LOW_WATER_S,
        check: bool = True,
    ) -> Generator[StreamProgress, None, None]:
        """Stream a path of any length: the first points as a path (with `append`: added to the
        path in progress), the rest appended in chunks while the daemon's queue holds less
        than `low_water_s` of motion. Yields the progress after every chunk and every poll of
        the queue; the stream is done when the iterator ends (`wait()` then follows the robot
        to the last point). Every point is checked before the first is sent: its numbers, and
        (with `check`) the whole path against the daemon's robot (`pathcheck`).

        Raises InputError (nothing sent); while iterating: Refused (a chunk refused, or the
        robot left HOLDING/MOVING; how far it got in the message), DaemonAbsent. Closing the
        iterator early, or an exception meanwhile, brakes the robot to a hold (with `brake`).
        """
        pts = inputs.points(points_m, "points_m")
        speed = inputs.speed(speed_mps, "speed_mps")
        if check:
            path = PathFile("points_m", pts, None, append, "path")
            check_with_robot(self, speed, path, speed_option="speed_mps")
        return self._stream(pts, speed, append, brake, low_water_s)

    def _stream(
        self,
        pts: list[list[float]],
        speed: float | None,
        append: bool,
        brake: bool,
        low_water_s: float,
    ) -> Generator[StreamProgress, None, None]:
        motion = self.expect_motion(pts[-MAX_PATH_POINTS_SENT:])  # followed from `arrival()`
        steps = iter_points(
            pts,
            lambda part, more: self.path_chunk(part, speed_mps=speed, append=more or append),
            self.status_map,
            refused=Refused,
            low_water_s=low_water_s,
            append_first=append,
        )
        try:
            for prog in steps:
                yield prog.snapshot()
        except StreamRefused as exc:
            raise Refused(str(exc)) from None
        except BaseException as exc:  # GeneratorExit too: the caller gave up on the stream
            if brake and self._motion is motion:
                self.brake_if_moving(None if isinstance(exc, GeneratorExit) else exc)
            raise

    def path_chunk(
        self, points_m: list[list[float]], *, speed_mps: float | None, append: bool
    ) -> dict[str, Any]:
        """One chunk of a stream as `iter_path` sends it (`controller.client.stream`): the path
        command with `append` as its flag, points checked already; the reply as sent ({} if it
        is not an object). Raises Refused, DaemonAbsent."""
        payload: dict[str, Any] = {"points_m": points_m, "append": append}
        if speed_mps is not None:
            payload["speed_mps"] = speed_mps
        reply = self.query(keys.command("path"), payload)
        return reply if isinstance(reply, dict) else {}

    def stream_path(
        self,
        points_m: Iterable[Sequence[float]],
        *,
        speed_mps: float | None = None,
        append: bool = False,
        on_progress: Callable[[StreamProgress], None] | None = None,
        brake: bool = True,
        low_water_s: float = LOW_WATER_S,
        check: bool = True,
    ) -> StreamProgress:
        """`iter_path` with a callback: `on_progress` gets each progress; returns the last
        (every point sent). Raises as `iter_path`; an exception in `on_progress` brakes the
        robot to a hold (with `brake`) and is raised."""
        last = StreamProgress(total=0)
        it = self.iter_path(
            points_m,
            speed_mps=speed_mps,
            append=append,
            brake=brake,
            low_water_s=low_water_s,
            check=check,
        )
        with closing(it) as steps:
            try:
                for last in steps:
                    if on_progress is not None:
                        on_progress(last)
            except (Refused, WaitTimeout):
                raise
            except BaseException as exc:  # the callback's: brake first, saying so on it
                if brake:
                    self.brake_if_moving(exc)
                raise
        return last
