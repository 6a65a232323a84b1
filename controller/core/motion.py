"""Motion: trapezoidal straight-line moves, multi-point paths, stop-to-hold, streamed set-points,
velocity input.

Everything here is deterministic and clock-free: the control loop calls
`MotionPlanner.advance(dt_s)` once per tick with the tick's time step and gets the new position
set-point. The per-tick path uses plain Python floats and 3-tuples (no numpy, no allocation
beyond a few tuples), so it costs a few microseconds, whatever the length of the path.

Behaviour:

* `TrapezoidMove`: rest-to-rest straight line, accelerate at `max_accel_mps2`, cruise at
  `max_speed_mps`, decelerate; a triangular profile when the distance is too short to reach the
  cruise speed. Its duration is the minimum possible under both limits.
* `MotionPlanner.move_to` / `follow_path`: each leg is one `TrapezoidMove`; the effector stops at
  every path point (no blending). A new move or path that arrives while the effector is moving
  first brakes to a stop along the current direction at `max_accel_mps2`, then starts its legs
  from the stop point, so velocity never jumps and the acceleration limit always holds.
  Zero-length legs are dropped.
* Legs are built one at a time, when the set-point reaches them, so starting a path costs the
  same for 1 or 100,000 points. One `advance` crosses at most `MAX_LEGS_PER_ADVANCE` legs: a
  path of legs so short that more of them fit in one tick runs slower than planned (every leg
  ends at rest, so dropping the rest of the tick at a leg's end keeps every limit).
* `MotionPlanner.stop`: brake along the current velocity direction at `max_accel_mps2` to a hold;
  the stop point is `position + v^2/(2 a)` along that direction. In a trapezoidal leg the
  remaining distance is always at least that braking distance, so a stop never leaves the leg.
* `MotionPlanner.stream`: the set-point chases the latest target with speed <= max speed and
  |change of velocity| <= max accel * dt per tick (a vector bang-bang limiter along the error
  direction with a discrete-time braking curve, so it lands on a fixed target without
  overshoot and holds there exactly).
* `MotionPlanner.command_velocity`: velocity input (a joystick, an RC stick). The commanded
  velocity's norm is clamped to `max_speed_mps`; every tick the set-point velocity moves toward
  it by at most `max_accel_mps2 * dt` (semi-implicit: the position advances by the new velocity),
  so speed and acceleration stay within the limits whatever the input. Dead-man: once a sample
  is older than `velocity_timeout_s` of planner time, the command becomes zero. A zero command
  (or one slower than `MIN_SPEED_MPS`) brakes at `max_accel_mps2` along the current velocity to
  a hold, and the planner then leaves velocity mode. A zero sample outside velocity mode is
  ignored (`command_velocity` returns False): a centred stick that keeps streaming zeros never
  stops a move; a non-zero sample takes over from any mode (hold, move, path, stop, stream) with
  the current velocity kept, like `stream`. A move, path, stream or stop replaces velocity mode.
* Workspace in velocity mode (`check_segment`, the workspace's straight-segment check): before
  a tick's new set-point is taken, the planner looks ahead by the braking distance |v|^2/(2 a)
  along the new velocity; if the segment from the new set-point to that rest point leaves the
  workspace, it brakes along the current velocity instead. Braking stays on the segment checked
  on the previous tick (its discrete rest point is never beyond the continuous one), so by
  induction every set-point, and every braking path, stays inside: pushing into a boundary
  stops just short of it. The induction needs the hand-over state's braking path inside, which
  a move or path guarantees (its legs are checked); a stream does not, and the control loop's
  own check of every set-point stays the last guard.
* Speeds: `check_speed` is the rule for a commanded speed (finite and at least `MIN_SPEED_MPS`;
  the command boundary and the control loop refuse others with its reason). Speeds above
  `max_speed_mps` given to `move_to`/`follow_path` are clamped to it; the control loop says so in
  its reply.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence

Vec3 = tuple[float, float, float]

_ZERO: Vec3 = (0.0, 0.0, 0.0)

MIN_SPEED_MPS = 1e-3
"""The slowest commanded move or path speed (1 mm/s): slower ones are refused, because a move
at a vanishing speed would keep the robot MOVING for hours (or, at 5e-324 m/s, forever)."""

DEFAULT_VELOCITY_TIMEOUT_S = 0.25
"""The dead-man timeout of velocity input when none is configured (`[limits]
velocity_timeout_s`): a velocity sample older than this is treated as zero."""

MAX_LEGS_PER_ADVANCE = 16
"""Path legs one `MotionPlanner.advance` may cross (bounds the per-tick cost; module docstring)."""


def check_speed(speed_mps: float) -> str | None:
    """None if `speed_mps` is a usable commanded speed, else the reason (finite and at least
    MIN_SPEED_MPS; the upper bound is the robot's max speed, applied by clamping). Raises nothing.
    """
    v = float(speed_mps)
    if not math.isfinite(v):
        return f"must be a finite number, got {speed_mps!r}"
    if not v > 0.0:
        return f"must be > 0, got {v:g}"
    if not v >= MIN_SPEED_MPS:
        return f"must be at least {MIN_SPEED_MPS:g} m/s (the minimum speed), got {v:g} m/s"
    return None


def clamp_velocity(velocity_mps: Sequence[float], max_speed_mps: float) -> Vec3:
    """`velocity_mps` as a 3-tuple whose norm is at most `max_speed_mps` (same direction).

    Exact for any finite input, however large (the norm is taken after scaling by the largest
    component, so it cannot overflow). A speed below `MIN_SPEED_MPS` is returned as zero (a
    stick's noise about its centre is no command). Raises ValueError for a non-finite or
    malformed vector.
    """
    x, y, z = _finite3(velocity_mps, "velocity_mps")
    m = max(abs(x), abs(y), abs(z))
    if m == 0.0:
        return _ZERO
    ux, uy, uz = x / m, y / m, z / m
    speed = math.hypot(ux, uy, uz) * m  # may round to inf: then it is above the maximum
    if speed < MIN_SPEED_MPS:
        return _ZERO
    if speed <= max_speed_mps:
        return (x, y, z)
    k = max_speed_mps / math.hypot(ux, uy, uz)
    return (ux * k, uy * k, uz * k)


def dedupe_path(points_m: Iterable[Sequence[float]]) -> tuple[Vec3, ...]:
    """The path's points as finite 3-tuples, consecutive repeats dropped (zero-length legs).

    Raises ValueError on an empty path or a non-finite or malformed point (naming its index).
    """
    out: list[Vec3] = []
    prev: Vec3 | None = None
    for i, p in enumerate(points_m):
        q = _finite3(p, f"points_m[{i}]")
        if q != prev:
            out.append(q)
            prev = q
    if not out:
        raise ValueError("points_m must contain at least one point")
    return tuple(out)


def _finite3(p: Sequence[float], what: str) -> Vec3:
    if len(p) != 3:
        raise ValueError(f"{what} must have 3 components, got {len(p)}")
    x, y, z = float(p[0]), float(p[1]), float(p[2])
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise ValueError(f"{what} must be finite, got {(x, y, z)!r}")
    return (x, y, z)


def _positive(value: float, what: str) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f"{what} must be finite and > 0, got {value!r}")
    return v


class TrapezoidMove:
    """A rest-to-rest straight move from `start_m` to `end_m` with a trapezoidal speed profile.

    `duration_s` is the minimum time under `max_speed_mps` and `max_accel_mps2` (triangular
    profile when the distance is shorter than the distance needed to reach full speed and brake).
    Raises ValueError on non-finite points or non-positive/non-finite limits.
    """

    __slots__ = (
        "_accel_s",
        "_cruise_s",
        "_peak_mps",
        "_unit",
        "accel_mps2",
        "distance_m",
        "duration_s",
        "end_m",
        "start_m",
    )

    def __init__(
        self,
        start_m: Sequence[float],
        end_m: Sequence[float],
        max_speed_mps: float,
        max_accel_mps2: float,
    ) -> None:
        self.start_m: Vec3 = _finite3(start_m, "start_m")
        self.end_m: Vec3 = _finite3(end_m, "end_m")
        vmax = _positive(max_speed_mps, "max_speed_mps")
        amax = _positive(max_accel_mps2, "max_accel_mps2")
        self.accel_mps2 = amax
        dx = self.end_m[0] - self.start_m[0]
        dy = self.end_m[1] - self.start_m[1]
        dz = self.end_m[2] - self.start_m[2]
        d = math.hypot(dx, dy, dz)  # no underflow for tiny distances
        self.distance_m = d
        if d == 0.0:
            self._unit: Vec3 = _ZERO
            self._peak_mps = 0.0
            self._accel_s = 0.0
            self._cruise_s = 0.0
        else:
            self._unit = (dx / d, dy / d, dz / d)
            if vmax * vmax >= d * amax:  # cannot reach vmax and brake in time: triangle
                peak = math.sqrt(d * amax)
                self._peak_mps = peak
                self._accel_s = peak / amax
                self._cruise_s = 0.0
            else:
                self._peak_mps = vmax
                self._accel_s = vmax / amax
                self._cruise_s = (d - vmax * vmax / amax) / vmax
        self.duration_s: float = 2.0 * self._accel_s + self._cruise_s

    @property
    def peak_speed_mps(self) -> float:
        """The highest speed reached (the cruise speed, or the triangle's apex)."""
        return self._peak_mps

    def distance_at(self, t_s: float) -> tuple[float, float]:
        """Distance travelled (m) and speed (m/s) at time `t_s` (clamped to [0, duration_s])."""
        ta = self._accel_s
        a = self.accel_mps2
        if t_s <= 0.0 or self.distance_m == 0.0:
            return 0.0, 0.0
        if t_s >= self.duration_s:
            return self.distance_m, 0.0
        if t_s < ta:
            return 0.5 * a * t_s * t_s, a * t_s
        t2 = t_s - ta
        peak = self._peak_mps
        d_acc = 0.5 * peak * ta
        if t2 < self._cruise_s:
            return d_acc + peak * t2, peak
        t3 = self.duration_s - t_s  # time left: mirror of the acceleration phase
        return self.distance_m - 0.5 * a * t3 * t3, a * t3

    def sample(self, t_s: float) -> tuple[Vec3, Vec3]:
        """Position (m) and velocity (m/s) at time `t_s`; exactly `end_m` and zero at the end."""
        if t_s >= self.duration_s:
            return self.end_m, _ZERO
        s, v = self.distance_at(t_s)
        u = self._unit
        p0 = self.start_m
        return (
            (p0[0] + u[0] * s, p0[1] + u[1] * s, p0[2] + u[2] * s),
            (u[0] * v, u[1] * v, u[2] * v),
        )


_HOLD = 0
_MOVE = 1
_STOP = 2
_STREAM = 3
_VELOCITY = 4
_MODE_NAMES = {
    _HOLD: "hold",
    _MOVE: "move",
    _STOP: "stop",
    _STREAM: "stream",
    _VELOCITY: "velocity",
}

SegmentCheck = Callable[[Vec3, Vec3], str | None]
"""`check(a, b)`: None if the straight segment a->b is inside the workspace, else why not."""


class MotionPlanner:
    """The set-point generator of the control loop (see the module docstring for behaviour).

    `max_speed_mps` / `max_accel_mps2` bound every set-point trajectory it produces;
    `default_speed_mps` (default: `max_speed_mps`) is used when a move gives no speed.
    `velocity_timeout_s` is the dead-man timeout of velocity input; `check_segment` the
    workspace check of velocity mode (None: velocity input is not bounded by a workspace).
    Starts holding at the origin: call `hold(position)` with the measured pose before use.
    Raises ValueError on non-positive or non-finite limits.
    """

    def __init__(
        self,
        max_speed_mps: float,
        max_accel_mps2: float,
        default_speed_mps: float | None = None,
        *,
        velocity_timeout_s: float = DEFAULT_VELOCITY_TIMEOUT_S,
        check_segment: SegmentCheck | None = None,
    ) -> None:
        self.max_speed_mps = _positive(max_speed_mps, "max_speed_mps")
        self.max_accel_mps2 = _positive(max_accel_mps2, "max_accel_mps2")
        if default_speed_mps is None:
            self.default_speed_mps = self.max_speed_mps
        else:
            self.default_speed_mps = min(
                _positive(default_speed_mps, "default_speed_mps"), self.max_speed_mps
            )
        self._p: Vec3 = _ZERO
        self._v: Vec3 = _ZERO
        self._mode = _HOLD
        # A path in progress: `_leg` runs to `_path[_next - 1]`; `_path[_next:]` are still to go.
        self._leg: TrapezoidMove | None = None
        self._path: tuple[Vec3, ...] = ()
        self._next = 0
        self._path_speed = self.default_speed_mps
        self._pending: tuple[Vec3, ...] = ()  # a path to start once the current stop ends
        self._pending_speed = self.default_speed_mps
        self._t_s = 0.0
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
        return _MODE_NAMES[self._mode]

    @property
    def velocity_command_mps(self) -> Vec3:
        """The velocity input in force (zero outside velocity mode or after the dead-man)."""
        return self._vel_cmd if self._mode == _VELOCITY else _ZERO

    @property
    def target_m(self) -> Vec3:
        """Where the set-point is heading: last path point, stream target or stop point (in
        velocity mode: where it would come to rest, `rest_point_m`)."""
        if self._mode == _HOLD:
            return self._p
        if self._mode == _VELOCITY:
            return self.rest_point_m
        if self._mode == _STREAM:
            return self._stream_target
        if self._pending:
            return self._pending[-1]
        if self._mode == _MOVE and self._path:
            return self._path[-1]
        if self._mode == _STOP:
            return self._stop_point()
        return self._p

    @property
    def rest_point_m(self) -> Vec3:
        """Where the set-point would come to rest if `stop()` were called now (the start of
        the first leg of a move or path that arrives now): position + v^2/(2 a) along v."""
        if self._mode == _STOP:
            return self._stop_point()
        s = self._speed()
        if s == 0.0:
            return self._p
        k = s / (2.0 * self.max_accel_mps2)  # distance / speed
        v = self._v
        p = self._p
        return (p[0] + v[0] * k, p[1] + v[1] * k, p[2] + v[2] * k)

    def _speed(self) -> float:
        v = self._v
        return math.hypot(v[0], v[1], v[2])

    def _stop_point(self) -> Vec3:
        s = self._stop_speed
        d = s * s / (2.0 * self.max_accel_mps2)
        u = self._stop_unit
        p = self._stop_start
        return (p[0] + u[0] * d, p[1] + u[1] * d, p[2] + u[2] * d)

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
        self._pending = ()

    def move_to(self, target_m: Sequence[float], speed_mps: float | None = None) -> None:
        """Straight-line trapezoidal move to `target_m` (brakes to a stop first if moving).

        `speed_mps` None = the default speed; above max speed it is clamped. Raises ValueError
        on a non-finite target or a speed that `check_speed` refuses.
        """
        self.follow_path([target_m], speed_mps)

    def follow_path(
        self, points_m: Iterable[Sequence[float]], speed_mps: float | None = None
    ) -> None:
        """Visit `points_m` in order, one trapezoidal leg each, stopping at every point.

        If the set-point is moving, it first brakes to a stop along its current direction and the
        first leg starts from the stop point. Raises ValueError on an empty path, a non-finite
        point or a speed that `check_speed` refuses (the planner is unchanged then). Checks and
        copies the points (O(n)); `follow_points` takes points already checked in O(1).
        """
        pts = dedupe_path(points_m)
        self.follow_points(pts, self._speed_arg(speed_mps))

    def follow_points(self, points_m: tuple[Vec3, ...], speed_mps: float) -> None:
        """`follow_path` for points from `dedupe_path` and a speed `check_speed` accepts: O(1),
        whatever the number of points (the control loop prepares both outside its tick).

        `speed_mps` above max speed is clamped. Raises ValueError on an empty path or a speed
        that `check_speed` refuses.
        """
        if not points_m:
            raise ValueError("points_m must contain at least one point")
        speed = self._speed_arg(speed_mps)
        if self._speed() > 0.0:
            self._begin_stop()
            self._pending = points_m
            self._pending_speed = speed
        else:
            self._pending = ()
            self._start_path(points_m, speed)

    def _speed_arg(self, speed_mps: float | None) -> float:
        if speed_mps is None:
            return self.default_speed_mps
        reason = check_speed(speed_mps)
        if reason is not None:
            raise ValueError(f"speed_mps: {reason}")
        return min(float(speed_mps), self.max_speed_mps)

    def stop(self) -> None:
        """Brake along the current direction at max accel to a hold; forget queued moves."""
        self._pending = ()
        if self._mode == _STOP:
            return
        if self._speed() > 0.0:
            self._begin_stop()
        else:
            self._clear_path()
            self._mode = _HOLD

    def stream(self, target_m: Sequence[float]) -> None:
        """Chase `target_m` (latest wins) under the speed and acceleration limits.

        Replaces any move, path or stop in progress; the current velocity is kept, so the
        hand-over is smooth. Raises ValueError on a non-finite target.
        """
        self._stream_target = _finite3(target_m, "target_m")
        self._clear_path()
        self._pending = ()
        self._mode = _STREAM

    def command_velocity(self, velocity_mps: Sequence[float]) -> bool:
        """Fly at `velocity_mps` (one velocity-input sample; see the module docstring).

        The norm is clamped to max speed (`clamp_velocity`; below `MIN_SPEED_MPS` it is zero)
        and the dead-man timer restarts. A non-zero sample enters velocity mode from any mode,
        keeping the current velocity; a zero sample brakes to a hold in velocity mode and is
        ignored in any other. Returns True if the sample was taken, False if ignored.
        Raises ValueError for a non-finite or malformed vector (the planner is unchanged).
        """
        v = clamp_velocity(velocity_mps, self.max_speed_mps)
        if self._mode != _VELOCITY:
            if v == _ZERO:
                return False
            self._clear_path()
            self._pending = ()
            self._mode = _VELOCITY
        self._vel_cmd = v
        self._vel_age_s = 0.0
        if v == _ZERO and self._v == _ZERO:
            self._mode = _HOLD  # at rest already: nothing to brake
        return True

    # ----------------------------------------------------------------------------- internals
    def _clear_path(self) -> None:
        self._leg = None
        self._path = ()
        self._next = 0

    def _start_path(self, pts: tuple[Vec3, ...], speed: float) -> None:
        """Start the legs through `pts` from the current (resting) set-point."""
        self._path = pts
        self._next = 0
        self._path_speed = speed
        self._t_s = 0.0
        self._v = _ZERO
        if self._next_leg():
            self._mode = _MOVE
        else:
            self._clear_path()
            self._mode = _HOLD

    def _next_leg(self) -> bool:
        """Build the leg from the set-point to the next path point; False at the path's end.

        A zero-length leg is dropped (only the first point can repeat the set-point: the path's
        consecutive repeats were removed by `dedupe_path`).
        """
        path = self._path
        i = self._next
        if i < len(path) and path[i] == self._p:
            i += 1
        if i >= len(path):
            self._leg = None
            self._next = i
            return False
        self._leg = TrapezoidMove(self._p, path[i], self._path_speed, self.max_accel_mps2)
        self._next = i + 1
        return True

    def _begin_stop(self) -> None:
        s = self._speed()
        v = self._v
        self._clear_path()
        self._stop_start = self._p
        self._stop_unit = (v[0] / s, v[1] / s, v[2] / s)
        self._stop_speed = s
        self._t_s = 0.0
        self._mode = _STOP

    def advance(self, dt_s: float) -> Vec3:
        """Advance the set-point by `dt_s` seconds and return it (m).

        `dt_s` <= 0 or non-finite leaves everything unchanged (never produces NaN).
        """
        if not (dt_s > 0.0 and math.isfinite(dt_s)):
            return self._p
        mode = self._mode
        if mode == _MOVE:
            self._advance_move(dt_s)
        elif mode == _STOP:
            self._advance_stop(dt_s)
        elif mode == _STREAM:
            self._advance_stream(dt_s)
        elif mode == _VELOCITY:
            self._advance_velocity(dt_s)
        return self._p

    def _advance_move(self, dt_s: float) -> None:
        t = self._t_s + dt_s
        leg = self._leg
        assert leg is not None
        crossed = 0
        while t >= leg.duration_s:
            t -= leg.duration_s
            self._p = leg.end_m
            crossed += 1
            if not self._next_leg():
                self._v = _ZERO
                self._mode = _HOLD
                self._t_s = 0.0
                self._clear_path()
                return
            leg = self._leg
            assert leg is not None
            if crossed >= MAX_LEGS_PER_ADVANCE:
                t = 0.0  # at rest at a path point: the rest of this step is dropped
                break
        self._t_s = t
        self._p, self._v = leg.sample(t)

    def _advance_stop(self, dt_s: float) -> None:
        a = self.max_accel_mps2
        t = self._t_s + dt_s
        s0 = self._stop_speed
        t_end = s0 / a
        if t >= t_end:
            self._p = self._stop_point()
            self._v = _ZERO
            self._t_s = 0.0
            if self._pending:
                pts = self._pending
                self._pending = ()
                self._start_path(pts, self._pending_speed)
                leftover = t - t_end
                if self._mode == _MOVE and leftover > 0.0:
                    self._advance_move(leftover)
            else:
                self._mode = _HOLD
            return
        self._t_s = t
        d = s0 * t - 0.5 * a * t * t
        s = s0 - a * t
        u = self._stop_unit
        p = self._stop_start
        self._p = (p[0] + u[0] * d, p[1] + u[1] * d, p[2] + u[2] * d)
        self._v = (u[0] * s, u[1] * s, u[2] * s)

    def _advance_stream(self, dt_s: float) -> None:
        a = self.max_accel_mps2
        p = self._p
        v = self._v
        g = self._stream_target
        ex = g[0] - p[0]
        ey = g[1] - p[1]
        ez = g[2] - p[2]
        d = math.hypot(ex, ey, ez)
        # Desired velocity: toward the target at the fastest speed from which the discrete
        # braking sequence (speeds k*a*dt, k = n..1, semi-implicit Euler) still stops on it, and
        # never more than d/dt (land exactly) or max speed.
        if d > 0.0:
            x2 = 2.0 * d / (a * dt_s * dt_s)
            n = x2 / (math.sqrt(0.25 + x2) + 0.5)  # = sqrt(1/4 + x2) - 1/2 without cancellation
            want = min(self.max_speed_mps, n * a * dt_s, d / dt_s)
            k = want / d
            wx, wy, wz = ex * k, ey * k, ez * k
        else:
            wx = wy = wz = 0.0
        # Move the velocity toward the desired one by at most a*dt (keeps |v| <= max speed
        # because the new velocity lies on the segment between two vectors within the ball).
        cx, cy, cz = wx - v[0], wy - v[1], wz - v[2]
        c = math.hypot(cx, cy, cz)
        dv_max = a * dt_s
        clipped = c > dv_max
        if clipped:
            k = dv_max / c
            cx, cy, cz = cx * k, cy * k, cz * k
        nv = (v[0] + cx, v[1] + cy, v[2] + cz)
        if d > 0.0 and not clipped and want == d / dt_s:
            self._p = g  # lands exactly this tick (removes rounding residue)
        else:
            self._p = (p[0] + nv[0] * dt_s, p[1] + nv[1] * dt_s, p[2] + nv[2] * dt_s)
        self._v = nv

    def _advance_velocity(self, dt_s: float) -> None:
        a = self.max_accel_mps2
        age = self._vel_age_s + dt_s
        self._vel_age_s = age
        w = self._vel_cmd
        if age > self.velocity_timeout_s and w != _ZERO:
            w = self._vel_cmd = _ZERO  # dead-man: no fresh sample, brake to a hold
            self.deadman_stops += 1
        p = self._p
        v = self._v
        dv_max = a * dt_s
        # The velocity moves toward the command by at most a*dt (stays within the ball of
        # radius max speed: both ends of the segment are in it).
        cx, cy, cz = w[0] - v[0], w[1] - v[1], w[2] - v[2]
        c = math.hypot(cx, cy, cz)
        if c > dv_max:
            k = dv_max / c
            cx, cy, cz = cx * k, cy * k, cz * k
        nv: Vec3 = (v[0] + cx, v[1] + cy, v[2] + cz)
        check = self._check_segment
        if check is not None and nv != _ZERO:
            s = math.hypot(nv[0], nv[1], nv[2])
            np_ = (p[0] + nv[0] * dt_s, p[1] + nv[1] * dt_s, p[2] + nv[2] * dt_s)
            k = s / (2.0 * a)  # braking distance / speed
            rest = (np_[0] + nv[0] * k, np_[1] + nv[1] * k, np_[2] + nv[2] * k)
            if check(np_, rest) is not None:
                # Brake along the current velocity: stays on the segment checked last tick.
                self.boundary_brakes += 1
                s0 = math.hypot(v[0], v[1], v[2])
                if s0 <= dv_max:
                    nv = _ZERO
                else:
                    f = 1.0 - dv_max / s0
                    nv = (v[0] * f, v[1] * f, v[2] * f)
        if nv == _ZERO:
            self._v = _ZERO
            if w == _ZERO:
                self._mode = _HOLD  # at rest with nothing commanded: velocity mode ends
            return
        self._p = (p[0] + nv[0] * dt_s, p[1] + nv[1] * dt_s, p[2] + nv[2] * dt_s)
        self._v = nv


def circle_path(
    radius_m: float = 20.0,
    centre_m: Sequence[float] = (0.0, 0.0),
    z_m: float = 2.0,
    steps: int = 72,
) -> list[Vec3]:
    """The paper's example (c): a horizontal circle as `steps` straight legs.

    Returns `steps + 1` points at angles 0, 360/steps, ... 360 degrees, counter-clockwise from
    +x; the last point repeats the first exactly, so following the path closes the circle
    (72 legs of 5 degrees each for the defaults, radius 20 m about (0, 0) at z = 2 m).
    Raises ValueError on a non-positive/non-finite radius, non-finite centre or z, or steps < 3.
    """
    r = _positive(radius_m, "radius_m")
    if len(centre_m) != 2:
        raise ValueError(f"centre_m must have 2 components, got {len(centre_m)}")
    cx, cy = float(centre_m[0]), float(centre_m[1])
    z = float(z_m)
    if not (math.isfinite(cx) and math.isfinite(cy) and math.isfinite(z)):
        raise ValueError("centre_m and z_m must be finite")
    if int(steps) != steps or steps < 3:
        raise ValueError(f"steps must be an integer >= 3, got {steps!r}")
    pts: list[Vec3] = []
    for i in range(int(steps)):
        ang = 2.0 * math.pi * i / steps
        pts.append((cx + r * math.cos(ang), cy + r * math.sin(ang), z))
    pts.append(pts[0])
    return pts
