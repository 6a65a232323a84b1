"""Kinematics of a point-mass cable robot: IPK, FPK (Williams & Needler 2014), least squares.

Pure module: ``math`` and ``numpy`` only, no I/O, no global state.

Conventions
-----------
* SI units, metres.  The world frame {A} has z up; anchors (pulley exit points) ``B_i`` are
  rows of ``Geometry.anchors_m``.  All cables meet in one point P (no rotation).
* Cable *indices* in data (``seed_triple``, arrays) are 0-based, as in Python.  Cable *names*
  in error messages are 1-based (``cable 1`` is row 0), as in the paper (B1..B4).  The bare
  three-spheres functions name the sphere (``r1``/``r2``/``r3``).
* "Lower solution" is the intersection point below the plane of the three sphere centres
  (the paper's ``z_m``, eq. 12): a suspended robot can only pull.
* A tangent (discriminant zero up to a shortfall of ``TANGENT_TOL_M``) is accepted and gives
  ``z`` at the anchor plane; beyond that the lengths cannot meet (eq. 17) and
  ``UnreachableError`` names the cable to blame and by how much.  Eq. 17 singles out cable 1
  only because the paper substitutes back into sphere 1; in fact the radical line misses all
  three spheres at once.  So the error names the one cable whose length alone needs the
  smallest change for the three spheres to meet (the others held), with ``shortfall_m`` > 0
  when it is too short by that much (the usual case, eq. 17) and < 0 when it is too long.
* Nothing here returns NaN or inf: inputs are checked and outputs are finite or an exception
  is raised (single pose) / the row is flagged invalid (batch).

Paper examples (W = 50.0 m, L = 80.9 m, h = 7.62 m; anchors at x = +/-40.46, y = +/-25)
------------------------------------------------------------------------------------------
(a) radii 48, 48, 48 from B1, B2 and (40.46, -25, 7.62) give P = (0, 0, z) with
    z = 7.62 - sqrt(48^2 - 40.46^2 - 25^2) = 7.62 - sqrt(41.9884) = 1.140154 m exactly.
    The paper prints 1.16, which is not a rounding of 1.140 (off by 0.0198 m).  Both printed
    heights, (a) 1.16 and (b) 2.63, are what h = 7.64 m gives (1.1602, 2.6270); with the
    stated h = 7.62 m they are 1.1402 and 2.6070.  The fourth cable is 48 m (symmetry).
(b) radii 38, 48, 58.  The paper prints the third centre as (40.46, -25, 7.62), but with that
    centre the lower solution is (-11.864, -8.600, -11.282), far from the printed
    (-6.55, -8.60, 2.63).  The printed result holds for the third centre at (40.46, 25, 7.62):
    P = (-6.549679, -8.600000, 2.607006), and the "fourth cable 50.04 m" check is the anchor
    (40.46, -25, 7.62): 50.039984 m.  (With the printed centre the other anchor would need
    64.99 m.)  tests/test_kinematics.py shows both readings.

Operation counts (add/subtract, multiply/divide, square root; measured by
tests/test_kinematics_ops.py by running the functions on a counting float type)
--------------------------------------------------------------------------------------------
* Paper: new simplified algorithm 25 / 31 / 1; original general algorithm 48 / 62 / 1.
* ``three_spheres_equal_height`` (everything from the centres on each call: eqs. 7-12 with
  the origin moved to the third centre, the factor 2 of eq. 9 folded into the determinant,
  the quadratic of eq. 11 solved directly on the third sphere): 18 / 18 / 1.
* Per-tick hoisted form used by ``fpk`` (anchor-only terms precomputed in ``Geometry``):
  11 / 9 / 1.
* ``three_spheres`` (general, any heights, parametrised by z along the radical line, one
  square root, numerically stable root choice): 31 / 37 / 1; its per-tick hoisted form used
  by ``fpk`` for unequal heights: 16 / 18 / 1.
  Comparisons and the sign flips of the tangent / unreachable branches are not counted.

Forward kinematics with more than three cables
----------------------------------------------
``fpk`` seeds from ``Geometry.seed_triple`` (the usable triple with the largest plan-view
triangle; an equal-height one preferred among equals) with the simplified algorithm when its
anchors share a height, the general one otherwise.  When the other cables agree with the seed
to 1e-12 m (consistent lengths) that is the answer.  Otherwise it minimises
sum (|P - B_i| - L_i)^2 over all N cables, in the seed cables' length space: the unknowns are
the seed cables' fitted lengths q, P(q) is their three-spheres point, so those three cables
are met exactly and only the others are linearised.  This is what makes it fast: the fit
converges in about two steps, where Gauss-Newton in P needs three or four (near the anchor
plane, where z is poorly determined, many more).

* Four anchors at one height (the usual rig; ``_Planar4``): the fit is one scalar equation
  for a Lagrange multiplier, solved by a closed-form first step and one Newton step, to
  1e-12 m.
* Otherwise (``_fit_scalar``): Gauss-Newton in q, two steps, then until the step is below
  1e-12 m or below 1 um with the next predicted (linear convergence) below 1e-10 m.  With a
  tilted seed triple, the seed's mirror image in the triple's plane also meets the three
  spheres; when it is below every anchor and the other cables agree with it better, the fit
  starts there.
* Whatever these cannot vouch for (a step raising the cost, fitted lengths whose spheres miss,
  no convergence; rare) is finished by Gauss-Newton in P with step halving (``_gauss_newton``,
  which also mirrors to the lower side when all anchors share a height).

``fpk`` and ``fpk_batch`` compute the same fit and agree to ~1e-12 m; rows the batch's
vectorised steps give up on go through the scalar code.  (Within about a millimetre of the
plane of level anchors they may differ by up to ~1e-6 m: there z = zn - sqrt(disc) turns a
rounding difference of 1e-12 m^2 in disc into 1e-6 m, and the lengths fix z no better.)
``residual_m`` is the RMS of |P - B_i| - L_i over all N cables at the returned point.

Speed design
------------
The single-pose path (``three_spheres*``, ``fpk`` on N lengths, ``ipk_point``) is pure
Python floats with anchor-only terms precomputed in ``Geometry``: no numpy on scalars.
The batch path (``fpk_batch``, ``ipk``) is numpy, vectorised over rows, in chunks of
``BATCH_CHUNK`` rows so the working set stays in cache, operating in place on preallocated
buffers (a fresh array per operation doubles the cost of the cheap ones); masked ufuncs
(``where=``) and 2-D fancy indexing are avoided (several times slower than plain ones).  For
four anchors at one height everything up to the square roots is linear in the squared
lengths, so two matrix products, read straight from the row-major input, replace most of
the element-wise work.  ``FpkBatchResult.position_m`` is the (M, 3) transpose of a (3, M)
array.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NoReturn, overload

import numpy as np
import numpy.typing as npt

__all__ = [
    "COINCIDENT_TOL_M",
    "HEIGHT_TOL_M",
    "SINGULAR_REL_TOL",
    "TANGENT_TOL_M",
    "FpkBatchResult",
    "FpkResult",
    "Geometry",
    "KinematicsError",
    "SingularGeometryError",
    "UnreachableError",
    "footprint_contains",
    "fpk",
    "fpk_batch",
    "ipk",
    "ipk_point",
    "paper_anchors",
    "three_spheres",
    "three_spheres_equal_height",
]

FloatArray = npt.NDArray[np.float64]
Vec3 = tuple[float, float, float]

#: Anchors closer than this are coincident.
COINCIDENT_TOL_M = 1e-6
#: Anchor heights within this of each other count as equal (simplified algorithm allowed).
HEIGHT_TOL_M = 1e-9
#: A triple is singular (eq. 14) when its plan-view triangle's doubled area |ae-bd|/4 is below
#: this fraction of the squared plan-view span of the anchors.
SINGULAR_REL_TOL = 1e-6
#: Shortfall (metres) up to which a negative discriminant is treated as a tangent.
TANGENT_TOL_M = 1e-9
#: Gauss-Newton stops when the step is below this.
GN_STEP_TOL_M = 1e-12
#: Rows per chunk of the batch FPK (its working set stays in cache).
BATCH_CHUNK = 16384
#: Gauss-Newton also stops once a step is under 1 um and the next one, predicted from the
#: linear convergence rate (|s_k|^2 / |s_k-1|), is under sqrt(GN_NEXT_TOL2) = 1e-10 m: one
#: evaluation fewer than waiting for a 1e-12 m step, for a difference of about 1e-11 m.
GN_NEXT_TOL2 = 1e-20
#: Gauss-Newton iteration cap.
GN_MAX_ITER = 8
#: Step halvings tried before a Gauss-Newton step is given up.
GN_MAX_HALVINGS = 40
#: A trial step is accepted when the cost (sum of squared residuals, m^2) does not grow by
#: more than this fraction plus ``GN_COST_ROUND_M`` * sqrt(cost): rounding noise, not an
#: overshoot.  Each residual |P - B| - L carries a rounding error of about 1e-16 of the cable
#: length, so near the minimum the cost wobbles by about 2 * sqrt(N * cost) * that error.
GN_COST_REL_TOL = 1e-9
GN_COST_ROUND_M = 1e-11
#: J^T J determinant (sum of unit vectors' outer products) below which the fit stops.
GN_DET_MIN = 1e-12

# Module-level alias: one global lookup per call, and the operation-count test swaps it for a
# counting square root.
_sqrt = math.sqrt


class KinematicsError(ValueError):
    """Base class of every kinematics error."""


class SingularGeometryError(KinematicsError):
    """The anchors cannot be used: coincident, or collinear in plan view (eq. 14)."""


class UnreachableError(KinematicsError):
    """The cable lengths cannot meet in one point (negative discriminant, eq. 17).

    ``cable`` is 1-based: the cable index in the geometry for ``fpk``, the sphere number
    (1, 2, 3) for the bare three-spheres functions.  ``shortfall_m`` is the smallest change
    of that cable alone (others held) that lets the three spheres touch: > 0 means it is too
    short by that much, < 0 too long.
    """

    def __init__(self, cable: int, shortfall_m: float, what: str = "cable") -> None:
        self.cable = cable
        self.shortfall_m = shortfall_m
        name = f"r{cable}" if what == "sphere" else f"cable {cable}"
        how = "short" if shortfall_m >= 0.0 else "long"
        super().__init__(
            f"lengths cannot meet: {name} is too {how} by {abs(shortfall_m):.6g} m "
            "(negative discriminant, eq. 17)"
        )


# --------------------------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _EqualSeed:
    """Anchor-only constants of the simplified algorithm for one triple (hoisted eqs. 9-10)."""

    i1: int
    i2: int
    i3: int
    tri: tuple[int, int, int]
    centres: tuple[Vec3, Vec3, Vec3]
    x1: float
    y1: float
    zn: float
    e1: float  # dx = (r1^2-r3^2)*e1 + (r2^2-r3^2)*e2 + dx0
    e2: float
    dx0: float
    f1: float  # dy = (r1^2-r3^2)*f1 + (r2^2-r3^2)*f2 + dy0
    f2: float
    dy0: float


@dataclass(frozen=True, slots=True)
class _GeneralSeed:
    """Anchor-only constants of the general algorithm for one triple (see ``three_spheres``)."""

    i1: int
    i2: int
    i3: int
    tri: tuple[int, int, int]
    centres: tuple[Vec3, Vec3, Vec3]
    x1: float
    y1: float
    z1: float
    q2: float  # |c2-c1|^2 / 2
    q3: float  # |c3-c1|^2 / 2
    p1: float  # X0 = h2*p1 + h3*p2
    p2: float
    s1: float  # Y0 = h2*s1 + h3*s2
    s2: float
    wx: float  # x = x1 + X0 + wx*s
    wy: float
    inv_a: float  # 1 / (1 + wx^2 + wy^2)


@dataclass(frozen=True, slots=True)
class _Fit:
    """Constants of the least-squares fit in cable-length space (see ``_fit_scalar``).

    For each cable j outside the seed triple, the gradient k_j of its length |P - B_j| with
    respect to the seed cables' lengths (P moving so that it stays on the three spheres) is
    k_ji = L_i * det(D_i) / (d_j * det(D)), D the rows P - C_i of the triple's anchors and D_i
    the same with row i replaced by P - B_j.  Each determinant is linear in P: a . P + b.
    When B_j lies in the triple's plane the ratio is its barycentric coordinate c_ji, a
    constant, and k_ji = c_ji * L_i / d_j (no division by det(D), which vanishes in that
    plane).
    """

    others: tuple[int, ...]  # cables outside the seed triple (0-based)
    anchors: tuple[Vec3, ...]  # their anchors
    bary: tuple[Vec3 | None, ...]  # barycentric coordinates, or None: use ``num``
    num: tuple[tuple[tuple[float, float, float, float], ...] | None, ...]  # (ax, ay, az, b) per i
    den: tuple[float, float, float, float]  # det(D) = den . (x, y, z, 1)
    den_min: float  # |det(D)| below this (P within 1 um of the triple's plane): no fit here
    general: bool  # some k_j needs det(D)
    # Unit normal (n_z > 0) and a point of a tilted triple's plane (None when level): the
    # three spheres also meet at the seed's mirror image in that plane, which can be the
    # robot's position (above the plane yet below every anchor).
    tilt: tuple[Vec3, Vec3] | None


@dataclass(frozen=True, slots=True)
class _Planar4:
    """Four anchors at one height: the least-squares fit is one scalar equation.

    The fourth anchor is the barycentric combination B4 = sum c_i B_i of the seed triple's, so
    for any point on the three spheres |P - B4|^2 = sum c_i q_i^2 + m0 (q_i its distances to
    the triple, m0 = |B4|^2 - sum c_i |B_i|^2).  The fit minimises
    sum (q_i - L_i)^2 + (d - L4)^2 subject to d^2 = sum c_i q_i^2 + m0, whose Lagrange
    conditions give q_i = L_i / (1 + lam c_i), d = L4 / (1 - lam) and, for the multiplier,
    phi(lam) = sum c_i L_i^2 / (1 + lam c_i)^2 + m0 - L4^2 / (1 - lam)^2 = 0, strictly
    decreasing between its poles.  Newton from lam = 0 gives
    lam_1 = (D2 - L4^2) / (2 (A + L4^2)) with D2 = sum c_i L_i^2 + m0 and A = sum c_i^2 L_i^2;
    one more Newton step is taken and measured.  The cost is
    lam^2 (sum c_i^2 q_i^2 + d^2), and P = P(q) is the three-spheres point of the fitted
    lengths (exact: no linearisation in P at all, which is what makes two steps enough).

    For the batch everything before the square roots is linear in the squared lengths: one
    matrix product (``series``) on the four squared lengths gives the seed's X, Y (in the
    frame of the seed's first anchor: X = x - x1, Y = y - y1, depth W = zn - z), Q1, L4^2
    and the Taylor coefficients of phi and phi' in lam; another (``point``) on the fitted
    lengths' squares gives the fitted point's X, Y and A.
    """

    c: Vec3  # barycentric coordinates of the fourth anchor
    m0: float
    curv: float  # bound on |phi'' / (2 phi')|: Newton's error is curv * step^2
    lam_max: float  # |lam| up to which the batch's series for phi is exact to rounding
    x1: float
    y1: float
    zn: float
    tri: tuple[int, int, int]
    k4: int
    series: FloatArray  # (12, 4) on all four squared lengths, see ``_fpk_chunk_p4``
    series_bias: tuple[float, float, float]  # added to the rows X, Y, r0
    point: FloatArray  # (3, 3) on the seed cables' squared lengths: X, Y, A


def _make_planar4(pts: Sequence[Vec3], sd: _EqualSeed, fit: _Fit) -> _Planar4 | None:
    if len(fit.others) != 1 or fit.bary[0] is None:
        return None
    if any(pts[k][2] != sd.zn for k in (*sd.tri, fit.others[0])):
        return None  # the identity for D2 needs the fourth anchor exactly at the seed's height
    c1, c2, c3 = fit.bary[0]
    b4 = fit.anchors[0]
    m0 = -sum(ck * math.dist(pts[k], b4) ** 2 for ck, k in zip((c1, c2, c3), sd.tri, strict=True))
    rx = (sd.e1, sd.e2, -(sd.e1 + sd.e2), sd.dx0)
    ry = (sd.f1, sd.f2, -(sd.f1 + sd.f2), sd.dy0)
    k4 = fit.others[0]
    # Rows over (L_1^2 .. L_4^2) in cable order: X, Y, Q1, T = L4^2, then phi's Taylor
    # coefficients r_n = (n + 1) ((-1)^n S_(n+1) - T) (S_k = sum c_i^k Q_i; r0 also gets m0)
    # and phi''s, p_n = (n + 1) r_(n+1).
    series = np.zeros((12, 4), dtype=np.float64)
    for i, (col, ci) in enumerate(zip(sd.tri, (c1, c2, c3), strict=True)):
        series[0, col], series[1, col] = rx[i], ry[i]
        if i == 0:
            series[2, col] = 1.0
        for k in range(5):
            series[4 + k, col] = (k + 1) * (-1.0) ** k * ci ** (k + 1)
    series[3, k4] = 1.0
    for k in range(5):
        series[4 + k, k4] = -(k + 1.0)
    for k in range(1, 4):
        series[8 + k] = (k + 1) * series[4 + k + 1]
    point = np.array([rx[:3], ry[:3], (c1 * c1, c2 * c2, c3 * c3)], dtype=np.float64)
    cmax = max(1.0, abs(c1), abs(c2), abs(c3))
    return _Planar4(
        (c1, c2, c3),
        m0,
        3.0 * cmax,
        1e-3 / cmax,
        sd.x1,
        sd.y1,
        sd.zn,
        sd.tri,
        k4,
        series,
        (sd.dx0, sd.dy0, m0),
        point,
    )


def _plan_cross(a: Sequence[float], b: Sequence[float], c: Sequence[float]) -> float:
    """(x3-x1)(y3-y2) - (y3-y1)(x3-x2): eq. 13 divided by 4 (twice the signed plan area)."""
    return (c[0] - a[0]) * (c[1] - b[1]) - (c[1] - a[1]) * (c[0] - b[0])


def _convex_hull(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Counter-clockwise convex hull (Andrew's monotone chain), collinear points dropped."""
    pts = sorted(set(points))
    if len(pts) < 3:
        return pts

    def cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[tuple[float, float]] = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0.0:
            lower.pop()
        lower.append(p)
    upper: list[tuple[float, float]] = []
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0.0:
            upper.pop()
        upper.append(p)
    return lower[:-1] + upper[:-1]


class Geometry:
    """Anchor layout of an N-cable point-mass robot (N >= 3), validated at construction.

    ``anchors_m`` is an (N, 3) array-like of the pulley exit points.  Raises
    ``KinematicsError`` for a wrong shape, N < 3 or non-finite numbers, and
    ``SingularGeometryError`` for coincident anchors or when no triple of anchors is usable
    by the FPK (every triple collinear in plan view, eq. 14; with N == 3 the only triple).
    Triples that are singular are simply not used when N > 3; ``triples`` lists the usable
    ones (0-based), ``seed_triple`` is the best-conditioned one (largest plan-view area),
    which seeds every FPK.

    ``height_tol_m``: anchor heights within this count as equal (``equal_heights``).
    """

    __slots__ = (
        "_anchors_t",
        "_fit",
        "_hull_edges",
        "_p4",
        "_seed",
        "anchor_height_max_m",
        "anchor_height_min_m",
        "anchors_m",
        "equal_heights",
        "footprint_m",
        "height_tol_m",
        "n_cables",
        "seed_triple",
        "seed_uses_simplified",
        "triples",
    )

    anchors_m: FloatArray
    n_cables: int
    equal_heights: bool
    anchor_height_min_m: float
    anchor_height_max_m: float
    height_tol_m: float
    triples: tuple[tuple[int, int, int], ...]
    seed_triple: tuple[int, int, int]
    seed_uses_simplified: bool
    footprint_m: tuple[tuple[float, float], ...]
    _anchors_t: tuple[Vec3, ...]
    _seed: _EqualSeed | _GeneralSeed
    _fit: _Fit
    _p4: _Planar4 | None
    _hull_edges: tuple[tuple[float, float, float], ...]

    def __init__(self, anchors_m: Any, height_tol_m: float = HEIGHT_TOL_M) -> None:
        try:
            arr = np.array(anchors_m, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise KinematicsError(f"anchors must be an (N, 3) array of numbers: {exc}") from exc
        if arr.ndim != 2 or arr.shape[1] != 3:
            raise KinematicsError(f"anchors must have shape (N, 3), got {arr.shape}")
        n = int(arr.shape[0])
        if n < 3:
            raise KinematicsError(f"need at least 3 anchors, got {n}")
        if not np.all(np.isfinite(arr)):
            raise KinematicsError("anchors must be finite numbers")
        if not (math.isfinite(height_tol_m) and height_tol_m >= 0.0):
            raise KinematicsError("height_tol_m must be finite and >= 0")
        arr.setflags(write=False)
        pts: tuple[Vec3, ...] = tuple((float(r[0]), float(r[1]), float(r[2])) for r in arr.tolist())
        for i, j in itertools.combinations(range(n), 2):
            if math.dist(pts[i], pts[j]) <= COINCIDENT_TOL_M:
                raise SingularGeometryError(f"anchors {i + 1} and {j + 1} coincide")

        span2 = max(
            (a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 for a, b in itertools.combinations(pts, 2)
        )
        limit = SINGULAR_REL_TOL * span2
        usable: list[tuple[float, tuple[int, int, int]]] = []
        for tri in itertools.combinations(range(n), 3):
            area2 = abs(_plan_cross(pts[tri[0]], pts[tri[1]], pts[tri[2]]))
            if area2 > limit:
                usable.append((area2, tri))
        if not usable:
            raise SingularGeometryError(
                "algorithmic singularity (eq. 14): "
                + ("the three anchors are" if n == 3 else "every triple of anchors is")
                + " collinear in plan view"
            )

        zs = [p[2] for p in pts]
        self.anchors_m = arr
        self.n_cables = n
        self.height_tol_m = float(height_tol_m)
        self.anchor_height_min_m = min(zs)
        self.anchor_height_max_m = max(zs)
        self.equal_heights = (max(zs) - min(zs)) <= height_tol_m
        self.triples = tuple(t for _, t in usable)
        self._anchors_t = pts

        def tri_equal(t: tuple[int, int, int]) -> bool:
            h = [zs[k] for k in t]
            return max(h) - min(h) <= height_tol_m

        best = max(a for a, _ in usable)
        near_best = [(a, t) for a, t in usable if a >= best * (1.0 - 1e-9)]
        # Among the best-conditioned triples prefer one the simplified algorithm can use.
        near_best.sort(key=lambda at: (not tri_equal(at[1]), at[1]))
        seed = near_best[0][1]
        self.seed_triple = seed
        self.seed_uses_simplified = tri_equal(seed)
        self._seed = (
            _make_equal_seed(pts, seed)
            if self.seed_uses_simplified
            else _make_general_seed(pts, seed)
        )
        self._fit = _make_fit(pts, seed, height_tol_m)
        self._p4 = (
            _make_planar4(pts, self._seed, self._fit)
            if isinstance(self._seed, _EqualSeed)
            else None
        )

        hull = _convex_hull([(p[0], p[1]) for p in pts])
        # The anchors' plan-view convex hull, counter-clockwise (x, y) vertices.
        self.footprint_m = tuple(hull)
        edges: list[tuple[float, float, float]] = []
        for k in range(len(hull)):
            (ax, ay), (bx, by) = hull[k], hull[(k + 1) % len(hull)]
            ln = math.hypot(bx - ax, by - ay)
            nx, ny = -(by - ay) / ln, (bx - ax) / ln  # inward normal of a CCW polygon
            edges.append((nx, ny, -(nx * ax + ny * ay)))
        self._hull_edges = tuple(edges)

    def __repr__(self) -> str:
        return f"Geometry(anchors_m={self.anchors_m.tolist()!r})"


def _make_equal_seed(pts: Sequence[Vec3], tri: tuple[int, int, int]) -> _EqualSeed:
    (x1, y1, z1), (x2, y2, z2), (x3, y3, z3) = (pts[k] for k in tri)
    a, b = 2.0 * (x3 - x1), 2.0 * (y3 - y1)
    d, e = 2.0 * (x3 - x2), 2.0 * (y3 - y2)
    det = a * e - b * d
    k1 = x3 * x3 + y3 * y3 - x1 * x1 - y1 * y1
    k2 = x3 * x3 + y3 * y3 - x2 * x2 - y2 * y2
    e1, e2 = e / det, -b / det
    f1, f2 = -d / det, a / det
    return _EqualSeed(
        i1=tri[0],
        i2=tri[1],
        i3=tri[2],
        tri=tri,
        centres=(pts[tri[0]], pts[tri[1]], pts[tri[2]]),
        x1=x1,
        y1=y1,
        zn=(z1 + z2 + z3) / 3.0,
        e1=e1,
        e2=e2,
        dx0=k1 * e1 + k2 * e2 - x1,
        f1=f1,
        f2=f2,
        dy0=k1 * f1 + k2 * f2 - y1,
    )


def _make_general_seed(pts: Sequence[Vec3], tri: tuple[int, int, int]) -> _GeneralSeed:
    (x1, y1, z1), (x2, y2, z2), (x3, y3, z3) = (pts[k] for k in tri)
    v2x, v2y, v2z = x2 - x1, y2 - y1, z2 - z1
    v3x, v3y, v3z = x3 - x1, y3 - y1, z3 - z1
    uz = v2x * v3y - v2y * v3x
    wx = (v2y * v3z - v2z * v3y) / uz
    wy = (v3x * v2z - v2x * v3z) / uz
    return _GeneralSeed(
        i1=tri[0],
        i2=tri[1],
        i3=tri[2],
        tri=tri,
        centres=(pts[tri[0]], pts[tri[1]], pts[tri[2]]),
        x1=x1,
        y1=y1,
        z1=z1,
        q2=0.5 * (v2x * v2x + v2y * v2y + v2z * v2z),
        q3=0.5 * (v3x * v3x + v3y * v3y + v3z * v3z),
        p1=v3y / uz,
        p2=-v2y / uz,
        s1=-v3x / uz,
        s2=v2x / uz,
        wx=wx,
        wy=wy,
        inv_a=1.0 / (1.0 + wx * wx + wy * wy),
    )


def _det_plane(c: Sequence[Vec3]) -> tuple[float, float, float, float]:
    """(ax, ay, az, b) with det[P - c0; P - c1; P - c2] = a . P + b for every P."""
    (x0, y0, z0), (x1, y1, z1), (x2, y2, z2) = c
    ux, uy, uz = x2 - x0, y2 - y0, z2 - z0
    vx, vy, vz = x2 - x1, y2 - y1, z2 - z1
    ax, ay, az = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    return ax, ay, az, -(ax * x2 + ay * y2 + az * z2)


def _make_fit(pts: Sequence[Vec3], tri: tuple[int, int, int], height_tol_m: float) -> _Fit:
    cs = [pts[k] for k in tri]
    den = _det_plane(cs)
    norm = math.sqrt(den[0] * den[0] + den[1] * den[1] + den[2] * den[2])
    sg = 1.0 if den[2] > 0.0 else -1.0
    others = tuple(k for k in range(len(pts)) if k not in tri)
    bary: list[Vec3 | None] = []
    num: list[tuple[tuple[float, float, float, float], ...] | None] = []
    for j in others:
        bj = pts[j]
        off_plane_m = abs(den[0] * bj[0] + den[1] * bj[1] + den[2] * bj[2] + den[3]) / norm
        if off_plane_m <= height_tol_m:
            # Plan-view barycentric coordinates (the triple is not collinear in plan view).
            (x1, y1, _), (x2, y2, _), (x3, y3, _) = cs
            det = (x1 - x3) * (y2 - y3) - (x2 - x3) * (y1 - y3)
            c1 = ((bj[0] - x3) * (y2 - y3) - (x2 - x3) * (bj[1] - y3)) / det
            c2 = ((x1 - x3) * (bj[1] - y3) - (bj[0] - x3) * (y1 - y3)) / det
            bary.append((c1, c2, 1.0 - c1 - c2))
            num.append(None)
        else:
            bary.append(None)
            num.append(
                tuple(_det_plane([bj if m == i else cs[m] for m in range(3)]) for i in range(3))
            )
    return _Fit(
        others=others,
        anchors=tuple(pts[j] for j in others),
        bary=tuple(bary),
        num=tuple(num),
        den=den,
        den_min=1e-6 * norm,
        general=any(b is None for b in bary),
        tilt=None
        if den[0] == 0.0 and den[1] == 0.0
        else ((den[0] / norm * sg, den[1] / norm * sg, den[2] / norm * sg), cs[0]),
    )


def paper_anchors(
    half_length_m: float = 40.46, half_width_m: float = 25.0, height_m: float = 7.62
) -> FloatArray:
    """The paper's rectangular layout B1..B4 (section 2) as a (4, 3) array.

    B1=(-L/2,-W/2,h), B2=(-L/2,W/2,h), B3=(L/2,W/2,h), B4=(L/2,-W/2,h).  The defaults are
    the paper's printed anchors (x = +/-40.46 m; L/2 would be 40.45).  Raises nothing.
    """
    hl, hw = half_length_m, half_width_m
    return np.array(
        [[-hl, -hw, height_m], [-hl, hw, height_m], [hl, hw, height_m], [hl, -hw, height_m]],
        dtype=np.float64,
    )


def footprint_contains(geom: Geometry, x_m: float, y_m: float, margin_m: float = 0.0) -> bool:
    """True when (x, y) lies in the anchors' plan-view convex hull shrunk by ``margin_m``.

    A point exactly ``margin_m`` from an edge is inside.  Non-finite input gives False.
    Raises nothing.
    """
    # ">=" is False for NaN, so a NaN coordinate is outside.
    return all(nx * x_m + ny * y_m + c >= margin_m for nx, ny, c in geom._hull_edges)


# --------------------------------------------------------------------------------------------
# Inverse pose kinematics
# --------------------------------------------------------------------------------------------


def ipk_point(geom: Geometry, position_m: Sequence[float]) -> tuple[float, ...]:
    """Cable lengths (metres) for one point, pure Python floats (the per-tick fast path).

    Raises ``KinematicsError`` for a non-finite position.
    """
    x, y, z = position_m
    out = tuple(
        [
            _sqrt((x - ax) * (x - ax) + (y - ay) * (y - ay) + (z - az) * (z - az))
            for ax, ay, az in geom._anchors_t
        ]
    )
    s = x + y + z
    if s - s != 0.0:
        raise KinematicsError(f"position must be finite, got {tuple(position_m)!r}")
    return out


def ipk(geom: Geometry, position_m: Any) -> FloatArray:
    """Cable lengths: shape (N,) for one point (3,), (M, N) for M points (M, 3).

    Raises ``KinematicsError`` for a wrong shape or non-finite positions.
    """
    p = np.asarray(position_m, dtype=np.float64)
    if p.shape[-1:] != (3,) or p.ndim not in (1, 2):
        raise KinematicsError(f"position must have shape (3,) or (M, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise KinematicsError("position must be finite")
    diff = p[..., None, :] - geom.anchors_m
    out: FloatArray = np.sqrt(np.einsum("...k,...k->...", diff, diff))
    return out


# --------------------------------------------------------------------------------------------
# Three-spheres intersection
# --------------------------------------------------------------------------------------------


def _is_tangent(r1: float, r2: float, r3: float, power: float) -> bool:
    """Whether a negative discriminant is only a tangent (rounding), not a real miss.

    ``power`` > 0 is the (equal) power d_i^2 - r_i^2 of the radical line's closest point with
    respect to the three spheres; the line misses sphere i by d_i - r_i.
    """
    r = min(abs(r1), abs(r2), abs(r3))
    return math.sqrt(r * r + power) - r <= TANGENT_TOL_M


def _diagnose(
    cs: Sequence[Sequence[float]], rs: Sequence[float], power: float
) -> tuple[int, float]:
    """Name the cable to blame when three spheres cannot meet, and by how much.

    For each sphere k, with the other two lengths held, the lengths of k that meet them form
    an interval [lo, hi] (distances from c_k to the other two spheres' intersection circle).
    Returns the 1-based k needing the smallest change and that change: > 0 when it is too
    short by that much, < 0 when too long.  If no single cable can fix it (two spheres are
    disjoint whatever k does), names the shortest cable and its miss of the radical line.
    """
    best: tuple[float, int, float] | None = None
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        ci, cj, ck = cs[i], cs[j], cs[k]
        vx, vy, vz = cj[0] - ci[0], cj[1] - ci[1], cj[2] - ci[2]
        d = math.sqrt(vx * vx + vy * vy + vz * vz)
        if d == 0.0:
            continue
        nx, ny, nz = vx / d, vy / d, vz / d
        a = (d * d + rs[i] * rs[i] - rs[j] * rs[j]) / (2.0 * d)
        rho2 = rs[i] * rs[i] - a * a
        if rho2 < 0.0:
            continue
        rho = math.sqrt(rho2)
        wx, wy, wz = ck[0] - ci[0] - a * nx, ck[1] - ci[1] - a * ny, ck[2] - ci[2] - a * nz
        wn = wx * nx + wy * ny + wz * nz
        wp = math.sqrt(max(wx * wx + wy * wy + wz * wz - wn * wn, 0.0))
        lo, hi = math.hypot(wn, wp - rho), math.hypot(wn, wp + rho)
        rk = rs[k]
        change = lo - rk if rk < lo else (hi - rk if rk > hi else 0.0)
        if best is None or abs(change) < best[0]:
            best = (abs(change), k + 1, change)
    if best is not None and best[2] != 0.0:
        return best[1], best[2]
    k = min(range(3), key=lambda i: abs(rs[i]))
    r = abs(rs[k])
    return k + 1, math.sqrt(r * r + power) - r


def three_spheres_equal_height(
    c1: Sequence[float],
    c2: Sequence[float],
    c3: Sequence[float],
    r1: float,
    r2: float,
    r3: float,
) -> Vec3:
    """Lower intersection of three spheres whose centres share one height: eqs. (1)-(12).

    The paper's simplified algorithm, computed from the centres on every call (the per-tick
    form with anchor-only terms hoisted lives in ``fpk``).  Returns (x, y, z_m) with z_m the
    solution below the centres (eq. 12, minus sign).
    Raises ``KinematicsError`` when the centres' heights differ (use ``three_spheres``),
    ``SingularGeometryError`` when the centres are collinear in plan view (eq. 14), and
    ``UnreachableError`` naming the sphere (r1/r2/r3) that is too short (eq. 17).
    """
    x1, y1, z1 = c1
    x2, y2, z2 = c2
    x3, y3, zn = c3
    if zn != z1 or zn != z2:
        raise KinematicsError("centre heights differ; use three_spheres()")
    # Eqs. (7)-(8) with the origin moved to c3 (the factor 2 of a, b, d, e folded into the
    # determinant): a'x + b'y = c', d'x + e'y = f' for q = (x - x3, y - y3).
    a = x1 - x3
    b = y1 - y3
    d = x2 - x3
    e = y2 - y3
    r3s = r3 * r3
    c = a * a + b * b - r1 * r1 + r3s
    f = d * d + e * e - r2 * r2 + r3s
    try:
        inv = 0.5 / (a * e - b * d)  # eq. (13) / 4 is the determinant
    except ZeroDivisionError:  # a zero-cost guard on the fast path (CPython >= 3.11)
        raise SingularGeometryError("centres collinear in plan view (eq. 14)") from None
    qx = (c * e - b * f) * inv  # eq. (10)
    qy = (a * f - c * d) * inv
    # Eqs. (11)-(12) on sphere 3: (B^2 - 4C) / 4.
    disc = r3s - qx * qx - qy * qy
    if disc < 0.0:
        if not _is_tangent(float(r1), float(r2), float(r3), -float(disc)):
            cable, change = _diagnose((c1, c2, c3), (r1, r2, r3), -float(disc))
            raise UnreachableError(cable, change, "sphere")
        disc = 0.0 * disc
    return (x3 + qx, y3 + qy, zn - _sqrt(disc))


def three_spheres(
    c1: Sequence[float],
    c2: Sequence[float],
    c3: Sequence[float],
    r1: float,
    r2: float,
    r3: float,
) -> Vec3:
    """Lower intersection of three spheres with centres at any heights (general algorithm).

    Subtracting sphere 1 from spheres 2 and 3 gives two planes whose intersection (the
    radical line) is parametrised by s = z - z1: x = x1 + X0 + wx*s, y = y1 + Y0 + wy*s.
    Sphere 1 then gives A s^2 + 2 B s + C = 0; the root with the smaller z is returned,
    computed without cancellation.  The only singularity is the true one (centres collinear
    in plan view, where "lower" is undefined); equal heights give wx = wy = 0 and reduce it to
    the simplified algorithm.
    Raises ``SingularGeometryError`` for plan-view collinear centres and ``UnreachableError``
    naming the sphere (r1/r2/r3) that is too short.
    """
    x1, y1, z1 = c1
    x2, y2, z2 = c2
    x3, y3, z3 = c3
    v2x = x2 - x1
    v2y = y2 - y1
    v2z = z2 - z1
    v3x = x3 - x1
    v3y = y3 - y1
    v3z = z3 - z1
    uz = v2x * v3y - v2y * v3x
    if uz == 0.0:
        raise SingularGeometryError("centres collinear in plan view (eq. 14)")
    inv = 1.0 / uz
    wx = (v2y * v3z - v2z * v3y) * inv
    wy = (v3x * v2z - v2x * v3z) * inv
    r1s = r1 * r1
    h2 = 0.5 * (r1s - r2 * r2 + v2x * v2x + v2y * v2y + v2z * v2z)
    h3 = 0.5 * (r1s - r3 * r3 + v3x * v3x + v3y * v3y + v3z * v3z)
    x0 = (h2 * v3y - v2y * h3) * inv
    y0 = (v2x * h3 - v3x * h2) * inv
    qa = 1.0 + wx * wx + wy * wy
    qb = x0 * wx + y0 * wy
    qc = x0 * x0 + y0 * y0 - r1s
    disc = qb * qb - qa * qc
    if disc < 0.0:
        power = -float(disc) / float(qa)
        if not _is_tangent(float(r1), float(r2), float(r3), power):
            cable, change = _diagnose((c1, c2, c3), (r1, r2, r3), power)
            raise UnreachableError(cable, change, "sphere")
        disc = 0.0 * disc
    sq = _sqrt(disc)
    if qb > 0.0:
        s = -(qb + sq) / qa
    else:
        den = sq - qb
        s = qc / den if den != 0.0 else 0.0 * qb
    return (x1 + x0 + wx * s, y1 + y0 + wy * s, z1 + s)


# --------------------------------------------------------------------------------------------
# Forward pose kinematics
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class FpkResult:
    """One FPK solution: position, RMS cable-length mismatch, seed triple (0-based)."""

    position_m: Vec3
    residual_m: float
    seed_triple: tuple[int, int, int]


@dataclass(frozen=True, slots=True)
class FpkBatchResult:
    """A batch of FPK solutions; rows with ``valid`` False hold zeros, never NaN.

    ``position_m`` has shape (M, 3); it is a transposed view of a (3, M) array, so
    ``position_m[:, 0]`` (all x) is contiguous.

    ``short_cable`` is, for rows whose seed triple cannot meet, the 1-based cable to blame
    (0 elsewhere) and ``shortfall_m`` the change it needs, > 0 too short, < 0 too long (0
    elsewhere); the same diagnosis as ``UnreachableError``.
    """

    position_m: FloatArray
    residual_m: FloatArray
    valid: npt.NDArray[np.bool_]
    seed_triple: tuple[int, int, int]
    short_cable: npt.NDArray[np.int64]
    shortfall_m: FloatArray


def _raise_unreachable(
    tri: tuple[int, int, int], centres: tuple[Vec3, Vec3, Vec3], rs: Vec3, power: float
) -> NoReturn:
    k, change = _diagnose(centres, rs, power)
    raise UnreachableError(tri[k - 1] + 1, change)


def _seed_equal(sd: _EqualSeed, r1: float, r2: float, r3: float) -> Vec3:
    """Per-tick simplified algorithm with hoisted constants; 11 add, 9 mul, 1 sqrt."""
    s1 = r1 * r1
    s3 = r3 * r3
    u = s1 - s3
    v = r2 * r2 - s3
    dx = u * sd.e1 + v * sd.e2 + sd.dx0
    dy = u * sd.f1 + v * sd.f2 + sd.dy0
    disc = s1 - dx * dx - dy * dy
    if disc < 0.0:
        if not _is_tangent(r1, r2, r3, -disc):
            _raise_unreachable(sd.tri, sd.centres, (r1, r2, r3), -disc)
        disc = 0.0 * disc
    return (sd.x1 + dx, sd.y1 + dy, sd.zn - _sqrt(disc))


def _seed_general(sd: _GeneralSeed, r1: float, r2: float, r3: float) -> Vec3:
    """Per-tick general algorithm with hoisted constants; 16 add, 18 mul, 1 sqrt."""
    s1 = r1 * r1
    h2 = 0.5 * (s1 - r2 * r2) + sd.q2
    h3 = 0.5 * (s1 - r3 * r3) + sd.q3
    x0 = h2 * sd.p1 + h3 * sd.p2
    y0 = h2 * sd.s1 + h3 * sd.s2
    qb = x0 * sd.wx + y0 * sd.wy
    qc = x0 * x0 + y0 * y0 - s1
    disc = qb * qb - qc / sd.inv_a
    if disc < 0.0:
        if not _is_tangent(r1, r2, r3, -disc * sd.inv_a):
            _raise_unreachable(sd.tri, sd.centres, (r1, r2, r3), -disc * sd.inv_a)
        disc = 0.0 * disc
    sq = _sqrt(disc)
    if qb > 0.0:
        s = -(qb + sq) * sd.inv_a
    else:
        den = sq - qb
        s = qc / den if den != 0.0 else 0.0 * qb
    return (sd.x1 + x0 + sd.wx * s, sd.y1 + y0 + sd.wy * s, sd.z1 + s)


def _normal_eq(
    anchors: tuple[Vec3, ...], lengths: Sequence[float], x: float, y: float, z: float
) -> tuple[float, float, float, float, float, float, float, float, float, float]:
    """Sum of squared residuals, J^T J (6 entries) and J^T r at (x, y, z)."""
    a11 = a12 = a13 = a22 = a23 = a33 = g1 = g2 = g3 = cost = 0.0
    for (ax, ay, az), ln in zip(anchors, lengths, strict=True):
        dx = x - ax
        dy = y - ay
        dz = z - az
        d = _sqrt(dx * dx + dy * dy + dz * dz)
        res = d - ln
        cost += res * res
        t = 1.0 / d if d > 0.0 else 0.0
        ux = dx * t
        uy = dy * t
        uz = dz * t
        a11 += ux * ux
        a12 += ux * uy
        a13 += ux * uz
        a22 += uy * uy
        a23 += uy * uz
        a33 += uz * uz
        g1 += ux * res
        g2 += uy * res
        g3 += uz * res
    return cost, a11, a12, a13, a22, a23, a33, g1, g2, g3


def _gauss_newton(
    anchors: tuple[Vec3, ...],
    lengths: Sequence[float],
    x: float,
    y: float,
    z: float,
    z_mirror: float | None,
    start: tuple[float, float, float, float, float, float, float, float, float, float]
    | None = None,
) -> tuple[float, float, float, float]:
    """Least-squares refinement over all cables from (x, y, z); returns x, y, z, RMS residual.

    Minimises sum (|P - B_i| - L_i)^2 with Gauss-Newton, the 3x3 normal equations solved in
    closed form, the step halved until the cost does not increase (near the anchor plane the
    problem is ill-conditioned in z and a full step can overshoot).  Stops when the step is
    below ``GN_STEP_TOL_M``, or is under 1 um with the next one predicted below 1e-10 m
    (``GN_NEXT_TOL2``).  With all anchors at height ``z_mirror`` the cost is symmetric about
    that plane, and a point above it is mirrored back to the lower solution.  ``start`` is
    ``_normal_eq`` at (x, y, z) when the caller has it.
    """
    n = len(anchors)
    if start is None:
        start = _normal_eq(anchors, lengths, x, y, z)
    cost, a11, a12, a13, a22, a23, a33, g1, g2, g3 = start
    prev2 = math.inf
    tol2 = GN_STEP_TOL_M * GN_STEP_TOL_M
    for _ in range(GN_MAX_ITER):
        c11 = a22 * a33 - a23 * a23
        c12 = a13 * a23 - a12 * a33
        c13 = a12 * a23 - a13 * a22
        det = a11 * c11 + a12 * c12 + a13 * c13
        if not det > GN_DET_MIN:  # cables (nearly) coplanar with P: keep the estimate
            break
        c22 = a11 * a33 - a13 * a13
        c23 = a12 * a13 - a11 * a23
        c33 = a11 * a22 - a12 * a12
        inv = 1.0 / det
        sx = (c11 * g1 + c12 * g2 + c13 * g3) * inv
        sy = (c12 * g1 + c22 * g2 + c23 * g3) * inv
        sz = (c13 * g1 + c23 * g2 + c33 * g3) * inv
        step2 = sx * sx + sy * sy + sz * sz
        if step2 < 1e-12 and (step2 <= tol2 or step2 * step2 < GN_NEXT_TOL2 * prev2):
            # Converged: take this last small step without evaluating again. The cost at the
            # new point is the Gauss-Newton model's |r - J s|^2 = cost - g.s (exact to second
            # order in a sub-micrometre step), so the residual belongs to the returned point.
            x, y, z = x - sx, y - sy, z - sz
            cost = max(0.0, cost - (g1 * sx + g2 * sy + g3 * sz))
            if z_mirror is not None and z > z_mirror:
                z = 2.0 * z_mirror - z
            break
        prev2 = step2
        allowed = cost + (GN_COST_REL_TOL * cost + GN_COST_ROUND_M * _sqrt(cost))
        for _halving in range(GN_MAX_HALVINGS):
            tx, ty, tz = x - sx, y - sy, z - sz
            if z_mirror is not None and tz > z_mirror:
                tz = 2.0 * z_mirror - tz
            trial = _normal_eq(anchors, lengths, tx, ty, tz)
            if trial[0] <= allowed:
                break
            sx, sy, sz = 0.5 * sx, 0.5 * sy, 0.5 * sz
        else:
            break  # no decrease along the step: at the minimum to rounding
        x, y, z = tx, ty, tz
        cost, a11, a12, a13, a22, a23, a33, g1, g2, g3 = trial
    return x, y, z, _sqrt(cost / n)


def _others_scalar(
    anchors: tuple[Vec3, ...], lo: Sequence[float], x: float, y: float, z: float
) -> tuple[list[float], list[float], float, float]:
    """Distances and residuals of the cables outside the seed triple; their sum and max of
    squared residuals."""
    ds: list[float] = []
    fs: list[float] = []
    sumsq = worst = 0.0
    for (ax, ay, az), ln in zip(anchors, lo, strict=True):
        dx = x - ax
        dy = y - ay
        dz = z - az
        d = _sqrt(dx * dx + dy * dy + dz * dz)
        res = d - ln
        ds.append(d)
        fs.append(res)
        sq = res * res
        sumsq += sq
        if sq > worst:
            worst = sq
    return ds, fs, sumsq, worst


def _fit_planar4(
    p4: _Planar4, sd: _EqualSeed, lengths: Sequence[float], k4: int, cost0: float
) -> tuple[float, float, float, float] | None:
    """The fit for four anchors at one height (see ``_Planar4``); None when it cannot vouch
    for the result (multiplier near a pole, Newton not converged, the fitted lengths' spheres
    missing each other, or a cost above the seed's ``cost0``)."""
    l1, l2, l3, l4 = lengths[sd.i1], lengths[sd.i2], lengths[sd.i3], lengths[k4]
    c1, c2, c3 = p4.c
    a1, a2, a3 = c1 * l1 * l1, c2 * l2 * l2, c3 * l3 * l3
    t = l4 * l4
    lam = (a1 + a2 + a3 + p4.m0 - t) / (2.0 * (c1 * a1 + c2 * a2 + c3 * a3 + t))
    w1, w2, w3 = 1.0 / (1.0 + lam * c1), 1.0 / (1.0 + lam * c2), 1.0 / (1.0 + lam * c3)
    v = 1.0 / (1.0 - lam)
    b1, b2, b3 = a1 * w1 * w1, a2 * w2 * w2, a3 * w3 * w3
    tv = t * v * v
    step = (b1 + b2 + b3 + p4.m0 - tv) / (
        2.0 * (c1 * b1 * w1 + c2 * b2 * w2 + c3 * b3 * w3 + tv * v)
    )
    lam += step
    big = max(l1, l2, l3, l4)
    if not (abs(lam) * p4.curv <= 0.75 and big * p4.curv * step * step <= GN_STEP_TOL_M):
        return None
    q1, q2, q3 = l1 / (1.0 + lam * c1), l2 / (1.0 + lam * c2), l3 / (1.0 + lam * c3)
    d = l4 / (1.0 - lam)
    try:
        x, y, z = _seed_equal(sd, q1, q2, q3)
    except UnreachableError:
        return None
    cost = lam * lam * (c1 * c1 * q1 * q1 + c2 * c2 * q2 * q2 + c3 * c3 * q3 * q3 + d * d)
    if not cost <= cost0 + (GN_COST_REL_TOL * cost0 + GN_COST_ROUND_M * _sqrt(cost0)):
        return None
    return x, y, z, _sqrt(cost * 0.25)


def _mirror(tilt: tuple[Vec3, Vec3], x: float, y: float, z: float) -> Vec3:
    """(x, y, z) reflected in the plane of ``tilt`` (unit normal, point)."""
    (nx, ny, nz), (cx, cy, cz) = tilt
    t = 2.0 * ((x - cx) * nx + (y - cy) * ny + (z - cz) * nz)
    return x - t * nx, y - t * ny, z - t * nz


def _fit_scalar(
    geom: Geometry, lengths: Sequence[float], x: float, y: float, z: float
) -> tuple[float, float, float, float]:
    """Least-squares fit over all cables from the seed (x, y, z); returns x, y, z, RMS residual.

    Gauss-Newton in cable-length space: the unknowns are the residuals s of the three seed
    cables, P(s) the three-spheres point for their lengths L + s, and the other cables'
    residuals f_j(s) = |P(s) - B_j| - L_j; the cost |s|^2 + sum f_j^2 is the usual sum of
    squared length mismatches.  The three seed cables' residuals are linear in s, so only
    the N - 3 others are linearised (gradient k_j, see ``_Fit``), and each step lands exactly
    on the three spheres: from the seed this converges to 1e-10 m in two steps where
    Gauss-Newton in P needs three or four.  One step is, for N = 4,
    s' = k (k . s - f) / (1 + |k|^2) (Sherman-Morrison), else the 3x3 normal equations.
    Stops like ``_gauss_newton``.  When a step would raise the cost, leaves the three spheres'
    domain or P is within 1 um of the seed triple's plane (unequal heights), it returns
    ``_gauss_newton`` from the seed instead (step halving, robust near the anchor plane).
    """
    fit = geom._fit
    sd = geom._seed
    n = geom.n_cables
    lo = [lengths[j] for j in fit.others]
    ds, fs, cost, worst = _others_scalar(fit.anchors, lo, x, y, z)
    tol2 = GN_STEP_TOL_M * GN_STEP_TOL_M
    if worst <= tol2:  # consistent lengths (the usual case): the seed is the fit
        return x, y, z, _sqrt(cost / n)
    if geom._p4 is not None and isinstance(sd, _EqualSeed):
        done = _fit_planar4(geom._p4, sd, lengths, fit.others[0], cost)
        if done is not None:
            return done
    if fit.tilt is not None:
        mx, my, mz = _mirror(fit.tilt, x, y, z)
        # Only a mirror image below every anchor is a place the robot can hang (above them,
        # with noisy lengths on a poorly conditioned layout, it can even fit better).
        if mz < geom.anchor_height_min_m and _others_scalar(fit.anchors, lo, mx, my, mz)[2] < cost:
            # The other cables side with the mirror image: fit from there, in P.
            return _gauss_newton(geom._anchors_t, lengths, mx, my, mz, None)
    l1, l2, l3 = lengths[sd.i1], lengths[sd.i2], lengths[sd.i3]
    x0, y0, z0 = x, y, z
    s1 = s2 = s3 = 0.0
    prev2 = math.inf
    ax0, ay0, az0, b0 = fit.den
    for it in range(GN_MAX_ITER):
        p1, p2, p3 = l1 + s1, l2 + s2, l3 + s3
        inv_den = 0.0
        if fit.general:
            den = ax0 * x + ay0 * y + az0 * z + b0
            if not abs(den) > fit.den_min:
                break
            inv_den = 1.0 / den
        # Gradients k_j of the other cables' lengths, and the step's normal equations
        # (I + sum k k^T) s' = sum k (k . s - f).
        m11 = m22 = m33 = 1.0
        m12 = m13 = m23 = r1 = r2 = r3 = 0.0
        k1 = k2 = k3 = g = 0.0
        for d, f, bary, num in zip(ds, fs, fit.bary, fit.num, strict=True):
            t = 1.0 / d
            if bary is not None:
                k1, k2, k3 = bary[0] * t * p1, bary[1] * t * p2, bary[2] * t * p3
            else:
                assert num is not None
                t *= inv_den
                (a1, b1, c1, e1), (a2, b2, c2, e2), (a3, b3, c3, e3) = num
                k1 = (a1 * x + b1 * y + c1 * z + e1) * t * p1
                k2 = (a2 * x + b2 * y + c2 * z + e2) * t * p2
                k3 = (a3 * x + b3 * y + c3 * z + e3) * t * p3
            g = k1 * s1 + k2 * s2 + k3 * s3 - f
            m11 += k1 * k1
            m12 += k1 * k2
            m13 += k1 * k3
            m22 += k2 * k2
            m23 += k2 * k3
            m33 += k3 * k3
            r1 += k1 * g
            r2 += k2 * g
            r3 += k3 * g
        if len(ds) == 1:  # Sherman-Morrison: s' = k g / (1 + |k|^2)
            c = g / (m11 + m22 + m33 - 2.0)
            t1, t2, t3 = k1 * c, k2 * c, k3 * c
        else:
            c11 = m22 * m33 - m23 * m23
            c12 = m13 * m23 - m12 * m33
            c13 = m12 * m23 - m13 * m22
            c22 = m11 * m33 - m13 * m13
            c23 = m12 * m13 - m11 * m23
            c33 = m11 * m22 - m12 * m12
            inv = 1.0 / (m11 * c11 + m12 * c12 + m13 * c13)  # det >= 1: I + a PSD matrix
            t1 = (c11 * r1 + c12 * r2 + c13 * r3) * inv
            t2 = (c12 * r1 + c22 * r2 + c23 * r3) * inv
            t3 = (c13 * r1 + c23 * r2 + c33 * r3) * inv
        try:
            if isinstance(sd, _EqualSeed):
                nx, ny, nz = _seed_equal(sd, l1 + t1, l2 + t2, l3 + t3)
            else:
                nx, ny, nz = _seed_general(sd, l1 + t1, l2 + t2, l3 + t3)
        except UnreachableError:
            break
        ds, fs, fsq, _ = _others_scalar(fit.anchors, lo, nx, ny, nz)
        new_cost = t1 * t1 + t2 * t2 + t3 * t3 + fsq
        if not new_cost <= cost + (GN_COST_REL_TOL * cost + GN_COST_ROUND_M * _sqrt(cost)):
            break
        step2 = (nx - x) * (nx - x) + (ny - y) * (ny - y) + (nz - z) * (nz - z)
        x, y, z, s1, s2, s3, cost = nx, ny, nz, t1, t2, t3, new_cost
        # Always two steps (the batch takes them on whole chunks without a test between).
        if it and (step2 <= tol2 or (step2 < 1e-12 and step2 * step2 < GN_NEXT_TOL2 * prev2)):
            return x, y, z, _sqrt(cost / n)
        prev2 = step2
    mirror = sd.zn if geom.equal_heights and isinstance(sd, _EqualSeed) else None
    return _gauss_newton(geom._anchors_t, lengths, x0, y0, z0, mirror)


def _fpk_one(geom: Geometry, lengths: Sequence[float]) -> FpkResult:
    sd = geom._seed
    n = geom.n_cables
    if len(lengths) != n:
        raise KinematicsError(f"expected {n} cable lengths, got {len(lengths)}")
    total = sum(lengths)
    # total - total is NaN for any NaN or inf; the loop only runs to name the culprit.
    if not (min(lengths) > 0.0 and total - total == 0.0):
        for k, ln in enumerate(lengths):
            if not (0.0 < ln < math.inf):
                raise KinematicsError(f"cable {k + 1} length must be finite and > 0, got {ln!r}")
    r1, r2, r3 = lengths[sd.i1], lengths[sd.i2], lengths[sd.i3]
    if isinstance(sd, _EqualSeed):
        x, y, z = _seed_equal(sd, r1, r2, r3)
    else:
        x, y, z = _seed_general(sd, r1, r2, r3)
    tri = geom.seed_triple
    if n == 3:
        return FpkResult((x, y, z), 0.0, tri)
    x, y, z, rms = _fit_scalar(geom, lengths, x, y, z)
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z) and math.isfinite(rms)):
        raise KinematicsError("FPK produced a non-finite result")  # defensive, not expected
    return FpkResult((x, y, z), rms, tri)


@overload
def fpk(geom: Geometry, lengths_m: Sequence[float]) -> FpkResult: ...
@overload
def fpk(geom: Geometry, lengths_m: FloatArray) -> FpkResult | FpkBatchResult: ...


def fpk(geom: Geometry, lengths_m: Sequence[float] | FloatArray) -> FpkResult | FpkBatchResult:
    """Forward pose kinematics: the point P where the cables meet.

    ``lengths_m`` of shape (N,) gives an ``FpkResult``; shape (M, N) dispatches to
    ``fpk_batch``.  The seed is the geometry's ``seed_triple`` solved with the simplified
    algorithm when its anchors share a height, the general one otherwise; for N > 3 the
    least-squares fit over all cables follows (see the module docstring; skipped when the
    other cables already agree to 1e-12 m).  ``residual_m`` is the RMS cable-length mismatch.
    Raises ``KinematicsError`` for a wrong count or non-finite / non-positive lengths and
    ``UnreachableError`` (naming the 1-based cable and shortfall) when the seed triple
    cannot meet.
    """
    if isinstance(lengths_m, np.ndarray):
        if lengths_m.ndim == 2:
            return fpk_batch(geom, lengths_m)
        if lengths_m.ndim != 1:
            raise KinematicsError(f"lengths must have shape (N,) or (M, N), got {lengths_m.shape}")
        return _fpk_one(geom, lengths_m.tolist())
    return _fpk_one(geom, list(map(float, lengths_m)))


def fpk_batch(geom: Geometry, lengths_m: Any) -> FpkBatchResult:
    """Vectorised FPK of M poses from an (M, N) array of lengths; never raises per row.

    Rows with non-finite or non-positive lengths, or whose seed triple cannot meet, get
    ``valid`` False, position and residual 0 (never NaN).  Raises ``KinematicsError`` only
    for a wrong shape.
    """
    lens = np.asarray(lengths_m, dtype=np.float64)
    n = geom.n_cables
    if lens.ndim != 2 or lens.shape[1] != n:
        raise KinematicsError(f"lengths must have shape (M, {n}), got {lens.shape}")
    return _fpk_batch(geom, lens)


def _fpk_batch(geom: Geometry, lens: FloatArray) -> FpkBatchResult:
    # Memory traffic is the cost of a batch, so rows are processed in chunks that stay in
    # cache, each with in-place operations on a few buffers; positions live in a (3, M)
    # array returned as its (M, 3) transpose.
    m = lens.shape[0]
    xyz = np.empty((3, m), dtype=np.float64)
    residual = np.zeros(m, dtype=np.float64)
    ok = np.ones(m, dtype=bool)
    short_cable = np.zeros(m, dtype=np.int64)
    shortfall = np.zeros(m, dtype=np.float64)
    work: dict[int, _Work] = {}
    with np.errstate(all="ignore"):
        # One check on the whole array; per-row checks only where it fails.
        checked = bool(lens.min(initial=np.inf) > 0.0) and math.isfinite(float(lens.sum()))
        for s in range(0, m, BATCH_CHUNK):
            e = min(m, s + BATCH_CHUNK)
            args = (lens[s:e], xyz[:, s:e], residual[s:e], ok[s:e], short_cable[s:e])
            if geom._p4 is not None:
                if e - s not in work:
                    work[e - s] = _Work(e - s)
                _fpk_chunk_p4(geom, geom._p4, *args, shortfall[s:e], checked, work[e - s])
            else:
                _fpk_chunk(geom, *args, shortfall[s:e], checked)
    return FpkBatchResult(xyz.T, residual, ok, geom.seed_triple, short_cable, shortfall)


class _Work:
    """Preallocated buffers of ``_fpk_chunk_p4`` for chunks of m rows.

    (A fresh array per operation would double the cost of the cheap ones.)
    """

    __slots__ = (
        "act",
        "d",
        "idle",
        "lam",
        "q",
        "qq",
        "r",
        "rp",
        "sq",
        "t1",
        "t2",
        "t3",
        "t4",
        "zeros",
    )

    def __init__(self, m: int) -> None:
        self.sq = np.empty((m, 4), dtype=np.float64)  # squared lengths, row-major like the input
        self.r = np.empty((12, m), dtype=np.float64)  # the rows of _Planar4.series
        self.q = np.empty((3, m), dtype=np.float64)  # fitted lengths of the seed cables
        self.qq = np.empty((3, m), dtype=np.float64)  # their squares
        self.rp = np.empty((3, m), dtype=np.float64)  # X, Y, A of the fitted point
        self.lam, self.d, self.t1, self.t2, self.t3, self.t4 = (
            np.empty(m, dtype=np.float64) for _ in range(6)
        )
        self.zeros = np.zeros(m, dtype=np.float64)
        self.act = np.empty(m, dtype=bool)  # rows needing a fit
        self.idle = np.empty(m, dtype=bool)  # the others


def _fpk_chunk(
    geom: Geometry,
    lens: FloatArray,
    xyz: FloatArray,
    residual: FloatArray,
    ok: npt.NDArray[np.bool_],
    short_cable: npt.NDArray[np.int64],
    shortfall: FloatArray,
    checked: bool,
) -> None:
    """FPK of one chunk of rows, written into the given output views."""
    n = lens.shape[1]
    sd = geom._seed
    cols = lens.T.copy()  # (n, m), contiguous rows: one per cable
    if not checked:
        for c in cols:
            ok &= c > 0.0  # also False for NaN
            ok &= c < np.inf
    c1, c2, c3 = cols[sd.i1], cols[sd.i2], cols[sd.i3]
    x, y, z = xyz[0], xyz[1], xyz[2]
    power = _seed_cols(sd, c1, c2, c3, x, y, z)

    bad = power > 0.0
    bad &= ok
    if bad.any():
        _mark_unreachable(sd, lens, np.nonzero(bad)[0], power, ok, short_cable, shortfall)
    if n > 3:
        _refine_chunk(geom, cols, lens, x, y, z, ok, residual)
    _zero_invalid(xyz, residual, ok, short_cable, shortfall)


def _mark_unreachable(
    sd: _EqualSeed | _GeneralSeed,
    lens: FloatArray,
    idx: npt.NDArray[np.intp],
    power: FloatArray,
    ok: npt.NDArray[np.bool_],
    short_cable: npt.NDArray[np.int64],
    shortfall: FloatArray,
) -> None:
    """Rows ``idx`` whose seed spheres miss (power > 0): invalid, with the cable to blame,
    unless the miss is only a tangent."""
    trio = lens[idx][:, list(sd.tri)]
    rmin = np.min(np.abs(trio), axis=1)
    real = np.sqrt(rmin * rmin + power[idx]) - rmin > TANGENT_TOL_M
    idx, trio = idx[real], trio[real]
    ok[idx] = False
    k, change = _diagnose_batch(sd.centres, trio, power[idx])
    short_cable[idx] = np.asarray(sd.tri, dtype=np.int64)[k - 1] + 1
    shortfall[idx] = change


def _zero_invalid(
    xyz: FloatArray,
    residual: FloatArray,
    ok: npt.NDArray[np.bool_],
    short_cable: npt.NDArray[np.int64],
    shortfall: FloatArray,
) -> None:
    """Rows with a non-finite result become invalid; invalid rows hold zeros, valid rows no
    diagnosis."""
    buf = np.add(xyz[0], xyz[1])
    buf += xyz[2]
    buf += residual
    ok &= np.isfinite(buf)
    if not ok.all():
        bad = ~ok
        xyz[:, bad] = 0.0
        residual[bad] = 0.0
        short_cable[ok] = 0
        shortfall[ok] = 0.0


def _fpk_chunk_p4(
    geom: Geometry,
    p4: _Planar4,
    lens: FloatArray,
    xyz: FloatArray,
    residual: FloatArray,
    ok: npt.NDArray[np.bool_],
    short_cable: npt.NDArray[np.int64],
    shortfall: FloatArray,
    checked: bool,
    w: _Work,
) -> None:
    """``_fpk_chunk`` for four anchors at one height: ``_fit_planar4``, vectorised.

    One matrix product on the squared lengths (read in place, row-major) gives the seed's
    X, Y, Q1, L4^2 and the Taylor coefficients of phi and phi' in lam, which are exact to
    rounding for |lam| <= ``lam_max`` (the next term is below 1e-13 of phi's scale);
    lam_1 = -r0 / r1, then one Newton step on the series.  The fitted lengths' point comes
    from a second product.  Rows ``_fit_planar4`` would give up on (and rows beyond
    ``lam_max``: cables disagreeing by centimetres) are finished by ``_fit_scalar``.
    """
    x, y, z = xyz[0], xyz[1], xyz[2]
    t1, t2, t3, act = w.t1, w.t2, w.t3, w.act
    if not checked:
        for c in lens.T:
            ok &= c > 0.0  # also False for NaN
            ok &= c < np.inf
    np.multiply(lens, lens, out=w.sq)
    r = np.matmul(p4.series, w.sq.T, out=w.r)
    bx, by, b0 = p4.series_bias
    r[0] += bx
    r[1] += by
    r[4] += b0
    sx, sy, q1, tt, r0, r1, r2, r3, r4, p1, p2, p3 = r
    # Seeds whose spheres miss (power = X^2 + Y^2 - Q1 > 0) beyond a tangent: invalid rows.
    power = np.multiply(sx, sx, out=t2)
    power += np.multiply(sy, sy, out=t3)
    power -= q1
    bad = power > 0.0
    bad &= ok
    if bad.any():
        _mark_unreachable(geom._seed, lens, np.nonzero(bad)[0], power, ok, short_cable, shortfall)
    # The seed's fourth cable: D2 = r0 + T.
    np.add(r0, tt, out=t1)
    np.sqrt(t1, out=t1)
    l4 = lens[:, p4.k4]
    t1 -= l4  # f at the seed
    root = np.abs(t1, out=t1)  # sqrt of the seed's cost
    np.greater(root, GN_STEP_TOL_M, out=act)
    act &= ok
    if not act.any():  # consistent lengths: the seed is the fit
        np.negative(power, out=z)
        np.maximum(z, w.zeros, out=z)
        np.sqrt(z, out=z)
        np.subtract(p4.zn, z, out=z)
        np.add(sx, p4.x1, out=x)
        np.add(sy, p4.y1, out=y)
        np.multiply(root, 0.5, out=residual)
        _zero_invalid(xyz, residual, ok, short_cable, shortfall)
        return
    # lam_1 = -r0 / r1, then a Newton step: phi(lam_1) = lam_1^2 (r2 + lam_1 (r3 + lam_1 r4)).
    lam = np.divide(r0, r1, out=w.lam)
    np.negative(lam, out=lam)
    lam *= act  # rows needing no fit (or unusable) keep lam = 0: the seed
    np.multiply(r4, lam, out=t2)
    t2 += r3
    t2 *= lam
    t2 += r2
    t2 *= lam
    t2 *= lam  # phi(lam_1)
    np.multiply(p3, lam, out=t3)
    t3 += p2
    t3 *= lam
    t3 += p1
    t3 *= lam
    t3 += r1  # phi'(lam_1)
    step = np.divide(t2, t3, out=t2)
    lam -= step
    big = float(lens.max(initial=0.0))
    np.multiply(step, step, out=t3)
    slow = t3 > GN_STEP_TOL_M / (big * p4.curv)
    slow |= np.abs(lam, out=t3) > p4.lam_max
    # The fitted lengths q_i = L_i / (1 + lam c_i) and their point.
    q = w.q
    for i, (col, ci) in enumerate(zip(p4.tri, p4.c, strict=True)):
        np.multiply(lam, ci, out=q[i])
        q[i] += 1.0
        np.divide(lens[:, col], q[i], out=q[i])
    np.multiply(q, q, out=w.qq)
    rp = np.matmul(p4.point, w.qq, out=w.rp)
    rp[0] += bx
    rp[1] += by
    px, py, aa = rp
    disc = np.multiply(px, px, out=t3)
    np.subtract(w.qq[0], disc, out=disc)
    disc -= np.multiply(py, py, out=z)
    np.maximum(disc, w.zeros, out=z)  # an array of zeros: 5x faster than the scalar 0.0
    np.sqrt(z, out=z)
    np.subtract(p4.zn, z, out=z)
    np.add(px, p4.x1, out=x)
    np.add(py, p4.y1, out=y)
    # cost = lam^2 (A + d^2) with d = L4 / (1 - lam); rows at the seed keep f^2.
    cost = np.subtract(1.0, lam, out=w.d)
    np.divide(l4, cost, out=cost)
    cost *= cost
    cost += aa
    cost *= lam
    cost *= lam
    seed_cost = np.multiply(root, root, out=t2)
    np.logical_not(act, out=w.idle)
    cost += np.multiply(seed_cost, w.idle, out=w.t4)
    np.multiply(cost, 0.25, out=residual)
    np.sqrt(residual, out=residual)
    # The cost may not exceed the seed's (beyond rounding).
    seed_cost *= 1.0 + GN_COST_REL_TOL
    seed_cost += np.multiply(root, GN_COST_ROUND_M, out=w.t4)
    slow |= ~(cost <= seed_cost)  # also NaN
    miss = disc < 0.0
    miss &= act
    if miss.any():  # the fitted lengths' spheres miss, beyond a tangent: the scalar fit
        rows = np.nonzero(miss)[0]
        rmin = np.min(np.abs(q[:, rows]), axis=0)  # as _is_tangent
        slow[rows[np.sqrt(rmin * rmin - disc[rows]) - rmin > TANGENT_TOL_M]] = True
    slow &= act
    if slow.any():
        _finish_slow(geom, lens, x, y, z, residual, [np.nonzero(slow)[0]])
    _zero_invalid(xyz, residual, ok, short_cable, shortfall)


def _finish_slow(
    geom: Geometry,
    lens: FloatArray,
    x: FloatArray,
    y: FloatArray,
    z: FloatArray,
    residual: FloatArray,
    slow: list[npt.NDArray[np.intp]],
) -> None:
    """Rows the vectorised steps gave up on: ``_fit_scalar`` from the seed, one by one."""
    for rows in slow:
        for r in rows.tolist():
            sx, sy, sz = _seed_row(geom, lens[r])
            x[r], y[r], z[r], residual[r] = _fit_scalar(geom, lens[r].tolist(), sx, sy, sz)


def _diagnose_batch(
    cs: tuple[Vec3, Vec3, Vec3], rs: FloatArray, power: FloatArray
) -> tuple[npt.NDArray[np.int64], FloatArray]:
    """Vectorised ``_diagnose`` over K rows of three lengths: (1-based k, change) per row."""
    kk = rs.shape[0]
    best = np.full(kk, np.inf)
    best_k = np.zeros(kk, dtype=np.int64)
    best_change = np.zeros(kk)
    c = np.asarray(cs, dtype=np.float64)
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        v = c[j] - c[i]
        d = float(np.sqrt(v @ v))
        nv = v / d
        ri, rj, rk = rs[:, i], rs[:, j], rs[:, k]
        a = (d * d + ri * ri - rj * rj) / (2.0 * d)
        rho2 = ri * ri - a * a
        rho = np.sqrt(np.maximum(rho2, 0.0))
        w = (c[k] - c[i])[None, :] - a[:, None] * nv[None, :]
        wn = w @ nv
        wp = np.sqrt(np.maximum(np.einsum("ij,ij->i", w, w) - wn * wn, 0.0))
        lo, hi = np.hypot(wn, wp - rho), np.hypot(wn, wp + rho)
        change = np.where(rk < lo, lo - rk, np.where(rk > hi, hi - rk, 0.0))
        better = (rho2 >= 0.0) & (np.abs(change) < best)
        best = np.where(better, np.abs(change), best)
        best_k = np.where(better, k + 1, best_k)
        best_change = np.where(better, change, best_change)
    fallback = (best_k == 0) | (best_change == 0.0)
    if np.any(fallback):
        kmin = np.argmin(np.abs(rs), axis=1)
        rmin = np.abs(rs[np.arange(kk), kmin])
        best_k = np.where(fallback, kmin + 1, best_k)
        best_change = np.where(fallback, np.sqrt(rmin * rmin + power) - rmin, best_change)
    return best_k, best_change


def _seed_cols(
    sd: _EqualSeed | _GeneralSeed,
    c1: FloatArray,
    c2: FloatArray,
    c3: FloatArray,
    x: FloatArray,
    y: FloatArray,
    z: FloatArray,
) -> FloatArray:
    """Vectorised seed (``_seed_equal`` / ``_seed_general``) into x, y, z; returns the power.

    The power of the radical line is > 0 where the three spheres miss each other (the
    discriminant, clamped to 0 for the point, is its negative).
    """
    m = x.shape[0]
    buf_a = np.multiply(c1, c1)  # r1^2
    buf_b = np.empty(m, dtype=np.float64)
    if isinstance(sd, _EqualSeed):
        np.multiply(c3, c3, out=buf_b)  # r3^2
        np.subtract(buf_a, buf_b, out=z)  # u = r1^2 - r3^2
        np.multiply(c2, c2, out=y)
        np.subtract(y, buf_b, out=buf_b)  # v = r2^2 - r3^2
        np.multiply(z, sd.e1, out=x)
        x += np.multiply(buf_b, sd.e2, out=y)
        x += sd.dx0  # dx
        np.multiply(z, sd.f1, out=y)
        y += np.multiply(buf_b, sd.f2, out=z)
        y += sd.dy0  # dy
        buf_a -= np.multiply(x, x, out=z)
        buf_a -= np.multiply(y, y, out=z)  # disc = r1^2 - dx^2 - dy^2
        x += sd.x1
        y += sd.y1
        np.negative(buf_a, out=buf_b)  # power of the radical line
        np.maximum(buf_a, 0.0, out=buf_a)
        np.sqrt(buf_a, out=buf_a)
        np.subtract(sd.zn, buf_a, out=z)
        return buf_b
    h2 = buf_a - c2 * c2
    h2 *= 0.5
    h2 += sd.q2
    h3 = buf_a - c3 * c3
    h3 *= 0.5
    h3 += sd.q3
    x0 = h2 * sd.p1 + h3 * sd.p2
    y0 = h2 * sd.s1 + h3 * sd.s2
    qb = x0 * sd.wx + y0 * sd.wy
    qc = x0 * x0 + y0 * y0 - buf_a
    disc = qb * qb - qc / sd.inv_a
    power: FloatArray = -disc * sd.inv_a
    sq = np.sqrt(np.maximum(disc, 0.0))
    den = sq - qb
    z[:] = np.where(
        qb > 0.0,
        -(qb + sq) * sd.inv_a,
        np.where(den != 0.0, qc / np.where(den != 0.0, den, 1.0), 0.0),
    )
    np.add(sd.x1 + x0, sd.wx * z, out=x)
    np.add(sd.y1 + y0, sd.wy * z, out=y)
    z += sd.z1
    return power


def _others_cols(
    anchors: tuple[Vec3, ...], lo: list[FloatArray], x: FloatArray, y: FloatArray, z: FloatArray
) -> tuple[list[FloatArray], list[FloatArray], FloatArray]:
    """Vectorised ``_others_scalar``: distances, residuals and sum of squared residuals."""
    ds: list[FloatArray] = []
    fs: list[FloatArray] = []
    tmp = np.empty_like(x)
    cost = np.zeros_like(x)
    for (ax, ay, az), ln in zip(anchors, lo, strict=True):
        d = np.subtract(x, ax)
        d *= d
        np.subtract(y, ay, out=tmp)
        tmp *= tmp
        d += tmp
        np.subtract(z, az, out=tmp)
        tmp *= tmp
        d += tmp
        np.sqrt(d, out=d)
        f = np.subtract(d, ln)
        cost += np.multiply(f, f, out=tmp)
        ds.append(d)
        fs.append(f)
    return ds, fs, cost


def _lin(c: tuple[float, float, float, float], x: FloatArray, y: FloatArray, z: FloatArray) -> Any:
    """c . (x, y, z, 1), vectorised, skipping zero coefficients."""
    out = np.full_like(x, c[3])
    for k, v in zip(c[:3], (x, y, z), strict=True):
        if k != 0.0:
            out += k * v
    return out


def _step_cols(
    geom: Geometry,
    lt: tuple[FloatArray, FloatArray, FloatArray],
    lo: list[FloatArray],
    s: tuple[FloatArray, FloatArray, FloatArray] | None,
    px: FloatArray,
    py: FloatArray,
    pz: FloatArray,
    ds: list[FloatArray],
    fs: list[FloatArray],
) -> tuple[Any, ...]:
    """One vectorised step of ``_fit_scalar`` from s (None: the seed, s = 0) at P.

    Returns the new s (3 arrays), the new point (3 arrays), the power of its three spheres,
    the other cables' distances and residuals there, the new cost and a mask of rows whose
    gradient could not be formed (P in the seed triple's plane; None when never).
    """
    fit = geom._fit
    if s is None:
        p1, p2, p3 = lt
    else:
        p1, p2, p3 = lt[0] + s[0], lt[1] + s[1], lt[2] + s[2]
    den_bad = None
    inv_den: Any = None
    if fit.general:
        den = _lin(fit.den, px, py, pz)
        den_bad = ~(np.abs(den) > fit.den_min)
        inv_den = np.reciprocal(den)
    one = len(fs) == 1
    mm: list[Any] = [1.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0]  # m11 m12 m13 m22 m23 m33 r1-3
    t1: Any = None
    t2: Any = None
    t3: Any = None
    for d, f, bary, num in zip(ds, fs, fit.bary, fit.num, strict=True):
        t = np.reciprocal(d)
        if bary is not None:
            k1 = np.multiply(t, bary[0])
            k1 *= p1
            k2 = np.multiply(t, bary[1])
            k2 *= p2
            k3 = np.multiply(t, bary[2])
            k3 *= p3
        else:
            assert num is not None
            t *= inv_den
            k1 = _lin(num[0], px, py, pz)
            k1 *= t
            k1 *= p1
            k2 = _lin(num[1], px, py, pz)
            k2 *= t
            k2 *= p2
            k3 = _lin(num[2], px, py, pz)
            k3 *= t
            k3 *= p3
        if s is None:
            g = np.negative(f)
        else:
            g = k1 * s[0]
            g += k2 * s[1]
            g += k3 * s[2]
            g -= f
        if one:  # Sherman-Morrison: s' = k g / (1 + |k|^2)
            q = np.multiply(k1, k1)
            q += k2 * k2
            q += k3 * k3
            q += 1.0
            np.divide(g, q, out=g)
            k1 *= g
            k2 *= g
            k3 *= g
            t1, t2, t3 = k1, k2, k3
        else:
            mm[0] = mm[0] + k1 * k1
            mm[1] = mm[1] + k1 * k2
            mm[2] = mm[2] + k1 * k3
            mm[3] = mm[3] + k2 * k2
            mm[4] = mm[4] + k2 * k3
            mm[5] = mm[5] + k3 * k3
            mm[6] = mm[6] + k1 * g
            mm[7] = mm[7] + k2 * g
            mm[8] = mm[8] + k3 * g
    if not one:
        m11, m12, m13, m22, m23, m33, r1, r2, r3 = mm
        c11 = m22 * m33 - m23 * m23
        c12 = m13 * m23 - m12 * m33
        c13 = m12 * m23 - m13 * m22
        c22 = m11 * m33 - m13 * m13
        c23 = m12 * m13 - m11 * m23
        c33 = m11 * m22 - m12 * m12
        inv = 1.0 / (m11 * c11 + m12 * c12 + m13 * c13)
        t1 = (c11 * r1 + c12 * r2 + c13 * r3) * inv
        t2 = (c12 * r1 + c22 * r2 + c23 * r3) * inv
        t3 = (c13 * r1 + c23 * r2 + c33 * r3) * inv
    nx, ny, nz = np.empty_like(px), np.empty_like(px), np.empty_like(px)
    power = _seed_cols(geom._seed, lt[0] + t1, lt[1] + t2, lt[2] + t3, nx, ny, nz)
    nds, nfs, cost = _others_cols(fit.anchors, lo, nx, ny, nz)
    cost += t1 * t1
    cost += t2 * t2
    cost += t3 * t3
    return (t1, t2, t3), nx, ny, nz, power, nds, nfs, cost, den_bad


def _refine_chunk(
    geom: Geometry,
    cols: FloatArray,
    lens: FloatArray,
    x: FloatArray,
    y: FloatArray,
    z: FloatArray,
    ok: npt.NDArray[np.bool_],
    residual: FloatArray,
) -> None:
    """Vectorised ``_fit_scalar`` over one chunk: refines x, y, z in place, fills ``residual``."""
    fit = geom._fit
    sd = geom._seed
    n = geom.n_cables
    m = x.shape[0]
    lt = (cols[sd.i1], cols[sd.i2], cols[sd.i3])
    lo = [cols[j] for j in fit.others]
    ds, fs, cost = _others_cols(fit.anchors, lo, x, y, z)
    root = np.sqrt(cost)  # sqrt of the cost, for the rounding allowance and the residual
    np.multiply(root, 1.0 / math.sqrt(n), out=residual)
    act = np.zeros(m, dtype=bool)
    for f in fs:
        act |= np.abs(f) > GN_STEP_TOL_M
    act &= ok
    if not act.any():
        return  # consistent lengths: the seed is the fit
    slow: list[npt.NDArray[np.intp]] = []
    if fit.tilt is not None:
        (nx, ny, nz), (cx, cy, cz) = fit.tilt
        t = (x - cx) * nx + (y - cy) * ny + (z - cz) * nz
        t *= 2.0
        mz = z - t * nz
        mcost = _others_cols(fit.anchors, lo, x - t * nx, y - t * ny, mz)[2]
        flip = (mcost < cost) & act & (mz < geom.anchor_height_min_m)
        if flip.any():  # the mirror image is the better start: the scalar fit
            slow.append(np.nonzero(flip)[0])
            act &= ~flip
    # Rows that need no fit take a zero step (their f set to 0), so full-chunk steps leave
    # them where they are.
    for f in fs:
        f *= act
    state = _State(None, lt, lo, None, x, y, z, ds, fs, cost, root, np.full(m, np.inf), act)
    _iterate_cols(geom, lens, x, y, z, residual, state, 0, slow)


@dataclass(slots=True)
class _State:
    """Rows still iterating in ``_iterate_cols``: their chunk rows (None: all) and values."""

    idx: npt.NDArray[np.intp] | None
    lt: tuple[FloatArray, FloatArray, FloatArray]
    lo: list[FloatArray]
    s: tuple[FloatArray, FloatArray, FloatArray] | None
    px: FloatArray
    py: FloatArray
    pz: FloatArray
    ds: list[FloatArray]
    fs: list[FloatArray]
    cost: FloatArray
    root: FloatArray
    prev2: FloatArray
    act: npt.NDArray[np.bool_] | None = None  # None: all rows of the arrays


def _iterate_cols(
    geom: Geometry,
    lens: FloatArray,
    x: FloatArray,
    y: FloatArray,
    z: FloatArray,
    residual: FloatArray,
    st: _State,
    first: int,
    slow: list[npt.NDArray[np.intp]],
) -> None:
    """Steps ``first``.. of ``_fit_scalar``, vectorised over the rows of ``st``.

    Whole-chunk arrays (no gathers) while more than a quarter of the rows iterate, gathered
    rows after.  Converged rows are written to x, y, z, ``residual``.  Rows that
    ``_fit_scalar`` would hand to ``_gauss_newton`` (a step that raises the cost, leaves the
    spheres' domain or meets the seed triple's plane, or no convergence in ``GN_MAX_ITER``
    steps; rare) join ``slow`` and are finished by ``_fit_scalar`` itself, one by one.
    """
    n = geom.n_cables
    tol2 = GN_STEP_TOL_M * GN_STEP_TOL_M
    idx = st.idx
    act = st.act if st.act is not None else np.ones(st.px.shape[0], dtype=bool)
    s, px, py, pz, ds, fs = st.s, st.px, st.py, st.pz, st.ds, st.fs
    cost, root, prev2, sub_lt, sub_lo = st.cost, st.root, st.prev2, st.lt, st.lo
    for it in range(first, GN_MAX_ITER):
        if px.shape[0] == 0:
            break
        s_new, nx, ny, nz, power, nds, nfs, ncost, den_bad = _step_cols(
            geom, sub_lt, sub_lo, s, px, py, pz, ds, fs
        )
        allowed = cost * (1.0 + GN_COST_REL_TOL)
        allowed += GN_COST_ROUND_M * root
        worse = ~(ncost <= allowed)  # also NaN
        if den_bad is not None:
            worse |= den_bad
        miss = power > 0.0
        if miss.any():  # the step left the spheres' domain, beyond a tangent
            rows = np.nonzero(miss)[0]
            r3 = [np.abs(s_new[i][rows] + sub_lt[i][rows]) for i in range(3)]
            rmin = np.minimum(np.minimum(r3[0], r3[1]), r3[2])
            far = np.sqrt(rmin * rmin + power[rows]) - rmin > TANGENT_TOL_M
            worse[rows[far]] = True
        worse &= act
        step2 = np.subtract(nx, px)
        step2 *= step2
        tmp = np.subtract(ny, py)
        tmp *= tmp
        step2 += tmp
        np.subtract(nz, pz, out=tmp)
        tmp *= tmp
        step2 += tmp
        if it == 0:
            conv = np.zeros(act.shape, dtype=bool)
        else:
            conv = step2 < 1e-12
            conv &= (step2 <= tol2) | (step2 * step2 < GN_NEXT_TOL2 * prev2)
            conv &= act
            conv &= ~worse
        if conv.any():
            rows_c = np.nonzero(conv)[0]
            out_rows = rows_c if idx is None else idx[rows_c]
            x[out_rows], y[out_rows], z[out_rows] = nx[rows_c], ny[rows_c], nz[rows_c]
            residual[out_rows] = np.sqrt(ncost[rows_c] * (1.0 / n))
        if worse.any():
            rows_w = np.nonzero(worse)[0]
            slow.append(rows_w if idx is None else idx[rows_w])
        act &= ~conv
        act &= ~worse
        left = np.nonzero(act)[0]
        if left.size == 0:
            break
        s, px, py, pz, ds, fs, cost, prev2 = s_new, nx, ny, nz, nds, nfs, ncost, step2
        root = np.sqrt(cost)
        if left.size * 4 < act.size:  # few left: gather them
            idx = left if idx is None else idx[left]
            s = (s[0][left], s[1][left], s[2][left])
            px, py, pz = px[left], py[left], pz[left]
            ds = [d[left] for d in ds]
            fs = [f[left] for f in fs]
            cost, root, prev2 = cost[left], root[left], prev2[left]
            sub_lt = (sub_lt[0][left], sub_lt[1][left], sub_lt[2][left])
            sub_lo = [c[left] for c in sub_lo]
            act = np.ones(left.size, dtype=bool)
    else:
        left = np.nonzero(act)[0]
        slow.append(left if idx is None else idx[left])  # not converged in GN_MAX_ITER steps
    _finish_slow(geom, lens, x, y, z, residual, slow)


def _seed_row(geom: Geometry, row: FloatArray) -> Vec3:
    sd = geom._seed
    r1, r2, r3 = float(row[sd.i1]), float(row[sd.i2]), float(row[sd.i3])
    if isinstance(sd, _EqualSeed):
        return _seed_equal(sd, r1, r2, r3)
    return _seed_general(sd, r1, r2, r3)
