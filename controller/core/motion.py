"""Motion: trapezoidal straight-line moves, paths flown through their points with rounded
corners and look-ahead, a queue for jobs of any length, stop-to-hold, streamed set-points,
velocity input.

Everything here is deterministic and clock-free: the control loop calls
`MotionPlanner.advance(dt_s)` once per tick with the tick's time step and gets the new position
set-point. The per-tick path uses plain Python floats and 3-tuples (no numpy, no allocation
beyond a few tuples), so it costs a few microseconds, whatever the length of the path.

Behaviour:

* `TrapezoidMove`: rest-to-rest straight line, accelerate at `max_accel_mps2`, cruise at
  `max_speed_mps`, decelerate; a triangular profile when the distance is too short to reach the
  cruise speed. Its duration is the minimum possible under both limits.
* Paths (`MotionPlanner.follow_path`, `append_points`; `move_to` is a one-point path) are flown
  through their points, not stopped at each (how paths are flown, for users: docs/motion.md):

  - Corners are rounded. Printer firmware (Grbl, Marlin, Klipper) limits a corner's speed by
    "junction deviation" (Sonny Jeon's method in Grbl's planner: the speed at which a circle
    tangent to both segments, passing `delta` from the corner, has centripetal acceleration
    `a`) and then turns the velocity instantly, a jump that makes a hanging effector swing.
    cablebot flies that circle: each corner is an arc of radius
    R = delta * sin(theta/2) / (1 - sin(theta/2)), tangent to both segments, with theta the
    angle between the segments as Grbl defines it (180 degrees = straight on), and delta =
    `junction_deviation_m` (default `DEFAULT_JUNCTION_DEVIATION_M`). On it the speed is at most
    v = sqrt(a * R) * sqrt(CORNER_ACCEL_FRACTION): Grbl's junction speed
    v = sqrt(a * delta * sin(theta/2) / (1 - sin(theta/2))) scaled by sqrt(0.95) = 0.975, so a
    printer user's settings carry over; the 5 % of centripetal acceleration held back leaves 31 %
    of `max_accel_mps2` to change speed along the arc (|a| = hypot(v^2 / R, tangential) stays
    within `max_accel_mps2`), so a path made only of arcs (a finely sampled circle) can still
    speed up and slow down. `junction_speed_mps` is the formula.
  - The arc's tangent points lie R * tan(turn/2) from the corner; that length is capped at half
    of each adjoining segment, so consecutive blends never overlap. Where it is capped, the arc
    is smaller than delta allows (it passes closer to the corner) and its speed lower. A turn
    below `STRAIGHT_RAD` is straight on (no arc); a full reversal is a stop.
  - Speed limits: each straight piece at most its path's speed (clamped to `max_speed_mps`);
    with `anchors_m` every cable's speed |u . v| (u: the unit vector to the anchor) within
    `max_cable_speed_mps` along every piece. Along a straight line the angle to a fixed anchor
    changes monotonically, so the extreme of |u . d| is at an end of the segment; on an arc the
    tangent is c1 d1 + c2 d2 with c1, c2 >= 0, c1 + c2 <= 1 / cos(turn/2), and every arc point
    lies within the tangent length L of the corner (which turns u by at most 2 L / D for an
    anchor D away), so |u . t| <= max(|u . d1|, |u . d2|) / cos(turn/2) + 2 L / D bounds it
    safely.
  - Look-ahead over everything queued (a backward pass as in Grbl's and Klipper's planners):
    each junction's speed is at most what lets the set-point brake, at the pieces' own
    acceleration limits, to rest at the last queued point. So an empty queue never overshoots:
    the set-point comes to rest exactly at the last point and continues when more arrives
    (`append_points`). Each piece's profile is the fastest trapezoid from its entry speed under
    its cap, ending at the highest speed the pass allows; it is built when the set-point enters
    the piece (and rebuilt from the current state when an append raises its exit speed), so the
    velocity is continuous everywhere, corners included, and |acceleration| <= `max_accel_mps2`.
  - Incremental: appending points plans their pieces and walks back only over the tail whose
    speeds change (those within braking distance of the old end; Klipper's lookahead queue in
    `toolhead.py` flushes the same way), amortised O(1) per point. A blend at the previous last
    point is decided when the next point arrives; if the set-point is already braking for that
    point too hard to slow to the blend's speed, the corner is flown as a stop instead
    (counted in `blends_dropped`), so a late append never breaks a limit.
  - Cost: `advance` samples the head piece (a few arithmetic operations, a sine and a cosine on
    an arc) and plans at most `PLAN_POINTS_PER_CALL` staged points, only while the planned
    distance ahead is shorter than twice the braking distance from max speed (further points
    cannot change the speeds flown now). So neither a path nor an append costs the tick in
    proportion to its length, and a tick's cost does not depend on how much is queued. One
    `advance` crosses at most `MAX_LEGS_PER_ADVANCE` pieces: a path of pieces so short that
    more of them fit in one tick runs slower than planned (the rest of the tick is dropped:
    the trajectory is sampled late, which keeps every limit).
  - The queue holds at most `max_queued_points` points (`queued_points`, `queued_s`,
    `queue_full`); an append beyond it, or with no path in progress, raises `QueueError`.
  - A new move or path that arrives while the effector is moving first brakes to a stop (along
    the path on a path, as `stop` does; else along the current direction at `max_accel_mps2`),
    then starts from the stop point (appends made meanwhile join the new path). Zero-length
    segments are dropped.
* `MotionPlanner.stop`: brake to a hold at any queue depth and close the path (appends are
  refused until a new path). On a path it brakes along the path, through corners: the queue is
  cut where braking at each piece's own limit ends (`max_accel_mps2` on a straight piece, the
  tangential share, 31 % of it at the arc's speed limit, on a corner arc: a stop through a
  corner takes longer), and that point is `rest_point_m`; the look-ahead guarantees it is not
  beyond the last queued point. Otherwise (stream, velocity input) it brakes along the current
  velocity direction at `max_accel_mps2`; the stop point is `position + v^2/(2 a)` along it.
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

import itertools
import math
from collections import deque
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
"""Path pieces (lines and corner arcs) one `MotionPlanner.advance` may cross (bounds the
per-tick cost; module docstring)."""

DEFAULT_JUNCTION_DEVIATION_M = 0.01
"""How far a rounded corner may pass from its path point when none is configured (`[limits]
junction_deviation_m`). 10 mm: a cable robot's effector hangs on elastic cables and sways by
millimetres, and its paths (camera moves, large prints) are metres long, so 10 mm keeps a 90
degree corner at 1 m/s^2 at about sqrt(0.95 * a * 0.024 m) = 0.15 m/s instead of a stop, while
a path drawn with centimetre detail still passes within a centimetre of every point. (Printer
firmware uses 0.01-0.05 mm on rigid frames a hundred times smaller.)"""

CORNER_ACCEL_FRACTION = 0.95
"""The share of `max_accel_mps2` a corner arc may use for its centripetal acceleration at its
speed limit: the rest (sqrt(1 - 0.95^2) = 31 %) changes speed along the arc, so a path made of
arcs only (a finely sampled circle) can still start and stop. A corner is therefore flown at
sqrt(0.95) = 97.5 % of the junction-deviation speed."""

STRAIGHT_RAD = 1e-9
"""A turn smaller than this (rad) is straight on (no arc); closer than this to a full reversal
it is a stop."""

DEFAULT_MAX_QUEUED_POINTS = 100_000
"""The path queue's bound (points) when none is given: appends beyond it are refused."""

PLAN_POINTS_PER_CALL = 8
"""Staged points planned per `advance` (and per path or append call): bounds the tick's cost,
and plans as fast as a path can be flown (at most `MAX_LEGS_PER_ADVANCE` / 2 points a tick)."""


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


class QueueError(ValueError):
    """An append the path queue refuses: no path in progress to append to, or the queue would
    hold more than its bound of points. The planner is unchanged."""


def junction_speed_mps(
    angle_rad: float, junction_deviation_m: float, max_accel_mps2: float
) -> float:
    """Grbl's junction-deviation corner speed sqrt(a * delta * sin(theta/2) / (1 - sin(theta/2))).

    `angle_rad` is the angle between the two segments as Grbl defines it (pi = straight on,
    0 = a full reversal). It is the speed at which the circular blend within
    `junction_deviation_m` of the corner has centripetal acceleration `max_accel_mps2`
    (module docstring). Returns inf straight on and 0 for a reversal. Raises ValueError on a
    non-finite angle or a non-positive deviation or acceleration.
    """
    theta = float(angle_rad)
    if not math.isfinite(theta):
        raise ValueError(f"angle_rad must be finite, got {angle_rad!r}")
    delta = _positive(junction_deviation_m, "junction_deviation_m")
    a = _positive(max_accel_mps2, "max_accel_mps2")
    s = math.sin(0.5 * theta)
    if s >= 1.0:
        return math.inf
    if s <= 0.0:
        return 0.0
    return math.sqrt(a * delta * s / (1.0 - s))


class _Piece:
    """One piece of a planned path: a straight line or a circular blend arc.

    Line: p(s) = p0 + d s. Arc of radius r turning from direction d toward unit normal n:
    p(s) = p0 + d r sin(s/r) + n r (1 - cos(s/r)) (written with 2 sin^2 so that a huge radius
    loses no precision). `vexit` is the fastest exit speed from which the set-point can still
    stop at the end of the queue (the backward pass); `jcap` caps the exit junction (0: stop).
    """

    __slots__ = (
        "acc",
        "arc",
        "cap",
        "d",
        "end",
        "jcap",
        "length",
        "n",
        "p0",
        "point",
        "r",
        "seg",
        "tn",
        "vexit",
    )

    def __init__(
        self,
        arc: bool,
        p0: Vec3,
        d: Vec3,
        end: Vec3,
        length: float,
        cap: float,
        acc: float,
    ) -> None:
        self.arc = arc
        self.p0 = p0
        self.d = d
        self.n: Vec3 = _ZERO
        self.r = 0.0
        self.end = end
        self.length = length
        self.cap = cap
        self.acc = acc
        self.vexit = 0.0
        self.jcap = math.inf
        self.point = False  # a line that ends at a path point (counts the queued points)
        self.seg = length  # a line: its whole segment's length (before the blends trim it)
        self.tn = length / cap if cap > 0.0 else 0.0


class MotionPlanner:
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

    def _start_path(self, chunks: list[tuple[tuple[Vec3, ...], float]]) -> None:
        """Start a path from the set-point at rest."""
        self._clear_path()
        self._open = True
        self._v = _ZERO
        self._last = self._p
        self._mode = _MOVE
        for pts, speed in chunks:
            self._stage(pts, speed)
        self._plan(PLAN_POINTS_PER_CALL)
        self._after_plan()

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
                f"path queue full: {self.queued_points} + {len(points_m)} points would exceed "
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

    def stream(self, target_m: Sequence[float]) -> None:
        """Chase `target_m` (latest wins) under the speed and acceleration limits.

        Replaces any move, path or stop in progress; the current velocity is kept, so the
        hand-over is smooth. Raises ValueError on a non-finite target.
        """
        self._stream_target = _finite3(target_m, "target_m")
        self._clear_path()
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
            self._mode = _VELOCITY
        self._vel_cmd = v
        self._vel_age_s = 0.0
        if v == _ZERO and self._v == _ZERO:
            self._mode = _HOLD  # at rest already: nothing to brake
        return True

    # ----------------------------------------------------------------------------- the queue
    def _clear_path(self) -> None:
        self._q.clear()
        self._staged.clear()
        self._open = False
        self._stopping = False
        self._next_path = []
        self._next_points = 0
        self._staged_points = 0
        self._staged_s = 0.0
        self._queued_points = 0
        self._queued_s = 0.0
        self._queued_m = 0.0

    def _stage(self, pts: tuple[Vec3, ...], speed: float) -> None:
        self._staged.append((pts, 0, speed))
        self._staged_points += len(pts)
        # seconds at the requested speed (the straight legs' length: an estimate until planned)
        prev = self._staged[-2][0][-1] if len(self._staged) > 1 else self._last_point()
        length = 0.0
        for p in pts:
            length += math.dist(prev, p)
            prev = p
        self._staged_s += length / speed

    def _last_point(self) -> Vec3:
        if self._mode == _STOP:
            return self._stop_point()
        return self._last if self._q else self._p

    def _after_plan(self) -> None:
        if self._mode == _MOVE and not self._q and not self._staged:
            self._mode = _HOLD  # nothing to fly (every point repeats the set-point)
            self._v = _ZERO

    def _plan(self, max_points: int, force: bool = False) -> int:
        """Plan staged points into pieces (at most `max_points`, and unless `force` only while
        the planned distance is short of the look-ahead horizon), then run the backward pass
        and re-plan the head. Returns the number of points taken."""
        staged = self._staged
        if not staged:
            return 0
        if not force and self._q and self._queued_m - self._q[0].length >= self._horizon_m:
            return 0
        q = self._q
        if not q:  # starting from rest at the set-point
            self._last = self._p
            self._t_s = self._s0 = self._v0 = 0.0
        taken = 0
        fresh0 = len(q)
        undo: tuple[_Piece, Vec3, float, _Piece | None, _Piece] | None = None
        first = True
        while staged and taken < max_points:
            pts, i, speed = staged[0]
            take = min(len(pts) - i, max_points - taken)
            for j in range(i, i + take):
                if first and pts[j] != self._last:
                    # the first point added: its blend may trim a line planned before
                    undo = self._add_point(pts[j], speed)
                    first = False
                else:
                    self._add_point(pts[j], speed)
            taken += take
            seg_s = 0.0  # the staged estimate of what was just planned
            prev = pts[i - 1] if i > 0 else None
            for j in range(i, i + take):
                if prev is not None:
                    seg_s += math.dist(prev, pts[j])
                prev = pts[j]
            self._staged_points -= take
            self._staged_s = max(0.0, self._staged_s - seg_s / speed)
            if i + take >= len(pts):
                staged.popleft()
            else:
                staged[0] = (pts, i + take, speed)
        if not staged:
            self._staged_s = 0.0
            self._staged_points = 0
        fresh = len(q) - fresh0
        self._backward(fresh)
        if not self._head_feasible() and undo is not None:
            self._undo_blend(undo)
            self._backward(fresh)
            self.blends_dropped += 1
        self._replan_head()
        return taken

    def _add_point(
        self, p: Vec3, speed: float
    ) -> tuple[_Piece, Vec3, float, _Piece | None, _Piece] | None:
        """Queue the line to `p` (and the blend at the previous last point). Returns what
        `_undo_blend` needs if a blend trimmed a line that was already queued, else None."""
        last = self._last
        if p == last:
            return None
        dx, dy, dz = p[0] - last[0], p[1] - last[1], p[2] - last[2]
        l2 = math.hypot(dx, dy, dz)
        d2: Vec3 = (dx / l2, dy / l2, dz / l2)
        cap2 = min(speed, self._line_cable_cap(last, p, d2))
        a = self.max_accel_mps2
        q = self._q
        start = last
        start_off = 0.0
        trimmed: tuple[_Piece, Vec3, float, _Piece] | None = None
        if q:
            prev = q[-1]  # the line to `last`
            arc, lt = self._blend(prev, last, d2, l2, min(prev.cap, cap2))
            if arc is None and lt < 0.0:
                prev.jcap = 0.0  # a reversal: stop at the point
            elif arc is not None:
                old_end, old_len = prev.end, prev.length
                d1 = prev.d
                prev.length -= lt
                self._queued_m -= lt
                prev.end = (last[0] - d1[0] * lt, last[1] - d1[1] * lt, last[2] - d1[2] * lt)
                self._retime(prev)
                self._push(arc)
                start = arc.end
                start_off = lt
                trimmed = (prev, old_end, old_len, arc)
        line = _Piece(False, start, d2, p, l2 - start_off, cap2, a)
        line.seg = l2
        line.point = True
        self._push(line)
        self._queued_points += 1
        self._last = p
        if trimmed is not None:
            return (*trimmed, line)
        return None

    def _push(self, piece: _Piece) -> None:
        self._q.append(piece)
        self._queued_s += piece.tn
        self._queued_m += piece.length

    def _retime(self, piece: _Piece) -> None:
        """Update `piece.tn` and the queued seconds after its length or cap changed (the
        caller updates the queued length)."""
        old_tn = piece.tn
        tn = piece.length / piece.cap if piece.cap > 0.0 else 0.0
        piece.tn = tn
        self._queued_s += tn - old_tn

    def _blend(
        self, prev: _Piece, corner: Vec3, d2: Vec3, l2: float, vcap: float
    ) -> tuple[_Piece | None, float]:
        """The blend arc at `corner` from line `prev` into direction `d2` (segment length `l2`)
        and its tangent length. (None, 0): straight on, no arc; (None, -1): a reversal, stop."""
        d1 = prev.d
        c = d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2]
        nx, ny, nz = d2[0] - c * d1[0], d2[1] - c * d1[1], d2[2] - c * d1[2]
        s = math.hypot(nx, ny, nz)
        phi = math.atan2(s, c)  # the turn: 0 straight on, pi a reversal (Grbl's theta = pi - phi)
        if phi < STRAIGHT_RAD:
            return None, 0.0
        if phi > math.pi - STRAIGHT_RAD:
            return None, -1.0
        half = 0.5 * phi
        ch = math.cos(half)  # Grbl's sin(theta / 2)
        th = math.tan(half)
        one_minus = 2.0 * math.sin(0.5 * half) ** 2  # 1 - cos(half) without cancellation
        r = self.junction_deviation_m * ch / one_minus
        lt = r * th
        lmax = 0.5 * min(prev.seg, l2)
        if lt > lmax:
            lt = lmax
            r = lt / th
        a = self.max_accel_mps2
        cap = min(vcap, math.sqrt(CORNER_ACCEL_FRACTION * a * r))
        if self._anchors:
            cap = min(cap, self._arc_cable_cap(corner, d1, d2, ch, lt))
        if not (cap > 0.0 and r > 0.0 and lt > 0.0):
            return None, -1.0
        cen = cap * cap / r
        at = a * math.sqrt(max(0.0, 1.0 - (cen / a) ** 2))
        start: Vec3 = (corner[0] - d1[0] * lt, corner[1] - d1[1] * lt, corner[2] - d1[2] * lt)
        end: Vec3 = (corner[0] + d2[0] * lt, corner[1] + d2[1] * lt, corner[2] + d2[2] * lt)
        arc = _Piece(True, start, d1, end, r * phi, cap, at)
        arc.n = (nx / s, ny / s, nz / s)
        arc.r = r
        return arc, lt

    def _line_cable_cap(self, a: Vec3, b: Vec3, d: Vec3) -> float:
        """The fastest speed along a->b (direction `d`) at which no cable exceeds its speed
        limit: a cable's rate is v (d . u) with u the unit vector to its anchor, extreme at an
        end of a straight segment (the angle to a fixed point changes monotonically)."""
        if not self._anchors:
            return math.inf
        f = 0.0
        for anc in self._anchors:
            for p in (a, b):
                f = max(f, _abs_cos(anc, p, d))
        return self.max_cable_speed_mps / f if f > 0.0 else math.inf

    def _arc_cable_cap(self, corner: Vec3, d1: Vec3, d2: Vec3, ch: float, lt: float) -> float:
        """A safe cable speed cap on the blend at `corner`: the arc's tangent is c1 d1 + c2 d2
        with c1, c2 >= 0 and c1 + c2 <= 1 / cos(turn / 2) = 1 / `ch`, and every arc point is
        within `lt` of the corner, which moves the unit vector to an anchor D away by at most
        2 lt / D. So |u . t| <= max(|u_c . d1|, |u_c . d2|) / ch + 2 lt / D (and <= 1)."""
        f = 0.0
        for anc in self._anchors:
            dist = math.dist(anc, corner)
            if dist <= 2.0 * lt:
                g = 1.0
            else:
                g = max(_abs_cos(anc, corner, d1), _abs_cos(anc, corner, d2)) / ch
                g = min(1.0, g + 2.0 * lt / dist)
            f = max(f, g)
        return self.max_cable_speed_mps / f if f > 0.0 else math.inf

    def _undo_blend(self, undo: tuple[_Piece, Vec3, float, _Piece | None, _Piece]) -> None:
        """Fly the first corner of the last plan as a stop (no blend): restore the trimmed
        line, make the arc an empty piece at the corner and start the next line there."""
        prev, old_end, old_len, arc, line = undo
        self._queued_m += old_len - prev.length
        prev.end = old_end
        prev.length = old_len
        self._retime(prev)
        prev.jcap = 0.0
        if arc is not None:
            self._queued_m -= arc.length
            arc.length = 0.0
            self._retime(arc)
            arc.cap = 0.0
            arc.p0 = arc.end = old_end
            arc.vexit = 0.0
            self._queued_m += line.seg - line.length
            line.p0 = old_end
            line.length = line.seg
            self._retime(line)

    def _backward(self, fresh: int) -> None:
        """The backward pass: every piece's exit speed bound so that the set-point can stop at
        the end of the queue; walks back over the `fresh` new pieces, the trimmed line before
        them and then only while bounds change (amortised O(1) per point)."""
        nxt: _Piece | None = None
        for k, piece in enumerate(reversed(self._q)):
            if nxt is None:
                new = 0.0
            else:
                v2 = nxt.vexit * nxt.vexit + 2.0 * nxt.acc * nxt.length
                new = min(piece.cap, nxt.cap, piece.jcap, math.sqrt(v2))
            if k > fresh and new == piece.vexit:
                break
            piece.vexit = new
            nxt = piece

    def _head_state(self) -> tuple[float, float]:
        """Distance into the head piece and speed at the profile time `_t_s`."""
        t = self._t_s
        if t <= 0.0:
            return self._s0, self._v0
        if t < self._ta:
            return self._s0 + self._v0 * t + 0.5 * self._acc * t * t, self._v0 + self._acc * t
        t2 = t - self._ta
        if t2 < self._tc:
            return self._s0 + self._da + self._vp * t2, self._vp
        tau = self._dur - t
        if tau <= 0.0:
            return self._s0 + self._span, self._v1
        return (
            self._s0 + self._span - (self._v1 * tau + 0.5 * self._dec * tau * tau),
            self._v1 + self._dec * tau,
        )

    def _head_feasible(self) -> bool:
        q = self._q
        if not q or self._mode != _MOVE:
            return True
        head = q[0]
        s, v = self._head_state()
        rem = head.length - s
        if rem < -1e-12 * max(1.0, head.length):
            return False
        need = v * v - head.vexit * head.vexit
        return need <= 2.0 * head.acc * max(rem, 0.0) * (1.0 + 1e-9) + 1e-18

    def _replan_head(self) -> None:
        """The head's speed profile again from where the set-point is on it now."""
        q = self._q
        if not q:
            return
        if self._mode == _MOVE:
            s, v = self._head_state()
        else:
            s, v = 0.0, 0.0
        self._set_profile(q[0], s, v)

    def _set_profile(self, piece: _Piece, s0: float, v0: float) -> None:
        """The fastest profile over the rest of `piece` from speed `v0`, accelerating at most
        at `piece.acc`, never above its cap, ending at the highest speed <= `piece.vexit`."""
        d = max(0.0, piece.length - s0)
        acc = piece.acc
        v1 = min(piece.vexit, math.sqrt(v0 * v0 + 2.0 * acc * d))
        self._t_s = 0.0
        self._s0 = s0
        self._span = d
        self._v0 = v0
        self._v1 = v1
        self._acc = acc
        if d <= 0.0:
            self._v1 = v0 if v1 < v0 else v1
            self._vp = v0
            self._dec = acc
            self._ta = self._tc = self._td = self._da = self._dur = 0.0
            return
        if v0 * v0 - v1 * v1 >= 2.0 * acc * d:
            # only by rounding (the backward pass leaves room to brake): brake a hair harder
            self._vp = v0
            self._dec = (v0 * v0 - v1 * v1) / (2.0 * d)
            self._ta = self._tc = self._da = 0.0
            self._td = 2.0 * d / (v0 + v1)
            self._dur = self._td
            return
        vp2 = min(piece.cap * piece.cap, 0.5 * (2.0 * acc * d + v0 * v0 + v1 * v1))
        vp = max(math.sqrt(vp2), v0, v1)
        da = (vp * vp - v0 * v0) / (2.0 * acc)
        dd = (vp * vp - v1 * v1) / (2.0 * acc)
        dc = max(0.0, d - da - dd)
        self._vp = vp
        self._dec = acc
        self._da = da
        self._ta = (vp - v0) / acc
        self._td = (vp - v1) / acc
        self._tc = dc / vp if vp > 0.0 else 0.0
        self._dur = self._ta + self._tc + self._td

    # ----------------------------------------------------------------------------- the tick
    def _begin_stop(self) -> None:
        s = self._speed()
        v = self._v
        self._q.clear()
        self._staged.clear()
        self._staged_points = 0
        self._staged_s = 0.0
        self._queued_points = 0
        self._queued_s = 0.0
        self._queued_m = 0.0
        self._open = False
        self._stop_start = self._p
        self._stop_unit = (v[0] / s, v[1] / s, v[2] / s)
        self._stop_speed = s
        self._t_s = 0.0
        self._mode = _STOP

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

    def _advance_move(self, dt_s: float) -> None:
        q = self._q
        if not q:
            self._dry()
            return
        t = self._t_s + dt_s
        crossed = 0
        while t >= self._dur:
            t -= self._dur
            piece = q.popleft()
            self._queued_s -= piece.tn
            self._queued_m -= piece.length
            if piece.point:
                self._queued_points -= 1
            self._p = piece.end
            v1 = self._v1
            if not q:
                self._queued_s = self._queued_m = 0.0
                self._v = _ZERO
                self._t_s = 0.0
                if not self._staged:
                    self._dry()
                return
            self._set_profile(q[0], 0.0, v1)
            crossed += 1
            if crossed >= MAX_LEGS_PER_ADVANCE:
                t = 0.0  # the rest of this step is dropped: the path runs a little late
                break
        self._t_s = t
        self._sample(q[0])

    def _dry(self) -> None:
        """The queue ran dry: at rest at its last point, the path still takes appends (unless
        it was stopped; a path that arrived meanwhile starts now)."""
        self._v = _ZERO
        self._t_s = 0.0
        self._mode = _HOLD
        if self._next_path:
            self._start_next()
        elif self._stopping:
            self._clear_path()

    def _start_next(self) -> None:
        chunks = self._next_path
        self._next_path = []
        self._next_points = 0
        self._start_path(chunks)

    def _path_brake(self) -> tuple[int, float]:
        """Where braking along the queued pieces, each at its own acceleration limit, ends:
        (index of the piece, distance into it). Walks only the pieces within braking distance."""
        s, v = self._head_state()
        v2 = v * v
        q = self._q
        for k, piece in enumerate(q):
            start = s if k == 0 else 0.0
            rem = max(0.0, piece.length - start)
            room = 2.0 * piece.acc * rem
            if v2 <= room:
                return k, start + (v2 / (2.0 * piece.acc) if v2 > 0.0 else 0.0)
            v2 -= room
        return len(q) - 1, q[-1].length  # only by rounding: the end of the queue

    def _stop_on_path(self) -> None:
        """Cut the queue where braking along the path ends and brake there (at any depth)."""
        k, dist = self._path_brake()
        q = self._q
        if k + 1 < len(q):
            self._q = q = deque(itertools.islice(q, k + 1))
        piece = q[k]
        if dist < piece.length:
            piece.end = _point_at(piece, dist)
            piece.length = dist
        self._staged.clear()
        self._staged_points = 0
        self._staged_s = 0.0
        self._queued_points = 0
        self._queued_s = self._queued_m = 0.0
        for p in q:
            p.point = False
            p.tn = p.length / p.cap if p.cap > 0.0 else 0.0
            self._queued_s += p.tn
            self._queued_m += p.length
        self._last = piece.end
        self._backward(len(q))
        self._replan_head()
        self._stopping = True
        self._open = False

    def _sample(self, piece: _Piece) -> None:
        s, v = self._head_state()
        d = piece.d
        p = piece.p0
        if not piece.arc:
            self._p = (p[0] + d[0] * s, p[1] + d[1] * s, p[2] + d[2] * s)
            self._v = (d[0] * v, d[1] * v, d[2] * v)
            return
        r = piece.r
        psi = s / r
        sn = math.sin(psi)
        cs = math.cos(psi)
        a = r * sn
        b = 2.0 * r * math.sin(0.5 * psi) ** 2  # r (1 - cos psi)
        n = piece.n
        self._p = (
            p[0] + d[0] * a + n[0] * b,
            p[1] + d[1] * a + n[1] * b,
            p[2] + d[2] * a + n[2] * b,
        )
        self._v = (
            v * (d[0] * cs + n[0] * sn),
            v * (d[1] * cs + n[1] * sn),
            v * (d[2] * cs + n[2] * sn),
        )

    def _advance_stop(self, dt_s: float) -> None:
        a = self.max_accel_mps2
        t = self._t_s + dt_s
        s0 = self._stop_speed
        t_end = s0 / a
        if t >= t_end:
            self._p = self._stop_point()
            self._v = _ZERO
            self._t_s = 0.0
            if self._next_path:  # a path that arrived while moving starts from the stop point
                self._start_next()
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


def _point_at(piece: _Piece, s: float) -> Vec3:
    """The point `s` along `piece` (a line or an arc)."""
    d = piece.d
    p = piece.p0
    if not piece.arc:
        return (p[0] + d[0] * s, p[1] + d[1] * s, p[2] + d[2] * s)
    r = piece.r
    psi = s / r
    a = r * math.sin(psi)
    b = 2.0 * r * math.sin(0.5 * psi) ** 2
    n = piece.n
    return (p[0] + d[0] * a + n[0] * b, p[1] + d[1] * a + n[1] * b, p[2] + d[2] * a + n[2] * b)


def _abs_cos(anchor: Vec3, p: Vec3, d: Vec3) -> float:
    """|cos| of the angle between direction `d` and the line from `p` to `anchor` (1 at the
    anchor itself: the worst case)."""
    ux, uy, uz = anchor[0] - p[0], anchor[1] - p[1], anchor[2] - p[2]
    n = math.hypot(ux, uy, uz)
    if n == 0.0:
        return 1.0
    return min(1.0, abs(ux * d[0] + uy * d[1] + uz * d[2]) / n)


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
