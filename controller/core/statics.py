"""Statics of a point-mass cable robot: cable tensions that supply a force on the effector.

Pure module: ``math`` and ``numpy`` only (``scipy`` for more than four cables, imported when
first needed), no I/O, no global state.

Model
-----
N straight massless cables pull on one point P; ``u_i`` is the unit vector along cable ``i``
from P toward its anchor ``A_i`` (z up), whatever its direction: a cable may pull up, sideways
or down (a Hangprinter's low anchors).  The cables must supply a force ``f`` on P:
``sum_i t_i u_i = f``.  For a point mass ``m`` at rest, ``f = m g e_z`` (``g = G_MPS2``:
``solve``); an accelerating payload needs ``f = m (g e_z + a)``, and a caller with its own
cable directions (the tangents of sagging cables) hands them in (``solve_force``,
``solve_directions``: the core every solve runs through).  Each tension must stay within
``t_min_n <= t_i <= t_max_n``.  The distance of a distribution to the limits is
``min_i min(t_i - t_min_n, t_max_n - t_i)``; the answer is the equilibrium distribution that
maximises it, and that maximum is ``margin_n`` (negative when no distribution keeps every
cable in range: then it is the distribution that violates the limits least, and
``limiting_cable`` is the cable that cannot be kept in range; nothing is clamped).

* N = 3: ``U t = f`` has the unique solution (Cramer's rule).
* N = 4: the solutions are ``t = t_p + lambda n`` (``t_p`` the minimum-norm solution, ``n``
  the null vector of the 3x4 matrix U, its signed 3x3 minors).  The distance to each limit is
  a linear function of lambda; the largest smallest distance, a max-min of eight lines in one
  variable, is the smallest crossing value of a rising and a falling line (LP duality), and
  lambda is the middle of the interval where every line is at least that value.  Closed form,
  no iteration, vectorised for maps.
* N > 4: the max-min rule is the linear program "maximise s subject to U t = f, t_min + s <=
  t_i <= t_max - s": the distribution nearest the middle of the tension range in the max norm.
  With two or more spare dimensions its optimum can jump from one vertex to another as the
  pose moves (by tens of newtons on an eight-cable cube), so the planned distribution adds a
  small strictly convex term (``tension_many.regularised``): its largest distance from the
  middle is at most ``REGULARISE`` (5 %) more than the max-min's, it is unique and moves
  continuously, and where it would leave the limits while the max-min keeps them the
  max-min's vertex is taken.  ``controller.core.tension_many`` solves both in plain floats
  (the max-min through its dual, by pivots from the last optimal pair of cables; the strictly
  convex one by an active set started from the last pose's), so the tick does one small 3x3
  solve; ``scipy.optimize.linprog`` only settles a degenerate tie beyond rounding.  No
  closed-form derivative: callers take differences.

``feasible`` is ``margin_n >= 0``.  Cable *indices* in data are 0-based; cable *names* in
messages are 1-based (``cable 1`` is row 0), as in ``controller.core.kinematics``.

Examples (the paper robot of config/paper-acre.toml: anchors at (+/-40.45, +/-25, 7.62) m)
---------------------------------------------------------------------------------------
A 5 kg effector (49.03 N) with limits 5..500 N: at (0, 0, 2) m each cable carries
m g / (4 u_z) = 104.44 N (margin 99.44 N, to t_min); at (0, 0, 6.62) m, 1 m below the
anchors, each needs 583.04 N: infeasible, margin -83.04 N.  Sampled on a 0.25 m grid, the
tension-feasible part of its geometric workspace (x +/-38.45, y +/-23, z 0..6.62 m,
23418 m^3) is about 22400 m^3 (96 %): only a layer under the anchors, thinnest at the
corners, needs more than 500 N.  ``tests/test_statics.py`` checks these.

Errors (nothing here returns NaN or inf)
---------------------------------------
* ``StaticsInputError``: wrong shapes, non-finite numbers, ``mass_kg <= 0``, limits not
  ``0 <= t_min_n < t_max_n``, cable directions that are not unit vectors.
* ``SingularConfiguration``: P at (within ``ANCHOR_TOL_M`` of) an anchor; no cable pulls
  along the force (for the weight: P at or above every anchor, e.g. in the plane of level
  anchors); the cable directions do not span space (``sqrt(det(U U^T)) < RANK_TOL``:
  coplanar directions, P on the line of two anchors, coincident or parallel cables for N = 3).
* ``SolverUnavailable``: a degenerate tie of N > 4 cables without scipy.

The batch form never raises for a bad row: singular or non-finite rows get ``feasible`` False,
``limiting`` ``SINGULAR_ROW`` (-1), tensions 0.0 and margin ``SINGULAR_MARGIN_N`` (finite).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from controller.core.statics_errors import (
    SingularConfiguration,
    SolverUnavailable,
    StaticsError,
    StaticsInputError,
)
from controller.core.tension_batch import ANCHOR_TOL_M, UP_TOL, batch_closed, batch_margin
from controller.core.tension_derivative import derivative34
from controller.core.tension_many import (
    MANY_TOL,
    REGULARISE,
    Pairs,
    PairSolution,
    best_pairs,
    finite_tensions,
    freest_pair,
    pair_solution,
    pivot_solve,
    project,
    regularised,
    settles,
    sum_units,
    units_and_sum,
    vertex_tensions,
)
from controller.core.tension_math import RANK_TOL, TRIPLES4, det3, maxmin_lambda

__all__ = [
    "ANCHOR_TOL_M",
    "G_MPS2",
    "PATH_MAX_SAMPLES",
    "RANK_TOL",
    "SINGULAR_MARGIN_N",
    "SINGULAR_ROW",
    "UNIT_TOL",
    "CableStatics",
    "SingularConfiguration",
    "SolverUnavailable",
    "StaticsError",
    "StaticsInputError",
    "TensionCheck",
    "Tensions",
    "solve_tensions",
    "tensions_batch",
]

G_MPS2 = 9.80665
"""Standard gravity (m/s^2)."""

SINGULAR_ROW = -1
"""``limiting`` of a batch row with no distribution (singular configuration or bad input)."""

SINGULAR_MARGIN_N = -1.0e300
"""``margin`` of a batch row with no distribution: finite, below any real margin."""

UNIT_TOL = 1e-6
"""A cable direction handed to ``solve_directions`` must have a length within this of 1."""

_BATCH_CHUNK = 65536  # rows per vectorised chunk: bounds the temporaries (~30 MB for N = 4)

_UP: tuple[float, float, float] = (0.0, 0.0, 1.0)
"""The direction of the force that holds a weight."""

Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class Tensions:
    """The equilibrium tension distribution farthest from the limits at one pose.

    ``tensions_n``: one tension per cable (N), supplying the force (the weight, for
    ``CableStatics.solve``).  ``margin_n``: the smallest
    distance of any tension to either limit (negative when infeasible).  ``limiting_cable``:
    0-based index of the cable at that smallest distance (when infeasible, the cable that cannot
    be kept in range), ``limiting_bound`` which limit it is nearest to or beyond.  ``method``:
    ``"unique"`` (N = 3), ``"closed-form"`` (N = 4) or ``"lp"`` (N > 4, the linear program
    made strictly convex).  ``derivative``:
    d t_i / d P (one row per cable, N/m) when asked of ``CableStatics.solve`` and it has one
    (``tension_derivative``), else None.
    """

    tensions_n: tuple[float, ...]
    feasible: bool
    margin_n: float
    limiting_cable: int
    limiting_bound: Literal["min", "max"]
    t_min_n: float
    t_max_n: float
    method: str
    derivative: tuple[tuple[float, float, float], ...] | None = None

    def reason(self) -> str | None:
        """None when feasible, else why: the cable (1-based), its tension and the limit."""
        if self.feasible:
            return None
        i = self.limiting_cable
        t = self.tensions_n[i]
        limit = (
            f"below t_min {self.t_min_n:g} N"
            if self.limiting_bound == "min"
            else f"above t_max {self.t_max_n:g} N"
        )
        return (
            f"cable {i + 1} cannot be kept in range: at best it carries {t:.4g} N, {limit} "
            f"(margin {self.margin_n:.4g} N)"
        )


def _finite(x: float) -> bool:
    return math.isfinite(x)


def _check_mass(mass_kg: float) -> float:
    try:
        m = float(mass_kg)
    except (TypeError, ValueError):
        raise StaticsInputError(f"mass_kg must be a number, got {mass_kg!r}") from None
    if not (_finite(m) and m > 0.0):
        raise StaticsInputError(f"mass_kg must be finite and > 0, got {mass_kg!r}")
    return m


def _check_force(force_n: Sequence[float]) -> tuple[float, Vec3]:
    """(magnitude, unit direction) of a force; (0, e_z) for no force."""
    try:
        count = len(force_n)
    except TypeError:
        raise StaticsInputError(f"force_n must be 3 numbers, got {force_n!r}") from None
    if count != 3:
        raise StaticsInputError(f"force_n needs 3 components, got {count}")
    try:
        fx, fy, fz = float(force_n[0]), float(force_n[1]), float(force_n[2])
    except (TypeError, ValueError):
        raise StaticsInputError(f"force_n must be 3 numbers, got {force_n!r}") from None
    mag = math.sqrt(fx * fx + fy * fy + fz * fz)
    if not _finite(mag):
        raise StaticsInputError(f"force_n ({fx}, {fy}, {fz}) is not finite")
    if mag == 0.0:
        return 0.0, _UP
    if fx == 0.0 and fy == 0.0:  # along z: exactly the unit vector (the weight's fast path)
        return abs(fz), (0.0, 0.0, 1.0 if fz > 0.0 else -1.0)
    return mag, (fx / mag, fy / mag, fz / mag)


def _check_tension_limits(t_min_n: float, t_max_n: float) -> tuple[float, float]:
    try:
        lo, hi = float(t_min_n), float(t_max_n)
    except (TypeError, ValueError):
        raise StaticsInputError(
            f"tension limits must be numbers, got {t_min_n!r}, {t_max_n!r}"
        ) from None
    if not (_finite(lo) and _finite(hi) and 0.0 <= lo < hi):
        raise StaticsInputError(
            f"tension limits must be finite with 0 <= t_min_n < t_max_n, got {t_min_n!r}, "
            f"{t_max_n!r}"
        )
    return lo, hi


def _anchor_array(anchors_m: ArrayLike) -> NDArray[np.float64]:
    try:
        a = np.array(anchors_m, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise StaticsInputError(f"anchors_m must be an (N, 3) array of numbers: {e}") from None
    if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] < 3:
        raise StaticsInputError(f"anchors_m must have shape (N, 3) with N >= 3, got {a.shape}")
    if not np.isfinite(a).all():
        raise StaticsInputError("anchors_m has a non-finite coordinate")
    a.setflags(write=False)
    return a


def _solve3(u: list[Vec3], mag: float, dirn: Vec3) -> list[float]:
    """The three tensions of ``U t = mag * dirn`` (Cramer)."""
    (ax, ay, az), (bx, by, bz), (cx, cy, cz) = u
    det = det3(ax, ay, az, bx, by, bz, cx, cy, cz)
    if not abs(det) >= RANK_TOL:
        raise SingularConfiguration(
            "the three cable directions are coplanar (det = "
            f"{det:.3g}): they cannot balance the weight"
        )
    fx, fy, fz = dirn
    if fx == 0.0 and fy == 0.0:
        # Along z (the weight): the numerators are z of pairwise cross products.
        w = mag * fz
        return [
            w * (bx * cy - by * cx) / det,
            w * (cx * ay - cy * ax) / det,
            w * (ax * by - ay * bx) / det,
        ]
    # Cramer: t_a = f . (u_b x u_c) / det, and cyclically.
    return [
        mag
        * (fx * (by * cz - bz * cy) + fy * (bz * cx - bx * cz) + fz * (bx * cy - by * cx))
        / det,
        mag
        * (fx * (cy * az - cz * ay) + fy * (cz * ax - cx * az) + fz * (cx * ay - cy * ax))
        / det,
        mag
        * (fx * (ay * bz - az * by) + fy * (az * bx - ax * bz) + fz * (ax * by - ay * bx))
        / det,
    ]


class CableStatics:
    """Tension solver for one anchor layout and one pair of tension limits.

    Validates once; ``solve`` is then the per-pose call.  Raises ``StaticsInputError`` for an
    anchor array not of shape (N, 3) with N >= 3, non-finite numbers, or limits not
    ``0 <= t_min_n < t_max_n``.
    """

    __slots__ = (
        "_anchors_t",
        "_hint",
        "_many",
        "_pairs",
        "_signs",
        "_signs_g",
        "anchors_m",
        "n_cables",
        "t_max_n",
        "t_min_n",
    )

    def __init__(self, anchors_m: ArrayLike, t_min_n: float, t_max_n: float) -> None:
        self.anchors_m = _anchor_array(anchors_m)
        self.n_cables = int(self.anchors_m.shape[0])
        self.t_min_n, self.t_max_n = _check_tension_limits(t_min_n, t_max_n)
        self._anchors_t: tuple[Vec3, ...] = tuple(
            (float(r[0]), float(r[1]), float(r[2])) for r in self.anchors_m.tolist()
        )
        self._pairs = Pairs.of(self.n_cables) if self.n_cables > 4 else None
        # N > 4: the middle of the range, its half and the strictly convex term's weight
        half = 0.5 * (self.t_max_n - self.t_min_n)
        self._many = (
            0.5 * (self.t_min_n + self.t_max_n),
            half,
            2.0 * REGULARISE / (self.n_cables * half),
        )
        # N > 4: the last max-min vertex's pair and the last planned distribution's bound
        # cables, tried first: they only save time (each answer is checked to be the optimum).
        self._hint: tuple[int, int] | None = None
        self._signs: list[float] | None = None
        self._signs_g: Vec3 = (math.inf, math.inf, math.inf)

    # -- single pose -------------------------------------------------------------------------

    def _directions(self, point_m: Sequence[float]) -> tuple[list[Vec3], float]:
        """The unit vectors from P toward the anchors, and the largest z among them."""
        if len(point_m) != 3:
            raise StaticsInputError(f"point_m needs 3 coordinates, got {len(point_m)}")
        px, py, pz = float(point_m[0]), float(point_m[1]), float(point_m[2])
        if not (_finite(px) and _finite(py) and _finite(pz)):
            raise StaticsInputError(f"point_m ({px}, {py}, {pz}) is not finite")
        units: list[Vec3] = []
        up = -1.0
        for i, (ax, ay, az) in enumerate(self._anchors_t):
            dx, dy, dz = ax - px, ay - py, az - pz
            d = math.sqrt(dx * dx + dy * dy + dz * dz)
            if not d > ANCHOR_TOL_M:
                raise SingularConfiguration(
                    f"P = ({px:.6g}, {py:.6g}, {pz:.6g}) m is at anchor {i + 1}: cable {i + 1} "
                    "has no direction"
                )
            uz = dz / d
            if uz > up:
                up = uz
            units.append((dx / d, dy / d, uz))
        return units, up

    def _units(self, point_m: Sequence[float]) -> list[Vec3]:
        """The unit vectors at P of a weight's solve: some cable must pull up."""
        # ``_directions`` written out: the per-tick path of every hanging robot.
        if len(point_m) != 3:
            raise StaticsInputError(f"point_m needs 3 coordinates, got {len(point_m)}")
        px, py, pz = float(point_m[0]), float(point_m[1]), float(point_m[2])
        if not (_finite(px) and _finite(py) and _finite(pz)):
            raise StaticsInputError(f"point_m ({px}, {py}, {pz}) is not finite")
        units: list[Vec3] = []
        up = -1.0
        for ax, ay, az in self._anchors_t:
            dx, dy, dz = ax - px, ay - py, az - pz
            d = math.sqrt(dx * dx + dy * dy + dz * dz)
            if not d > ANCHOR_TOL_M:
                return self._directions(point_m)[0]  # raises, naming the anchor
            uz = dz / d
            if uz > up:
                up = uz
            units.append((dx / d, dy / d, uz))
        if not up > UP_TOL:
            raise SingularConfiguration(
                f"P = ({px:.6g}, {py:.6g}, {pz:.6g}) m is at or above every anchor: no cable "
                "pulls upward, the weight cannot be held"
            )
        return units

    def _units_sum(self, point_m: Sequence[float]) -> tuple[list[Vec3], Vec3]:
        """``_units`` and their sum (``sum_units``): the per-tick path of five or more
        cables.  Raises what ``_units`` raises (it is asked whenever anything is off, and
        names the problem)."""
        got = units_and_sum(self._anchors_t, point_m)
        if got is not None:
            return got
        u = self._units(point_m)
        return u, sum_units(u)

    @staticmethod
    def _check_along(u: Sequence[Vec3], mag: float, dirn: Vec3) -> None:
        """SingularConfiguration when no cable pulls along the force (none can supply it)."""
        if mag == 0.0:
            return
        fx, fy, fz = dirn
        best = max(x * fx + y * fy + z * fz for x, y, z in u)
        if not best > UP_TOL:
            raise SingularConfiguration(
                f"no cable pulls along the force ({mag * fx:.4g}, {mag * fy:.4g}, "
                f"{mag * fz:.4g}) N: it cannot be supplied"
            )

    def solve(self, point_m: Sequence[float], mass_kg: float, derivative: bool = False) -> Tensions:
        """The equilibrium tensions farthest from the limits for a mass ``mass_kg`` at rest at
        P (the cables supply its weight); with `derivative`, also their derivative with
        respect to P (``tension_derivative``, sharing the solve's cable directions and null
        vector: about two thirds of a solve more).

        Raises ``StaticsInputError`` (bad point or mass), ``SingularConfiguration`` (see the
        module docstring), ``SolverUnavailable`` (N > 4 without scipy) and ``StaticsError``
        if the linear program fails.
        """
        m = _check_mass(mass_kg)
        if self._pairs is not None:  # N > 4: no derivative (callers take differences)
            u, su = self._units_sum(point_m)
            return self._result(self._solve_many(u, m * G_MPS2, _UP, su), "lp")
        u = self._units(point_m)
        return self._distribute(u, m * G_MPS2, _UP, point_m if derivative else None)

    def solve_force(
        self, point_m: Sequence[float], force_n: Sequence[float], derivative: bool = False
    ) -> Tensions:
        """The equilibrium tensions farthest from the limits for straight cables from P to
        the anchors that supply the force `force_n` (N) on P: the weight ``(0, 0, m g)`` at
        rest, ``m (g e_z + a)`` for a payload accelerating at ``a``.  With `derivative`, also
        d t / d P at a fixed force (``tension_derivative``).

        Raises ``StaticsInputError`` (bad point or force), ``SingularConfiguration`` (P at an
        anchor, no cable pulling along the force, directions not spanning space) and what
        ``solve`` raises for N > 4.
        """
        mag, dirn = _check_force(force_n)
        u, _ = self._directions(point_m)
        self._check_along(u, mag, dirn)
        return self._distribute(u, mag, dirn, point_m if derivative else None)

    def solve_directions(
        self, units: Sequence[Sequence[float]], force_n: Sequence[float]
    ) -> Tensions:
        """The core of every solve: the equilibrium tensions farthest from the limits for
        cables pulling along `units` (one unit vector per cable, from the effector along the
        cable: toward a straight cable's anchor, along a sagging cable's tangent) that supply
        the force `force_n` (N) on the effector.

        Raises ``StaticsInputError`` for a wrong count, a non-finite number or a direction
        whose length is not 1 (within ``UNIT_TOL``) and ``SingularConfiguration`` when no
        cable pulls along the force or the directions do not span space.
        """
        n = self.n_cables
        if len(units) != n:
            raise StaticsInputError(f"need {n} cable directions, got {len(units)}")
        u: list[Vec3] = []
        for i, v in enumerate(units):
            try:
                x, y, z = (float(c) for c in v)
            except (TypeError, ValueError):
                raise StaticsInputError(
                    f"cable {i + 1}: direction must be 3 numbers, got {v!r}"
                ) from None
            length = math.sqrt(x * x + y * y + z * z)
            if not abs(length - 1.0) <= UNIT_TOL:  # also catches NaN and inf
                raise StaticsInputError(
                    f"cable {i + 1}: direction ({x}, {y}, {z}) is not a unit vector"
                )
            u.append((x, y, z))
        mag, dirn = _check_force(force_n)
        self._check_along(u, mag, dirn)
        return self._distribute(u, mag, dirn, None)

    def _distribute(
        self,
        u: list[Vec3],
        mag: float,
        dirn: Vec3,
        point_m: Sequence[float] | None,
    ) -> Tensions:
        """The distribution for directions `u` and the force ``mag * dirn``; with `point_m`
        (straight cables to the anchors from there) its derivative too."""
        nv: list[float] | None = None
        d = None
        if self.n_cables == 3:
            t = _solve3(u, mag, dirn)
            method = "unique"
        elif self.n_cables == 4:
            t, nv = self._solve4_parts(u, mag, dirn)
            method = "closed-form"
        else:
            t = self._solve_many(u, mag, dirn, sum_units(u))
            method = "lp"
            point_m = None  # no closed-form derivative: callers take differences
        if point_m is not None:
            d = derivative34(self._anchors_t, self.t_min_n, self.t_max_n, point_m, u, t, nv)
        return self._result(t, method, d)

    def _solve_many(self, u: list[Vec3], mag: float, dirn: Vec3, su: Vec3) -> list[float]:
        """N > 4: the planned distribution (``controller.core.tension_many``): the max-min
        rule made strictly convex (``regularised``).  Where its answer frees two cables and
        binds the rest (nearly everywhere) it is the max-min vertex itself, reached by pivots
        from the last pose's pair or from the two cables most nearly perpendicular to the
        force's share, and checked (``settles``); elsewhere the active set is searched from
        the last pose's or the vertex's, and the max-min vertex itself is taken where the
        strictly convex answer leaves the limits but the vertex keeps them (the limits decide,
        not the smoothing).  Each start only saves time: an answer is taken where its
        optimality conditions hold, and it is unique.  `su`: ``sum_i u_i``.  Raises
        ``SingularConfiguration`` where the directions do not span space or the tensions
        overflow."""
        c, r, eps = self._many
        fx, fy, fz = dirn
        f = (mag * fx, mag * fy, mag * fz)
        gx, gy, gz = f[0] - c * su[0], f[1] - c * su[1], f[2] - c * su[2]
        g = (gx, gy, gz)
        scale = self.t_max_n + mag
        tol = MANY_TOL * scale
        lx, ly, lz = self._signs_g
        self._signs_g = g
        # The last active set is likely to hold when g barely moved (the tick); a pose far
        # away (a map, a check of a distant target) starts afresh.
        near = abs(gx - lx) + abs(gy - ly) + abs(gz - lz) < 0.05 * scale
        signs = self._signs
        if near and signs is not None:  # the last answer was not a pair vertex
            res = regularised(u, g, eps, signs, tol, 1)
            if res is not None and res[1] <= r:
                self._signs = res[2]
                return finite_tensions(project(u, f, c, res[0]))
        vertex = self._vertex(u, g, scale, near)
        if settles(u, vertex, eps):
            self._signs = None
            return finite_tensions(vertex_tensions(u, g, c, vertex))
        res = regularised(u, g, eps, vertex.signs, tol, 4 * len(u))
        if res is None or (res[1] > r >= vertex.rho):
            return finite_tensions(project(u, f, c, vertex.d))
        self._signs = res[2]
        return finite_tensions(project(u, f, c, res[0]))

    def _vertex(self, u: list[Vec3], g: Vec3, scale: float, near: bool) -> PairSolution:
        """The max-min distribution's vertex (``tension_many``): the dual simplex from the
        last optimal pair (`near`: the last pose's), or from the two cables most nearly
        perpendicular to g (``freest_pair``), else every pair, else the linear program (a tie
        beyond rounding)."""
        assert self._pairs is not None
        a, b = (self._hint if near else None) or freest_pair(u, g)
        sol = pivot_solve(u, g, a, b, scale, 2 * len(u))
        if sol is not None:
            self._hint = (sol.a, sol.b)
            return sol
        pairs, span = best_pairs(u, g, self._pairs)
        if not span >= RANK_TOL:
            raise SingularConfiguration(
                f"the cable directions do not span space (sqrt(det(U U^T)) = {span:.3g}): "
                "they cannot balance the weight"
            )
        for a, b in pairs:
            sol = pair_solution(u, g, a, b, scale)
            if sol is not None and sol.optimal:
                return sol
        c = 0.5 * (self.t_min_n + self.t_max_n)
        fx = g[0] + c * sum(v[0] for v in u)
        fy = g[1] + c * sum(v[1] for v in u)
        fz = g[2] + c * sum(v[2] for v in u)
        mag, dirn = _check_force((fx, fy, fz))
        t = self._solve_lp(u, mag, dirn)
        d = [x - c for x in t]
        rho = max(abs(x) for x in d)
        return PairSolution(0, 1, d, rho, True, False, [0.0] * len(u), (0.0, 0.0, 0.0), d)

    def _result(
        self,
        t: list[float],
        method: str,
        derivative: tuple[tuple[float, float, float], ...] | None = None,
    ) -> Tensions:
        lo, hi = self.t_min_n, self.t_max_n
        margin = math.inf
        limiting = 0
        bound: Literal["min", "max"] = "min"
        for i, ti in enumerate(t):
            d_lo = ti - lo
            d_hi = hi - ti
            if d_lo < margin:
                margin, limiting, bound = d_lo, i, "min"
            if d_hi < margin:
                margin, limiting, bound = d_hi, i, "max"
        if not math.isfinite(margin):  # overflow on a pathological pose: never return inf
            raise SingularConfiguration("tensions overflow: the configuration is singular")
        return Tensions(
            tensions_n=tuple(t),
            feasible=margin >= 0.0,
            margin_n=margin,
            limiting_cable=limiting,
            limiting_bound=bound,
            t_min_n=lo,
            t_max_n=hi,
            method=method,
            derivative=derivative,
        )

    def _solve4_parts(
        self, u: list[Vec3], mag: float, dirn: Vec3
    ) -> tuple[list[float], list[float]]:
        """The four tensions and the null vector n (n_j = (-1)^j D_j) they were found with."""
        # D_j: determinant of the triple without cable j; the null vector is n_j = (-1)^j D_j.
        # The minimum-norm solution is sum_j D_j^2 t^(j) / |n|^2 where t^(j) solves the triple
        # without cable j (t^(j)_j = 0): the weights sum to 1 and make it orthogonal to n.
        tp = [0.0, 0.0, 0.0, 0.0]
        n = [0.0, 0.0, 0.0, 0.0]
        nn = 0.0
        fx, fy, fz = dirn
        along_z = fx == 0.0 and fy == 0.0
        for j, (a, b, c) in enumerate(TRIPLES4):
            ax, ay, az = u[a]
            bx, by, bz = u[b]
            cx, cy, cz = u[c]
            d = det3(ax, ay, az, bx, by, bz, cx, cy, cz)
            n[j] = -d if j & 1 else d
            nn += d * d
            # D_j^2 t^(j) = D_j * (Cramer numerators: dirn . pairwise cross products)
            if along_z:  # the sign of fz goes into the scale below
                tp[a] += d * (bx * cy - by * cx)
                tp[b] += d * (cx * ay - cy * ax)
                tp[c] += d * (ax * by - ay * bx)
            else:
                tp[a] += d * (
                    fx * (by * cz - bz * cy) + fy * (bz * cx - bx * cz) + fz * (bx * cy - by * cx)
                )
                tp[b] += d * (
                    fx * (cy * az - cz * ay) + fy * (cz * ax - cx * az) + fz * (cx * ay - cy * ax)
                )
                tp[c] += d * (
                    fx * (ay * bz - az * by) + fy * (az * bx - ax * bz) + fz * (ax * by - ay * bx)
                )
        norm = math.sqrt(nn)
        if not norm >= RANK_TOL:
            raise SingularConfiguration(
                f"the four cable directions do not span space (sqrt(det(U U^T)) = {norm:.3g}): "
                "they cannot balance the weight"
            )
        scale = (mag * fz if along_z else mag) / nn
        tp = [x * scale for x in tp]
        s = [x / norm for x in n]
        lam = maxmin_lambda(tp, s, self.t_min_n, self.t_max_n)
        return [tp[i] + lam * s[i] for i in range(4)], n

    def solve_with_derivative(
        self, point_m: Sequence[float], mass_kg: float
    ) -> tuple[tuple[float, ...], tuple[tuple[float, float, float], ...] | None]:
        """(the tensions ``solve`` gives at P for a mass ``mass_kg``, their derivative
        ``tension_derivative``) in one call sharing the cable directions and the null vector;
        without the margin bookkeeping of ``Tensions``.  The derivative is None where
        ``tension_derivative`` gives none.  Raises what ``solve`` raises.
        """
        m = _check_mass(mass_kg)
        u = self._units(point_m)
        w = m * G_MPS2
        nv: list[float] | None = None
        if self.n_cables == 3:
            t = _solve3(u, w, _UP)
        elif self.n_cables == 4:
            t, nv = self._solve4_parts(u, w, _UP)
        else:
            t = self._solve_many(u, w, _UP, sum_units(u))
        total = sum(t)
        if total - total != 0.0:  # overflow on a pathological pose: never return inf
            raise SingularConfiguration("tensions overflow: the configuration is singular")
        if self.n_cables > 4:
            return tuple(t), None
        return tuple(t), derivative34(
            self._anchors_t, self.t_min_n, self.t_max_n, point_m, u, t, nv
        )

    def tension_derivative(
        self, point_m: Sequence[float], tensions_n: Sequence[float]
    ) -> tuple[tuple[float, float, float], ...] | None:
        """d t_i / d P (one row (d/dx, d/dy, d/dz) per cable, N/m) of the distribution
        ``solve`` returns at `point_m`, given those `tensions_n` (its answer there).

        Analytic for three and four cables: differentiating ``U(P) t = m g e_z`` gives
        ``U T' = G`` with ``G = sum_i t_i (I - u_i u_i^T) / L_i``; for four cables the
        distribution also keeps its two binding distances to the limits equal (the rising and
        the falling line of ``maxmin_lambda`` that cross at its optimum), which fixes the
        null-space part.  Where the binding pair changes (a kink of the distribution) this is
        the derivative on the side the tensions `tensions_n` belong to.  Returns None for more
        than four cables (no closed form: callers take differences) and where no line pair
        binds (a cable whose tension does not depend on the null space, a degenerate tie).
        Raises ``StaticsInputError`` for a bad point or a wrong count of tensions and
        ``SingularConfiguration`` where ``solve`` would.
        """
        nc = self.n_cables
        if len(tensions_n) != nc:
            raise StaticsInputError(f"need {nc} tensions, got {len(tensions_n)}")
        if nc > 4:
            return None
        return derivative34(
            self._anchors_t,
            self.t_min_n,
            self.t_max_n,
            point_m,
            self._units(point_m),
            tensions_n,
            None,
        )

    def _solve_lp(self, u: list[Vec3], mag: float, dirn: Vec3) -> list[float]:
        um = np.array(u, dtype=np.float64).T  # (3, N)
        gram = um @ um.T
        rank = math.sqrt(max(float(np.linalg.det(gram)), 0.0))
        if not rank >= RANK_TOL:
            raise SingularConfiguration(
                f"the cable directions do not span space (sqrt(det(U U^T)) = {rank:.3g}): "
                "they cannot balance the weight"
            )
        f = mag * np.array(dirn, dtype=np.float64)
        t = _lp_maxmin(um, f, self.t_min_n, self.t_max_n)
        # Project onto U t = f (the LP meets it only to its tolerance).
        r = f - um @ t
        t = t + um.T @ np.linalg.solve(gram, r)
        if not np.isfinite(t).all():
            raise SingularConfiguration("tensions overflow: the configuration is singular")
        return [float(x) for x in t]

    # -- many poses --------------------------------------------------------------------------

    def solve_batch(
        self, points_m: ArrayLike, mass_kg: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.int64]]:
        """``solve`` for M points at once: ``(tensions (M, N), margin (M,), feasible (M,),
        limiting (M,))``.

        Vectorised for N = 3 and N = 4, one linear program per row for N > 4.  A row that is
        singular or not finite does not raise: feasible False, limiting ``SINGULAR_ROW``,
        tensions 0.0, margin ``SINGULAR_MARGIN_N``.  No NaN or inf in any output.
        Raises ``StaticsInputError`` if ``points_m`` is not (M, 3) numbers or the mass is bad,
        ``SolverUnavailable`` for N > 4 without scipy.
        """
        m = _check_mass(mass_kg)
        lo, hi = self.t_min_n, self.t_max_n
        try:
            p = np.asarray(points_m, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise StaticsInputError(f"points_m must be an (M, 3) array of numbers: {e}") from None
        if p.ndim != 2 or p.shape[1] != 3:
            raise StaticsInputError(f"points_m must have shape (M, 3), got {p.shape}")
        rows = p.shape[0]
        nc = self.n_cables
        tens = np.zeros((rows, nc))
        margin = np.full(rows, SINGULAR_MARGIN_N)
        limiting = np.full(rows, SINGULAR_ROW, dtype=np.int64)
        w = m * G_MPS2
        for start in range(0, rows, _BATCH_CHUNK):
            sl = slice(start, min(rows, start + _BATCH_CHUNK))
            if nc <= 4:
                t, ok = batch_closed(self.anchors_m, p[sl], w, lo, hi)
            else:
                t, ok = self._batch_many(p[sl], m)
            mg, lim = batch_margin(t, lo, hi)
            ok &= np.isfinite(mg)
            tens[sl] = np.where(ok[:, None], t, 0.0)
            margin[sl] = np.where(ok, mg, SINGULAR_MARGIN_N)
            limiting[sl] = np.where(ok, lim, SINGULAR_ROW)
        feasible = (limiting != SINGULAR_ROW) & (margin >= 0.0)
        return tens, margin, feasible, limiting

    def _batch_many(
        self, p: NDArray[np.float64], mass_kg: float
    ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """N > 4 on rows of points: the single-pose solve row by row (each starts from the
        row before: neighbouring points of a map share their bound cables)."""
        t = np.zeros((p.shape[0], self.n_cables))
        ok = np.zeros(p.shape[0], dtype=bool)
        for k, row in enumerate(p.tolist()):
            t[k], ok[k] = self._row(row, mass_kg)
        return t, ok

    def _row(self, point: list[float], mass_kg: float) -> tuple[Any, bool]:
        """One batch row by the single-pose solve: (tensions, True), or (0, False) where it
        is singular or not finite."""
        try:
            return self.solve(point, mass_kg).tensions_n, True
        except SolverUnavailable:
            raise
        except StaticsError:
            return 0.0, False


def _lp_maxmin(
    um: NDArray[np.float64], f: NDArray[np.float64], lo: float, hi: float
) -> NDArray[np.float64]:
    """Max-min tensions for N > 4 by linear programming, in units of the force (or of
    ``hi`` when there is none)."""
    try:
        from scipy.optimize import linprog
    except ImportError:
        raise SolverUnavailable(
            "more than four cables need scipy (scipy.optimize.linprog); install scipy"
        ) from None
    nc = um.shape[1]
    w = float(np.sqrt(f @ f))
    if not w > 0.0:
        w = hi
    lo_w, hi_w = lo / w, hi / w
    # Variables x = (t / w, s / w); minimise -s.
    c = np.zeros(nc + 1)
    c[-1] = -1.0
    a_eq = np.hstack([um, np.zeros((3, 1))])
    b_eq = f / w
    eye = np.eye(nc)
    ones = np.ones((nc, 1))
    a_ub = np.vstack([np.hstack([-eye, ones]), np.hstack([eye, ones])])
    b_ub = np.concatenate([np.full(nc, -lo_w), np.full(nc, hi_w)])
    res: Any = linprog(
        c,
        A_ub=a_ub,
        b_ub=b_ub,
        A_eq=a_eq,
        b_eq=b_eq,
        bounds=[(None, None)] * (nc + 1),
        method="highs",
    )
    if res.status != 0 or res.x is None:
        raise StaticsError(f"the tension linear program failed: {res.message}")
    x: NDArray[np.float64] = np.asarray(res.x[:nc], dtype=np.float64) * w
    return x


PATH_MAX_SAMPLES = 200_000
"""At most this many tension samples per path check (`TensionCheck.path_failure`): the spacing
grows to fit."""


class TensionCheck:
    """The tension rule for one robot and payload: every cable within the limits, by a margin.

    A pose passes when the equilibrium distribution farthest from the limits keeps every
    tension in ``[t_min_n + margin_n, t_max_n - margin_n]`` (``Tensions.margin_n >=
    margin_n``).  ``max_source`` names where ``t_max_n`` comes from, for messages.  Raises
    ``StaticsInputError`` for bad anchors, mass or limits, a negative or non-finite margin, or
    a margin that leaves no range.
    """

    __slots__ = ("margin_n", "mass_kg", "max_source", "statics")

    def __init__(
        self,
        anchors_m: ArrayLike,
        mass_kg: float,
        t_min_n: float,
        t_max_n: float,
        margin_n: float = 0.0,
        max_source: str = "max_tension_n",
    ) -> None:
        self.statics = CableStatics(anchors_m, t_min_n, t_max_n)
        self.mass_kg = _check_mass(mass_kg)
        m = float(margin_n)
        if not (_finite(m) and m >= 0.0):
            raise StaticsInputError(f"margin_n must be finite and >= 0, got {margin_n!r}")
        if not self.statics.t_min_n + m < self.statics.t_max_n - m:
            raise StaticsInputError(
                f"margin_n {m:g} N leaves no range inside {self.statics.t_min_n:g}.."
                f"{self.statics.t_max_n:g} N"
            )
        self.margin_n = m
        self.max_source = max_source

    def solve(self, point_m: Sequence[float], derivative: bool = False) -> Tensions:
        """The payload's tension distribution at P (``CableStatics.solve``, with its derivative
        when asked); raises as it does."""
        return self.statics.solve(point_m, self.mass_kg, derivative)

    def solve_force(
        self, point_m: Sequence[float], force_n: Sequence[float], derivative: bool = False
    ) -> Tensions:
        """The distribution at P when the cables must supply `force_n` (N) instead of the
        payload's weight (e.g. ``m (g e_z + a)`` for the payload accelerating at ``a``):
        ``CableStatics.solve_force``; raises as it does.  Judge it with ``reason``."""
        return self.statics.solve_force(point_m, force_n, derivative)

    def reason(self, result: Tensions) -> str | None:
        """None if `result` passes, else why: the cable (1-based), its tension and the bound."""
        if result.margin_n >= self.margin_n:
            return None
        i = result.limiting_cable
        t = result.tensions_n[i]
        lo, hi, m = self.statics.t_min_n, self.statics.t_max_n, self.margin_n
        if result.limiting_bound == "min":
            return (
                f"cable {i + 1} tension {t:.4g} N below {lo + m:.4g} N (min_tension_n {lo:g} N "
                f"+ tension_margin_n {m:g} N) holding {self.mass_kg:g} kg"
            )
        return (
            f"cable {i + 1} tension {t:.4g} N above {hi - m:.4g} N ({self.max_source} "
            f"{hi:.4g} N - tension_margin_n {m:g} N) holding {self.mass_kg:g} kg"
        )

    def check(self, point_m: Sequence[float]) -> str | None:
        """None if the payload can be held at P by the rule, else the reason. Raises nothing."""
        try:
            return self.reason(self.statics.solve(point_m, self.mass_kg))
        except StaticsError as exc:
            return f"the cables cannot hold {self.mass_kg:g} kg there: {exc}"

    def path_failure(
        self,
        points: Sequence[Sequence[float]],
        start_m: Sequence[float] | None,
        step_m: float,
        max_samples: int = PATH_MAX_SAMPLES,
    ) -> tuple[int, str] | None:
        """The first point of `points` (or point on the straight leg to it, from the point
        before, and from `start_m` for point 0 when given) where the payload cannot be held by
        the rule, as (0-based index, reason), or None.

        Each leg is sampled every `step_m` (coarser if that would exceed `max_samples` in
        all) and solved in one batch; the first failing sample is solved again for its
        reason, which starts with "on the leg to it: at [x, y, z]: " when it is not the point
        itself. Raises nothing for finite points."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if start_m is None:
            starts = np.vstack([pts[:1], pts[:-1]])
        else:
            starts = np.vstack([np.asarray(start_m, dtype=np.float64).reshape(1, 3), pts[:-1]])
        leg = pts - starts
        length = np.sqrt(np.einsum("ij,ij->i", leg, leg))
        counts = np.maximum(1, np.ceil(length / step_m)).astype(np.int64)
        total = int(counts.sum())
        if total > max_samples:
            counts = np.maximum(1, np.ceil(counts * (max_samples / total))).astype(np.int64)
        idx = np.repeat(np.arange(len(pts)), counts)
        # fraction j / m_k along leg k, j = 1..m_k: the last sample is the point itself
        first = np.cumsum(counts) - counts
        frac = (np.arange(idx.size) - first[idx] + 1) / counts[idx]
        samples = starts[idx] + frac[:, None] * leg[idx]
        _, margin, _, limiting = self.statics.solve_batch(samples, self.mass_kg)
        bad = np.flatnonzero((limiting == SINGULAR_ROW) | (margin < self.margin_n))
        if bad.size == 0:
            return None
        j = int(bad[0])
        i = int(idx[j])
        q = (float(samples[j, 0]), float(samples[j, 1]), float(samples[j, 2]))
        reason = self.check(q) or "the tension rule fails there"
        if frac[j] < 1.0:
            at = "[" + ", ".join(f"{v:.4f}" for v in q) + "]"
            return i, f"on the leg to it: at {at}: {reason}"
        return i, reason


# -- module-level conveniences ---------------------------------------------------------------


def solve_tensions(
    anchors_m: ArrayLike, point_m: Sequence[float], mass_kg: float, t_min_n: float, t_max_n: float
) -> Tensions:
    """One-off ``CableStatics(anchors_m, t_min_n, t_max_n).solve(point_m, mass_kg)``.

    Raises what ``CableStatics`` and ``CableStatics.solve`` raise.  For many calls with one
    layout build a ``CableStatics`` once.
    """
    return CableStatics(anchors_m, t_min_n, t_max_n).solve(point_m, mass_kg)


def tensions_batch(
    anchors_m: ArrayLike, points_m: ArrayLike, mass_kg: float, t_min_n: float, t_max_n: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.int64]]:
    """``(tensions (M, N), margin (M,), feasible (M,), limiting (M,))`` for M points.

    See ``CableStatics.solve_batch`` (singular rows: feasible False, limiting ``SINGULAR_ROW``,
    tensions 0.0, margin ``SINGULAR_MARGIN_N``).  Raises what it and ``CableStatics`` raise.
    """
    return CableStatics(anchors_m, t_min_n, t_max_n).solve_batch(points_m, mass_kg)
