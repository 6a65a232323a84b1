"""Speeds and the straight move: the motion constants, the commanded-speed rule, velocity
clamping, path de-duplication and the rest-to-rest trapezoid (`TrapezoidMove`); the planner's
modes (behaviour: the package docstring)."""

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

BRAKE_ACCEL_SHARE = math.sqrt(1.0 - CORNER_ACCEL_FRACTION**2)
"""The least share of `max_accel_mps2` a path brakes at (31 %: on a corner arc flown at its
speed limit, the rest is centripetal), so no stop takes longer than speed / (this * a)."""

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
