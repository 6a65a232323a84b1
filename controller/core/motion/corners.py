"""Corner geometry: Grbl's junction speed, the path's pieces (lines and blend arcs), the blend
arc at a corner and the cable-speed caps along a line and an arc (behaviour: the package
docstring)."""

from __future__ import annotations

import math
from collections import deque

from .speeds import _ZERO, CORNER_ACCEL_FRACTION, STRAIGHT_RAD, SegmentCheck, Vec3, _positive


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


class _State:
    """The planner's state, declared once for the parts it is built from (the corner geometry,
    the path queue, the other modes, the planner; each sets and reads it as the planner did)."""

    max_speed_mps: float
    max_accel_mps2: float
    default_speed_mps: float
    junction_deviation_m: float
    max_cable_speed_mps: float
    max_queued_points: int
    velocity_timeout_s: float
    deadman_stops: int
    boundary_brakes: int
    blends_dropped: int
    _anchors: tuple[Vec3, ...]
    _p: Vec3
    _v: Vec3
    _mode: int
    _q: deque[_Piece]
    _staged: deque[tuple[tuple[Vec3, ...], int, float]]
    _open: bool
    _stopping: bool
    _next_path: list[tuple[tuple[Vec3, ...], float]]
    _next_points: int
    _last: Vec3
    _staged_points: int
    _staged_s: float
    _queued_points: int
    _queued_s: float
    _queued_m: float
    _horizon_m: float
    _t_s: float
    _s0: float
    _v0: float
    _v1: float
    _vp: float
    _acc: float
    _dec: float
    _ta: float
    _tc: float
    _td: float
    _da: float
    _dur: float
    _span: float
    _stop_start: Vec3
    _stop_unit: Vec3
    _stop_speed: float
    _stream_target: Vec3
    _check_segment: SegmentCheck | None
    _vel_cmd: Vec3
    _vel_age_s: float

    def _speed(self) -> float:
        v = self._v
        return math.hypot(v[0], v[1], v[2])

    def _stop_point(self) -> Vec3:
        s = self._stop_speed
        d = s * s / (2.0 * self.max_accel_mps2)
        u = self._stop_unit
        p = self._stop_start
        return (p[0] + u[0] * d, p[1] + u[1] * d, p[2] + u[2] * d)

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
