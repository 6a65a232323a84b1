"""`MotionPlanner`: the set-point generator of the control loop, its queries and commands
(behaviour: the package docstring)."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Sequence

from .corners import _Piece, _point_at
from .modes import _Modes
from .queue import QUEUE_FULL, QueueError
from .speeds import (
    _HOLD,
    _MODE_NAMES,
    _MOVE,
    _STOP,
    _STREAM,
    _VELOCITY,
    _ZERO,
    DEFAULT_JUNCTION_DEVIATION_M,
    DEFAULT_MAX_QUEUED_POINTS,
    DEFAULT_VELOCITY_TIMEOUT_S,
    PLAN_POINTS_PER_CALL,
    SegmentCheck,
    Vec3,
    _finite3,
    _positive,
    check_speed,
    dedupe_path,
)


class MotionPlanner(_Modes):
    """The set-point generator of the control loop (see the module docstring for behaviour).

    `max_speed_mps` / `max_accel_mps2` bound every set-point trajectory it produces;
    `default_speed_mps` (default: `max_speed_mps`) is used when a move gives no speed.
    `velocity_timeout_s` is the dead-man timeout of velocity input; `check_segment` the
    workspace check of velocity mode (None: velocity input is not bounded by a workspace).
    `junction_deviation_m` bounds how far a path's rounded corner passes from its point;
    `anchors_m` and `max_cable_speed_mps` (both or neither) bound every cable's speed along a
    path; `max_queued_points` bounds the path queue. Starts holding at the origin: call
    `hold(position)` with the measured pose before use. Raises ValueError on non-positive or
    non-finite limits or malformed anchors.
    """

    def __init__(
        self,
        max_speed_mps: float,
        max_accel_mps2: float,
        default_speed_mps: float | None = None,
        *,
        velocity_timeout_s: float = DEFAULT_VELOCITY_TIMEOUT_S,
        check_segment: SegmentCheck | None = None,
        junction_deviation_m: float = DEFAULT_JUNCTION_DEVIATION_M,
        anchors_m: Sequence[Sequence[float]] | None = None,
        max_cable_speed_mps: float | None = None,
        max_queued_points: int = DEFAULT_MAX_QUEUED_POINTS,
    ) -> None:
        self.max_speed_mps = _positive(max_speed_mps, "max_speed_mps")
        self.max_accel_mps2 = _positive(max_accel_mps2, "max_accel_mps2")
        if default_speed_mps is None:
            self.default_speed_mps = self.max_speed_mps
        else:
            self.default_speed_mps = min(
                _positive(default_speed_mps, "default_speed_mps"), self.max_speed_mps
            )
        self.junction_deviation_m = _positive(junction_deviation_m, "junction_deviation_m")
        if (anchors_m is None) != (max_cable_speed_mps is None):
            raise ValueError("anchors_m and max_cable_speed_mps go together (both or neither)")
        self._anchors: tuple[Vec3, ...] = ()
        self.max_cable_speed_mps = math.inf
        if anchors_m is not None and max_cable_speed_mps is not None:
            self._anchors = tuple(_finite3(a, f"anchors_m[{i}]") for i, a in enumerate(anchors_m))
            self.max_cable_speed_mps = _positive(max_cable_speed_mps, "max_cable_speed_mps")
        if int(max_queued_points) != max_queued_points or max_queued_points < 1:
            raise ValueError(
                f"max_queued_points must be an integer >= 1, got {max_queued_points!r}"
            )
        self.max_queued_points = int(max_queued_points)
        self._p: Vec3 = _ZERO
        self._v: Vec3 = _ZERO
        self._mode = _HOLD
        # The path queue: planned pieces (the head, q[0], is being flown) and staged points not
        # yet planned ((points, next index, speed) chunks).
        self._q: deque[_Piece] = deque()
        self._staged: deque[tuple[tuple[Vec3, ...], int, float]] = deque()
        self._open = False  # a path in progress takes appends
        self._stopping = False  # the queue was cut where braking along the path ends
        # a path that arrived while moving: started once the set-point is at rest
        self._next_path: list[tuple[tuple[Vec3, ...], float]] = []
        self._next_points = 0
        self._last: Vec3 = _ZERO  # the last planned point
        self._staged_points = 0
        self._staged_s = 0.0
        self._queued_points = 0  # planned points not yet reached
        self._queued_s = 0.0  # sum of the planned pieces' length / cap
        self._queued_m = 0.0  # sum of the planned pieces' lengths
        # plan ahead twice the braking distance from max speed: further points cannot change
        # the speeds flown now
        self._horizon_m = self.max_speed_mps**2 / self.max_accel_mps2
        # the head's speed profile (from distance _s0 into the piece): accelerate at _acc to _vp,
        # cruise, decelerate at _dec to _v1; phase durations _ta, _tc, _td; _t is the time in it
        self._t_s = 0.0
        self._s0 = 0.0
        self._v0 = 0.0
        self._v1 = 0.0
        self._vp = 0.0
        self._acc = 0.0
        self._dec = 0.0
        self._ta = 0.0
        self._tc = 0.0
        self._td = 0.0
        self._da = 0.0
        self._dur = 0.0
        self._span = 0.0
        # stop state: p(t) = start + unit * (speed*t - a t^2/2), t <= speed/a
        self._stop_start: Vec3 = _ZERO
        self._stop_unit: Vec3 = _ZERO
        self._stop_speed = 0.0
        self._stream_target: Vec3 = _ZERO
        # velocity mode: the commanded velocity and the planner time since its sample
        self.velocity_timeout_s = _positive(velocity_timeout_s, "velocity_timeout_s")
        self._check_segment = check_segment
        self._vel_cmd: Vec3 = _ZERO
        self._vel_age_s = 0.0
        self.deadman_stops = 0
        """Times the dead-man timeout turned a non-zero velocity command into zero."""
        self.boundary_brakes = 0
        """Velocity-mode ticks that braked because the look-ahead left the workspace."""
        self.blends_dropped = 0
        """Corners flown as a stop because the set-point, already committed to braking toward
        the end of the queue when the next point came, could not slow down for the blend."""

    # ----------------------------------------------------------------------------- queries
    @property
    def position_m(self) -> Vec3:
        """The current set-point (m)."""
        return self._p

    @property
    def velocity_mps(self) -> Vec3:
        """The current set-point velocity (m/s)."""
        return self._v

    @property
    def moving(self) -> bool:
        """True unless holding still (a braking stop counts; a stream that sits on its target
        with zero velocity does not)."""
        if self._mode == _STREAM:
            return not (self._p == self._stream_target and self._v == _ZERO)
        if self._mode == _VELOCITY:
            # A non-zero command counts even at rest (pushed against a boundary): the state
            # stays MOVING instead of flickering with the look-ahead.
            return self._v != _ZERO or self._vel_cmd != _ZERO
        return self._mode != _HOLD

    @property
    def mode(self) -> str:
        """'hold', 'move', 'stop', 'stream' or 'velocity' (for status output)."""
        if self._stopping and self._mode == _MOVE:
            return "stop"
        return _MODE_NAMES[self._mode]

    @property
    def velocity_command_mps(self) -> Vec3:
        """The velocity input in force (zero outside velocity mode or after the dead-man)."""
        return self._vel_cmd if self._mode == _VELOCITY else _ZERO

    @property
    def queued_points(self) -> int:
        """Path points queued and not yet reached (planned and staged)."""
        if not self._open:
            return 0
        return self._queued_points + self._staged_points + self._next_points

    @property
    def queued_s(self) -> float:
        """Seconds of motion queued, at each piece's speed limit (a lower bound: the time
        spent changing speed is not counted)."""
        if not self._open:
            return 0.0
        return max(0.0, self._queued_s) + self._staged_s

    @property
    def queue_full(self) -> bool:
        """True when the path queue holds `max_queued_points` points (appends are refused)."""
        return self.queued_points >= self.max_queued_points

    @property
    def appendable(self) -> bool:
        """True while a path is in progress (or ran dry at its last point) and takes appends."""
        return self._open

    @property
    def target_m(self) -> Vec3:
        """Where the set-point is heading: last queued path point, stream target or stop point
        (in velocity mode: where it would come to rest, `rest_point_m`)."""
        if self._mode == _HOLD:
            return self._p
        if self._mode == _VELOCITY:
            return self.rest_point_m
        if self._mode == _STREAM:
            return self._stream_target
        if self._next_path:
            return self._next_path[-1][0][-1]
        if self._staged:
            return self._staged[-1][0][-1]
        if self._mode == _MOVE:
            return self._last
        if self._mode == _STOP:
            return self._stop_point()
        return self._p

    @property
    def rest_point_m(self) -> Vec3:
        """Where the set-point would come to rest if `stop()` were called now (the start of
        the first leg of a move or path that arrives now): on a path, where braking along it
        ends; otherwise position + v^2/(2 a) along v."""
        if self._mode == _STOP:
            return self._stop_point()
        s = self._speed()
        if s == 0.0:
            return self._p
        if self._mode == _MOVE and self._q:
            i, dist = self._path_brake()
            piece = self._q[i]
            return _point_at(piece, dist) if dist < piece.length else piece.end
        k = s / (2.0 * self.max_accel_mps2)  # distance / speed
        v = self._v
        p = self._p
        return (p[0] + v[0] * k, p[1] + v[1] * k, p[2] + v[2] * k)

    @property
    def brake_time_s(self) -> float:
        """Seconds a `stop()` now takes to come to rest (on a path along it, each piece at its
        own acceleration limit: longer than speed / max accel through a corner arc; else
        speed / max accel). 0 when still. Raises nothing."""
        a = self.max_accel_mps2
        if self._mode == _STOP:
            return max(0.0, self._stop_speed / a - self._t_s)
        if self._mode != _MOVE or not self._q:
            return self._speed() / a
        s, v = self._head_state()
        t = 0.0
        for k, piece in enumerate(self._q):
            rem = max(0.0, piece.length - (s if k == 0 else 0.0))
            v2 = v * v - 2.0 * piece.acc * rem
            if v2 <= 0.0:
                return t + v / piece.acc
            w = math.sqrt(v2)
            t += (v - w) / piece.acc
            v = w
        return t

    # ----------------------------------------------------------------------------- commands
    def hold(self, position_m: Sequence[float]) -> None:
        """Hold still at `position_m` at once (velocity zero; forgets any move or stream).

        Use it to seed the planner with the measured pose (arming, homing, after a fault).
        Raises ValueError on a non-finite position.
        """
        self._p = _finite3(position_m, "position_m")
        self._v = _ZERO
        self._mode = _HOLD
        self._vel_cmd = _ZERO
        self._clear_path()

    def move_to(self, target_m: Sequence[float], speed_mps: float | None = None) -> None:
        """Straight-line move to `target_m`, from rest to rest (brakes to a stop first if
        moving). `speed_mps` None = the default speed; above max speed it is clamped. Raises
        ValueError on a non-finite target or a speed that `check_speed` refuses.
        """
        self.follow_path([target_m], speed_mps)

    def follow_path(
        self, points_m: Iterable[Sequence[float]], speed_mps: float | None = None
    ) -> None:
        """Fly through `points_m` in order, corners rounded (module docstring), to rest at the
        last point; replaces any path in progress.

        If the set-point is moving, it first brakes to a stop along its current direction and the
        path starts from the stop point. Raises ValueError on an empty path, a non-finite
        point, a speed that `check_speed` refuses or more than `max_queued_points` points (the
        planner is unchanged then). Checks and copies the points (O(n)); `follow_points` takes
        points already checked.
        """
        pts = dedupe_path(points_m)
        self.follow_points(pts, self._speed_arg(speed_mps))

    def follow_points(self, points_m: tuple[Vec3, ...], speed_mps: float) -> None:
        """`follow_path` for points from `dedupe_path` and a speed `check_speed` accepts.

        Plans at most `PLAN_POINTS_PER_CALL` points now (the rest as the set-point advances).
        `speed_mps` above max speed is clamped. Raises ValueError on an empty path, a speed
        that `check_speed` refuses or more than `max_queued_points` points.
        """
        if not points_m:
            raise ValueError("points_m must contain at least one point")
        speed = self._speed_arg(speed_mps)
        if len(points_m) > self.max_queued_points:
            raise QueueError(
                f"{len(points_m)} points: the path queue holds at most "
                f"{self.max_queued_points} points (send the rest as appends)"
            )
        if self._speed() > 0.0:
            # brake first (along the path on a path), then start from where it comes to rest
            if self._mode == _MOVE:
                self._stop_on_path()
            else:
                self._begin_stop()
            self._next_path = [(points_m, speed)]
            self._next_points = len(points_m)
            self._open = True
            return
        self._next_path = []
        self._next_points = 0
        self._start_path([(points_m, speed)])

    def append_points(
        self, points_m: Iterable[Sequence[float]], speed_mps: float | None = None
    ) -> None:
        """Add `points_m` to the end of the path in progress (flown on through the current
        last point, which becomes a rounded corner if the set-point is not yet braking for it).

        A path that ran dry (at rest at its last point) continues. Raises QueueError when no
        path is in progress (none sent, or stopped, replaced or held since) or the queue would
        hold more than `max_queued_points` points, and ValueError on a non-finite point or a
        speed that `check_speed` refuses (the planner is unchanged then). O(n) checks and
        copies; `append_prepared` takes points from `dedupe_path`.
        """
        pts = dedupe_path(points_m)
        self.append_prepared(pts, self._speed_arg(speed_mps))

    def append_prepared(self, points_m: tuple[Vec3, ...], speed_mps: float) -> None:
        """`append_points` for points from `dedupe_path` and a speed `check_speed` accepts.

        Plans at most `PLAN_POINTS_PER_CALL` points now (the rest as the set-point advances).
        Raises QueueError or ValueError as `append_points` does.
        """
        if not points_m:
            raise ValueError("points_m must contain at least one point")
        speed = self._speed_arg(speed_mps)
        if not self._open:
            raise QueueError("no path in progress to append to (send a path first)")
        total = self.queued_points + len(points_m)
        if total > self.max_queued_points:
            raise QueueError(
                f"{QUEUE_FULL}: {self.queued_points} + {len(points_m)} points would exceed "
                f"{self.max_queued_points}"
            )
        if self._next_path:  # a path waiting for the stop before it to end
            self._next_path.append((points_m, speed))
            self._next_points += len(points_m)
            return
        self._stage(points_m, speed)
        if self._mode == _HOLD:  # ran dry at the last point: continue from rest
            self._mode = _MOVE
        self._plan(PLAN_POINTS_PER_CALL)
        self._after_plan()

    def plan(self, max_points: int = PLAN_POINTS_PER_CALL) -> int:
        """Plan up to `max_points` staged points now, whatever the look-ahead horizon (for the
        benchmark, or to plan ahead outside the tick). Returns how many were planned. Raises
        nothing."""
        if self._mode != _MOVE:
            return 0
        n = self._plan(max_points, force=True)
        self._after_plan()
        return n

    def _speed_arg(self, speed_mps: float | None) -> float:
        if speed_mps is None:
            return self.default_speed_mps
        reason = check_speed(speed_mps)
        if reason is not None:
            raise ValueError(f"speed_mps: {reason}")
        return min(float(speed_mps), self.max_speed_mps)

    def stop(self) -> None:
        """Brake at max accel to a hold (on a path: along the path, at any queue depth; else
        along the current direction); forget the path queue (appends are refused until a new
        path)."""
        self._staged.clear()
        self._staged_points = 0
        self._staged_s = 0.0
        self._next_path = []
        self._next_points = 0
        self._open = False
        if self._mode == _STOP:
            return
        if self._speed() > 0.0:
            if self._mode == _MOVE:
                self._stop_on_path()
            else:
                self._begin_stop()
        else:
            self._clear_path()
            self._mode = _HOLD

    def advance(self, dt_s: float) -> Vec3:
        """Advance the set-point by `dt_s` seconds and return it (m).

        `dt_s` <= 0 or non-finite leaves everything unchanged (never produces NaN). On a path
        it plans at most `PLAN_POINTS_PER_CALL` staged points first, and only while the
        planned distance is short of the look-ahead horizon: the cost does not depend on how
        much is queued.
        """
        if not (dt_s > 0.0 and math.isfinite(dt_s)):
            return self._p
        mode = self._mode
        if mode == _MOVE:
            if self._staged:
                self._plan(PLAN_POINTS_PER_CALL)
            self._advance_move(dt_s)
        elif mode == _STOP:
            self._advance_stop(dt_s)
        elif mode == _STREAM:
            self._advance_stream(dt_s)
        elif mode == _VELOCITY:
            self._advance_velocity(dt_s)
        return self._p
