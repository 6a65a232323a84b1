"""Command execution: the thread-safe submit API, preparing moves and paths off the tick, and in
the tick one small handler per verb, dispatched after `controller.core.states.COMMAND_RULES`
allowed the verb in the current state; the limit checks commands and set-points get.
"""

from __future__ import annotations

import concurrent.futures
import math
import queue
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from controller.core.commands import (
    Arm,
    Command,
    CommandRefused,
    Disarm,
    Estop,
    Home,
    Move,
    Path,
    Pretension,
    Reset,
    Setpoint,
    Shaper,
    Stop,
    Vec3,
    Velocity,
)
from controller.core.motion import QueueError, check_speed, dedupe_path
from controller.core.motion.shaper import ShaperError
from controller.core.states import ARMED_STATES, State, refusal
from controller.core.vibration import ModesError
from controller.core.workspace import points_array
from controller.service.control.base import (
    CONFLICT_HOLDOFF_S,
    TENSION_MAX_SAMPLES,
    Reply,
    _chain,
    _fmt,
    _Motion,
    log,
)
from controller.service.control.homing import Homing
from drivers.base import ArmRefused, AxisReading

_VERBS: Mapping[type, str] = {
    Move: "move",
    Path: "path",
    Stop: "stop",
    Estop: "estop",
    Arm: "arm",
    Disarm: "disarm",
    Reset: "reset",
    Home: "home",
    Pretension: "pretension",
    Setpoint: "setpoint",
    Velocity: "velocity",
    Shaper: "shaper",
}
_MAX_COMMANDS_PER_TICK = 8


class CommandExecution(Homing):
    """The controller's commands: submitting, preparing, checking and executing them."""

    # ---------------------------------------------------------------- thread-safe API

    def submit(self, cmd: Command) -> concurrent.futures.Future[dict[str, Any]]:
        """Queue `cmd` for the loop; the future resolves with a reply dict or CommandRefused.

        Estop bypasses the queue (it is never refused as busy). A full queue refuses at once
        with CommandRefused("busy"). Setpoint and Velocity commands go to `submit_setpoint` /
        `submit_velocity`.
        """
        fut: concurrent.futures.Future[dict[str, Any]] = concurrent.futures.Future()
        if isinstance(cmd, Estop):
            with self._estop_lock:
                self._estop_futures.append(fut)
                self._estop_flag = True
            return fut
        if isinstance(cmd, Setpoint | Velocity):
            try:
                if isinstance(cmd, Setpoint):
                    why = self._offer_setpoint(cmd.position_m)
                else:
                    why = self._offer_velocity(cmd.velocity_mps)
            except ValueError as exc:
                why = str(exc)
            if why is None:
                fut.set_result({"ok": True})
            else:
                fut.set_exception(CommandRefused(why))
            return fut
        motion = None
        if isinstance(cmd, Move | Path):
            # Here, in the submitting thread: O(number of points), so never in the tick.
            motion = self._prepare_motion(cmd)
        try:
            self._queue.put_nowait((cmd, fut, motion, next(self._arrivals)))
        except queue.Full:
            fut.set_exception(CommandRefused("busy: command queue full"))
        return fut

    def request_estop(self) -> None:
        """Ask for an e-stop at the start of the next tick (thread-safe, never blocks)."""
        with self._estop_lock:
            self._estop_flag = True

    def submit_setpoint(self, position_m: Sequence[float]) -> None:
        """Stream a target position; the latest one wins, validated and limited in the tick.

        Taken only while HOLDING or MOVING (`COMMAND_RULES`); otherwise discarded and counted.
        Raises ValueError/TypeError/IndexError for a position that is not three numbers.
        """
        self._offer_setpoint(position_m)

    def _offer_setpoint(self, position_m: Sequence[float]) -> str | None:
        """Store a streamed set-point for the tick, or return why the state discards it."""
        p = (float(position_m[0]), float(position_m[1]), float(position_m[2]))
        # Read the session before the state: if the state then says armed, the session read is
        # that one or an earlier one (discarded by the tick), never a later one.
        epoch = self._arm_epoch
        state = self.state
        why = refusal(state, "setpoint")
        if why is not None:
            text = self._refusal_text(state, why)
            self.stream_last_discard = text
            self.stream_discarded += 1  # after the reason: a reader of the count finds it
            return text
        self._stream_target = (p, epoch, next(self._arrivals))  # one assignment: atomic
        return None

    def submit_velocity(self, velocity_mps: Sequence[float]) -> None:
        """Velocity input: fly at `velocity_mps` (latest wins; see `controller.service.loop`).

        Taken only while HOLDING or MOVING (`COMMAND_RULES`); otherwise discarded and counted.
        Raises ValueError/TypeError/IndexError for a velocity that is not three finite numbers.
        """
        self._offer_velocity(velocity_mps)

    def _offer_velocity(self, velocity_mps: Sequence[float]) -> str | None:
        """Store a velocity sample for the tick, or return why the state discards it."""
        v = (float(velocity_mps[0]), float(velocity_mps[1]), float(velocity_mps[2]))
        if not (math.isfinite(v[0]) and math.isfinite(v[1]) and math.isfinite(v[2])):
            raise ValueError(f"velocity_mps must be finite, got {list(v)}")
        epoch = self._arm_epoch  # before the state: see `_offer_setpoint`
        state = self.state
        why = refusal(state, "velocity")
        if why is not None:
            self.velocity_discarded += 1
            return self._refusal_text(state, why)
        self._velocity_cmd = (v, epoch)  # one reference assignment: atomic
        return None

    def _prepare_motion(self, cmd: Move | Path) -> _Motion:
        """Check a move's or path's points, legs and speed and prepare them for the planner.

        Reads only immutable limits and configuration: safe in any thread. Vectorised over the
        points; the leg from where the set-point comes to rest to the first point depends on
        the state and is checked in the tick. Raises nothing (a problem becomes `refusal`).
        """
        limited: float | None = None
        if cmd.speed_mps is None:
            speed = self._default_speed_mps
        else:
            why = check_speed(cmd.speed_mps)
            if why is not None:
                return _Motion((), 0.0, None, f"speed_mps: {why}")
            speed = float(cmd.speed_mps)
            vmax = float(self.cfg.limits.max_speed_mps)
            if speed > vmax:
                speed = limited = vmax
        if isinstance(cmd, Move):
            points: Sequence[Vec3] = (cmd.position_m,)
        else:
            points = cmd.points_m
        try:
            arr = points_array(points) if len(points) > 1 else None
            failure = self.workspace.path_failure(points, array=arr)
            if failure is None and self.tension is not None:
                failure = self._tension_failure(points, None)
            if failure is not None:
                i, why = failure
                where = "target" if isinstance(cmd, Move) else f"points_m[{i}]"
                return _Motion((), speed, limited, f"{where} {_fmt(points[i])}: {why}")
            if (
                arr is not None
                and type(points) is tuple
                and bool(np.all(np.any(arr[1:] != arr[:-1], axis=1)))
            ):
                pts: tuple[Vec3, ...] = points  # checked finite, no repeats: as it is
            else:
                pts = dedupe_path(points)
        except Exception as exc:  # e.g. a malformed point built in code: refuse, do not raise
            return _Motion((), speed, limited, f"invalid points: {exc}")
        return _Motion(pts, speed, limited, None)

    def begin_shutdown(self) -> concurrent.futures.Future[dict[str, Any]]:
        """Start a shutdown: from now on no new motion is taken (move, path, streamed set-points,
        arm, home are refused or ignored) and any motion brakes to a hold at `max_accel_mps2`
        (a queued Stop, whose future is returned). Thread-safe; the loop keeps running."""
        self._closing = True
        return self.submit(Stop())

    # ---------------------------------------------------------------- commands in the tick

    def _take_commands(self, readings: Sequence[AxisReading], now_s: float) -> None:
        for _ in range(_MAX_COMMANDS_PER_TICK):
            try:
                cmd, fut, motion, arrived = self._queue.get_nowait()
            except queue.Empty:
                return
            if not fut.set_running_or_notify_cancel():
                continue
            try:
                reply = self._execute(cmd, readings, now_s, motion)
            except CommandRefused as exc:
                log.info("refused %s: %s", type(cmd).__name__.lower(), exc)
                fut.set_exception(exc)
            except Exception as exc:  # a bug must not kill the loop
                log.exception("command %r failed", cmd)
                fut.set_exception(CommandRefused(f"internal error: {exc}"))
            else:
                if isinstance(cmd, Move | Path | Stop):
                    self._motion_taken_at = arrived
                if isinstance(reply, concurrent.futures.Future):  # answered later (homing save)
                    reply.add_done_callback(_chain(fut))
                else:
                    fut.set_result(reply)

    def _refusal_text(self, state: State, why: str) -> str:
        """The refusal message for a verb `state` refuses with reason `why` (COMMAND_RULES)."""
        if state is State.FAULT or state is State.ESTOPPED:
            return f"not allowed in {state.value} ({self.reason}): {why}"
        return f"not allowed in {state.value}: {why}"

    def _execute(
        self,
        cmd: Command,
        readings: Sequence[AxisReading],
        now_s: float,
        motion: _Motion | None = None,
    ) -> Reply:
        """Carry out one command in the tick: its reply, or a future of it when it comes later
        (a homing save). Raises CommandRefused when the state or the limits refuse it."""
        verb = _VERBS.get(type(cmd))
        if verb is None:
            raise CommandRefused(f"unsupported command {type(cmd).__name__}")
        if self._closing and isinstance(cmd, Move | Path | Arm | Home | Pretension):
            raise CommandRefused("shutting down: no new motion")
        why = refusal(self.state, verb)
        if why is not None:
            raise CommandRefused(self._refusal_text(self.state, why))
        handler = _HANDLERS.get(verb)
        if handler is None:  # estop, setpoint, velocity: taken outside the queue
            raise CommandRefused(f"unsupported command {type(cmd).__name__}")
        return handler(self, cmd, readings, now_s, motion)

    # ----------------------- one handler per verb (called by `_execute` once the state allowed it)

    def _cmd_motion(
        self,
        cmd: Move | Path,
        readings: Sequence[AxisReading],
        now_s: float,
        motion: _Motion | None,
    ) -> Reply:
        """`move`, `path`: start the prepared motion; a path with `append` joins the path in
        progress. The reply of a path carries the queue's depth after it (`queued_points`,
        `queued_s`, `queue_full`). Raises CommandRefused (the limits, the queue)."""
        if motion is None:  # not submitted through `submit`: prepare it here
            motion = self._prepare_motion(cmd)
        if isinstance(cmd, Path) and cmd.append:
            self._append_motion(motion)
        else:
            self._start_motion(motion, cmd)
        reply: dict[str, Any] = {"ok": True}
        if isinstance(cmd, Move):
            reply["target_m"] = list(cmd.position_m)
        else:
            reply["points"] = len(cmd.points_m)
            reply["append"] = cmd.append
        reply["speed_mps"] = motion.speed_mps
        if motion.limited_to_mps is not None:
            reply["speed_limited_to_mps"] = motion.limited_to_mps
        if isinstance(cmd, Path):
            planner = self.planner
            reply["queued_points"] = planner.queued_points
            reply["queued_s"] = planner.queued_s
            reply["queue_full"] = planner.queue_full
        return reply

    def _cmd_stop(
        self, cmd: Stop, readings: Sequence[AxisReading], now_s: float, motion: _Motion | None
    ) -> Reply:
        """`stop`: end a pre-tension where the reels are, or brake the motion to a hold."""
        if self.state is State.PRETENSIONING:
            self._stop_pretension()
        elif self.state in ARMED_STATES:
            self.planner.stop()
            if self.state is State.MOVING:
                why = "the daemon's shutdown" if self._closing else "a `stop` command"
                self._stop_brake = (self.planner.rest_point_m, f"stopped by {why}")
        return {"ok": True, "state": self.state.value}

    def _cmd_shaper(
        self, cmd: Shaper, readings: Sequence[AxisReading], now_s: float, motion: _Motion | None
    ) -> Reply:
        """`shaper`: a new input shaper, applied now when the set-point is at rest, else when
        the motion ends. Raises CommandRefused for the model's frequency without a model."""
        at = self.setpoint_m if self.setpoint_m is not None else (0.0, 0.0, 0.0)
        try:
            when = self.shaping.change(cmd.type, cmd.frequency_hz, cmd.damping_ratio, at)
        except (ShaperError, ModesError) as exc:
            raise CommandRefused(f"shaper: {exc}") from None
        log.info("shaper %s (%s)", self.shaping.describe(), when)
        return {
            "ok": True,
            "state": self.state.value,
            "applies": when,
            "shaper": self.shaping.describe(),
        }

    def _cmd_arm(
        self, cmd: Arm, readings: Sequence[AxisReading], now_s: float, motion: _Motion | None
    ) -> Reply:
        """`arm`: closed loop, holding the motors where they are. Raises CommandRefused when
        not homed or when the bus fails."""
        if not self.homed:
            raise CommandRefused("not homed: run `home` at a known pose first")
        lost = self._count_lost(readings)
        if lost is not None:
            raise CommandRefused(f"not homed: {lost}")
        res = self.residual_m
        if self.pose_valid and res is not None and res > self._residual_max_m:
            # Arming would fault on it at once (the residual rule of every armed state).
            raise CommandRefused(
                f"residual: {res * 1e3:.1f} mm > {self._residual_max_m * 1e3:.1f} mm: the cables"
                " disagree (slack or slipped cable): home at a known pose, or pretension, first"
            )
        since = self._conflict_s
        if since is not None and now_s - since < CONFLICT_HOLDOFF_S:
            raise CommandRefused(
                f"bus_conflict: {self.driver.stats.last_conflict} (heard {now_s - since:.1f} s ago)"
            )
        try:
            self.driver.arm()
        except ArmRefused as exc:  # e.g. a restarted drive being configured beside the loop
            raise CommandRefused(f"not_ready: arm: {exc}") from None
        except Exception as exc:
            raise CommandRefused(f"bus_error: arm: {exc}") from None
        self._arm_start_s = now_s
        self._arm_rev = None
        self.commanded_rev = None
        self.setpoint_m = None
        self.setpoint_lengths_m = None
        # A new armed session: set-points streamed before it are never taken.
        self._arm_epoch += 1
        self._stream_target = None
        self._velocity_cmd = None
        self._set_state(State.ARMING)
        return {"ok": True, "state": State.ARMING.value}

    def _cmd_disarm(
        self, cmd: Disarm, readings: Sequence[AxisReading], now_s: float, motion: _Motion | None
    ) -> Reply:
        """`disarm`: idle the motors. Raises nothing."""
        self._disarm("disarm")
        return {"ok": True, "state": self.state.value}

    def _cmd_reset(
        self, cmd: Reset, readings: Sequence[AxisReading], now_s: float, motion: _Motion | None
    ) -> Reply:
        """`reset`: from FAULT or ESTOPPED back to DISARMED. Raises nothing."""
        if self.state is not State.DISARMED:
            self._disarm("reset")
        return {"ok": True, "state": self.state.value}

    def _cmd_home(
        self, cmd: Home, readings: Sequence[AxisReading], now_s: float, motion: _Motion | None
    ) -> Reply:
        """`home`: `_execute_home`. Raises CommandRefused as it does."""
        return self._execute_home(cmd, readings, now_s)

    def _cmd_pretension(
        self,
        cmd: Pretension,
        readings: Sequence[AxisReading],
        now_s: float,
        motion: _Motion | None,
    ) -> Reply:
        """`pretension`: `_start_pretension`. Raises CommandRefused as it does."""
        return self._start_pretension(cmd, readings, now_s)

    def _start_motion(self, motion: _Motion, cmd: Move | Path) -> None:
        """Start a prepared move or path (a move is a one-point path): O(1) in its length.

        Raises CommandRefused (nothing changed) if the preparation refused it or if the first
        leg leaves the limits; that leg starts where the set-point will come to rest (a motion
        that arrives while moving first brakes to a stop).
        """
        if motion.refusal is not None:
            raise CommandRefused(motion.refusal)
        if self.setpoint_m is not None:
            self._check_first_leg(motion, self.planner.rest_point_m, isinstance(cmd, Move))
        try:
            self.planner.follow_points(motion.points_m, motion.speed_mps)
        except QueueError as exc:  # more points than the queue holds: nothing changed
            raise CommandRefused(str(exc)) from None
        self.path_speed_mps = motion.speed_mps
        if self.state is State.HOLDING:
            self._set_state(State.MOVING, "move" if isinstance(cmd, Move) else "path")

    def _append_motion(self, motion: _Motion) -> None:
        """Append a prepared path to the path in progress (no braking): O(1) in its length.

        The leg checked is from the last queued point (`planner.target_m`) to the first
        appended point. A path that ran dry (HOLDING at its last point) continues (MOVING).
        Raises CommandRefused (nothing changed) if the preparation refused it, the leg leaves
        the limits, no path takes appends (none sent, or it was stopped, replaced or held:
        an append never starts motion on its own) or the queue is full (with its depth: retry
        when it has drained).
        """
        if motion.refusal is not None:
            raise CommandRefused(motion.refusal)
        planner = self.planner
        if not planner.appendable:
            raise CommandRefused(
                "no path in progress to append to (none sent, or it was stopped, replaced or "
                "held since): send the first points as a path without append"
            )
        self._check_first_leg(motion, planner.target_m, False)
        try:
            planner.append_prepared(motion.points_m, motion.speed_mps)
        except QueueError as exc:
            raise CommandRefused(
                f"{exc}: {planner.queued_points} points ({planner.queued_s:.1f} s of motion) "
                f"queued; retry when fewer are queued"
            ) from None
        self.path_speed_mps = motion.speed_mps
        if self.state is State.HOLDING and planner.moving:
            self._set_state(State.MOVING, "path")

    def _check_first_leg(self, motion: _Motion, start: Vec3, is_move: bool) -> None:
        """Raise CommandRefused if the leg from `start` to the motion's first point leaves the
        workspace or (with `[payload]`) the tension rule."""
        first = motion.points_m[0]
        reason = self.workspace.check_segment(start, first)
        if reason is None and self.tension is not None:
            failure = self._tension_failure((first,), start)
            reason = None if failure is None else failure[1].removeprefix("on the leg to it: ")
        if reason is not None:
            where = "target" if is_move else "points_m[0]"
            raise CommandRefused(
                f"{where} {_fmt(first)}: on the leg to it from {_fmt(start)}: {reason}"
            )

    # ----------------------------------------------------------- limits of commands and set-points

    def _check_segment(self, a: Sequence[float], b: Sequence[float]) -> str | None:
        """Velocity mode's look-ahead: `Workspace.check_segment`, then with `[payload]` the
        tension rule at points `_tension_step_m` apart along a->b (b included; a is where the
        set-point is). Scalar: the look-ahead is a braking distance, a few samples. Raises
        nothing."""
        reason = self.workspace.check_segment(a, b)
        chk = self.tension
        if reason is not None or chk is None:
            return reason
        ax, ay, az = float(a[0]), float(a[1]), float(a[2])
        dx, dy, dz = float(b[0]) - ax, float(b[1]) - ay, float(b[2]) - az
        n = max(1, math.ceil(math.sqrt(dx * dx + dy * dy + dz * dz) / self._tension_step_m))
        for k in range(1, n + 1):
            f = k / n
            q = (ax + f * dx, ay + f * dy, az + f * dz)
            why = chk.check(q)
            if why is not None:
                return f"at {_fmt(q)}: {why}"
        return None

    def _check_target(self, p: Sequence[float]) -> str | None:
        """Why `p` is not an allowed target (`Workspace.check_target`, then with `[payload]`
        the payload's cable tensions within their limits and margin), or None if it is.
        Raises nothing."""
        reason = self.workspace.check_target(p)
        if reason is None and self.tension is not None:
            reason = self.tension.check(p)
        return reason

    def _tension_failure(
        self, points: Sequence[Sequence[float]], start_m: Sequence[float] | None
    ) -> tuple[int, str] | None:
        """The first point of `points` (or point on the leg to it, from `start_m` for point 0)
        where the payload cannot be held by the tension rule, as (index, reason), or None.

        Each leg is sampled every `TENSION_SAMPLE_FRACTION` of the anchors' span (coarser if
        that would exceed `TENSION_MAX_SAMPLES`) and solved in one batch; the first failing
        sample is solved again for its reason. Raises nothing for finite points (checked by
        the limits before)."""
        chk = self.tension
        assert chk is not None
        return chk.path_failure(points, start_m, self._tension_step_m, TENSION_MAX_SAMPLES)


_HANDLERS: Mapping[
    str, Callable[[CommandExecution, Any, Sequence[AxisReading], float, _Motion | None], Reply]
] = {
    "move": CommandExecution._cmd_motion,
    "path": CommandExecution._cmd_motion,
    "stop": CommandExecution._cmd_stop,
    "arm": CommandExecution._cmd_arm,
    "disarm": CommandExecution._cmd_disarm,
    "reset": CommandExecution._cmd_reset,
    "home": CommandExecution._cmd_home,
    "pretension": CommandExecution._cmd_pretension,
    "shaper": CommandExecution._cmd_shaper,
}
"""The handler of each verb of `controller.core.states.COMMAND_VERBS` that goes through the
command queue (estop, streamed set-points and velocity samples do not)."""
