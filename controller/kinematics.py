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
to 1e-12 m (consistent lengths) that is the answer; otherwise Gauss-Newton minimises
sum (|P - B_i| - L_i)^2 over all N cables (3x3 normal equations in closed form, step halving
so the cost never rises, mirror to the lower side when all anchors share a height), stopping
when the step is below 1e-12 m or is below 1 um with the next step predicted (linear
convergence) below 1e-10 m; with 1 mm of length noise that is two steps.  ``fpk`` and
``fpk_batch`` follow the same rule and agree to ~1e-11 m.  ``residual_m`` is the RMS of
|P - B_i| - L_i over all N cables.

Speed design
------------
The single-pose path (``three_spheres*``, ``fpk`` on N lengths, ``ipk_point``) is pure
Python floats with anchor-only terms precomputed in ``Geometry``: no numpy on scalars.
The batch path (``fpk_batch``, ``ipk``) is numpy, vectorised over rows, in chunks of
``BATCH_CHUNK`` rows so the working set stays in cache, operating in place; masked ufuncs
(``where=``) are avoided (about 20x slower than plain ones).  Only rows whose step would
raise the cost or that do not converge (rare: near-tangent seeds) are finished one by one by
the scalar fit.  ``FpkBatchResult.position_m`` is the (M, 3) transpose of a (3, M) array.
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
#: more than this fraction plus ``GN_COST_ABS_TOL``: rounding noise, not an overshoot.
GN_COST_REL_TOL = 1e-9
GN_COST_ABS_TOL = 1e-24
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
        "_hull_edges",
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


def _normal_eq_at_seed(
    anchors: tuple[Vec3, ...],
    lengths: Sequence[float],
    x: float,
    y: float,
    z: float,
    exact: tuple[int, int, int],
) -> tuple[float, float, float, float, float, float, float, float, float, float]:
    """``_normal_eq`` at the seed point, which meets the cables ``exact`` by construction.

    Their residual is zero and their unit vector is (P - B) / L: no square root needed.
    """
    a11 = a12 = a13 = a22 = a23 = a33 = g1 = g2 = g3 = cost = 0.0
    for k, ((ax, ay, az), ln) in enumerate(zip(anchors, lengths, strict=True)):
        dx = x - ax
        dy = y - ay
        dz = z - az
        if k in exact:
            t = 1.0 / ln
            res = 0.0
        else:
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
        allowed = cost + (GN_COST_REL_TOL * cost + GN_COST_ABS_TOL)
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
    # Consistent lengths (the usual case): the other cables already agree, skip the fit.
    anchors = geom._anchors_t
    sumsq = 0.0
    worst = 0.0
    for k in range(n):
        if k == sd.i1 or k == sd.i2 or k == sd.i3:
            continue
        ax, ay, az = anchors[k]
        dx = x - ax
        dy = y - ay
        dz = z - az
        res = _sqrt(dx * dx + dy * dy + dz * dz) - lengths[k]
        sumsq += res * res
        if res * res > worst:
            worst = res * res
    if worst > GN_STEP_TOL_M * GN_STEP_TOL_M:
        mirror = sd.zn if geom.equal_heights and isinstance(sd, _EqualSeed) else None
        start = _normal_eq_at_seed(anchors, lengths, x, y, z, (sd.i1, sd.i2, sd.i3))
        x, y, z, rms = _gauss_newton(anchors, lengths, x, y, z, mirror, start)
    else:
        rms = _sqrt(sumsq / n)
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
    algorithm when its anchors share a height, the general one otherwise; for N > 3 a
    Gauss-Newton least-squares fit over all cables follows (skipped when the other cables
    already agree to 1e-12 m).  ``residual_m`` is the RMS cable-length mismatch.
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
    with np.errstate(all="ignore"):
        # One check on the whole array; per-row checks only where it fails.
        checked = bool(lens.min(initial=np.inf) > 0.0) and math.isfinite(float(lens.sum()))
        for s in range(0, m, BATCH_CHUNK):
            e = min(m, s + BATCH_CHUNK)
            _fpk_chunk(
                geom,
                lens[s:e],
                xyz[:, s:e],
                residual[s:e],
                ok[s:e],
                short_cable[s:e],
                shortfall[s:e],
                checked,
            )
    return FpkBatchResult(xyz.T, residual, ok, geom.seed_triple, short_cable, shortfall)


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
    m, n = lens.shape
    sd = geom._seed
    cols = lens.T.copy()  # (n, m), contiguous rows: one per cable
    if not checked:
        for c in cols:
            ok &= c > 0.0  # also False for NaN
            ok &= c < np.inf
    c1, c2, c3 = cols[sd.i1], cols[sd.i2], cols[sd.i3]
    x, y, z = xyz[0], xyz[1], xyz[2]
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
        power = buf_b
    else:
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
        power = -disc * sd.inv_a
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

    bad = power > 0.0
    bad &= ok
    if bad.any():
        idx = np.nonzero(bad)[0]
        trio = np.stack([c1[idx], c2[idx], c3[idx]], axis=1)
        rmin = np.min(np.abs(trio), axis=1)
        real = np.sqrt(rmin * rmin + power[idx]) - rmin > TANGENT_TOL_M
        idx, trio = idx[real], trio[real]
        ok[idx] = False
        k, change = _diagnose_batch(sd.centres, trio, power[idx])
        short_cable[idx] = np.asarray(sd.tri, dtype=np.int64)[k - 1] + 1
        shortfall[idx] = change

    if n > 3:
        _refine_chunk(geom, cols, lens, x, y, z, ok, residual)

    np.add(x, y, out=buf_b)
    buf_b += z
    buf_b += residual
    ok &= np.isfinite(buf_b)
    if not ok.all():
        bad = ~ok
        xyz[:, bad] = 0.0
        residual[bad] = 0.0
        short_cable[ok] = 0
        shortfall[ok] = 0.0


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
    """Vectorised Gauss-Newton over one chunk: refines x, y, z in place, fills ``residual``.

    Same fit as ``_gauss_newton``, arranged for few passes over memory: the first normal
    equations reuse the residual check of the cables outside the seed triple, and for the
    seed cables (which the seed meets exactly) need only their unit vectors.  A step of
    under 1 um whose successor is predicted below 1e-10 m (linear convergence,
    |s_k|^2 / |s_k-1|; see ``GN_NEXT_TOL2``) is taken without evaluating the cost
    again.  Rows whose step would raise the cost (rare: near-tangent seeds) or that do not
    converge in ``GN_MAX_ITER`` steps are finished by the scalar ``_gauss_newton`` (with
    its step halving), a Python loop over those rows only.
    """
    anchors = geom._anchors_t
    n = geom.n_cables
    sd = geom._seed
    mirror = sd.zn if geom.equal_heights and isinstance(sd, _EqualSeed) else None
    seed_idx = (sd.i1, sd.i2, sd.i3)
    m = x.shape[0]
    # Residuals of the cables outside the seed triple (the seed ones are met exactly).
    cost = np.zeros(m)
    worst = np.zeros(m)
    tmp = np.empty(m)
    saved = []
    for k in range(n):
        if k in seed_idx:
            continue
        ax, ay, az = anchors[k]
        dx, dy, dz = x - ax, y - ay, z - az
        d = np.multiply(dx, dx)
        d += np.multiply(dy, dy, out=tmp)
        d += np.multiply(dz, dz, out=tmp)
        np.sqrt(d, out=d)
        res = d - cols[k]
        np.multiply(res, res, out=tmp)
        cost += tmp
        np.maximum(worst, tmp, out=worst)
        saved.append((dx, dy, dz, d, res))
    np.divide(cost, n, out=residual)
    np.sqrt(residual, out=residual)
    tol2 = GN_STEP_TOL_M * GN_STEP_TOL_M
    need = worst > tol2
    need &= ok
    if not need.any():
        return  # consistent lengths: the seed is the fit

    ne = [cost] + [np.zeros(m) for _ in range(9)]
    _, a11, a12, a13, a22, a23, a33, g1, g2, g3 = ne
    for dx, dy, dz, d, res in saved:
        np.divide(1.0, d, out=d)
        dx *= d
        dy *= d
        dz *= d
        a11 += np.multiply(dx, dx, out=tmp)
        a12 += np.multiply(dx, dy, out=tmp)
        a13 += np.multiply(dx, dz, out=tmp)
        a22 += np.multiply(dy, dy, out=tmp)
        a23 += np.multiply(dy, dz, out=tmp)
        a33 += np.multiply(dz, dz, out=tmp)
        g1 += np.multiply(dx, res, out=tmp)
        g2 += np.multiply(dy, res, out=tmp)
        g3 += np.multiply(dz, res, out=tmp)
    _accumulate_jtj(ne, [anchors[k] for k in seed_idx], cols[list(seed_idx)], x, y, z)

    # Two modes: "full" works on whole-chunk arrays with a mask of rows still iterating
    # (no gathers; the usual noisy batch converges in two steps), "compact" on gathered
    # rows once few remain.
    act = need
    full = True
    idx = np.arange(m)
    px, py, pz, sub_cols = x, y, z, cols
    prev2 = np.full(m, np.inf)  # squared length of the previous step
    slow: list[npt.NDArray[np.intp]] = []  # chunk rows handed to the scalar fit
    if np.count_nonzero(need) * 4 < m:
        full = False
        idx = np.nonzero(need)[0]
        px, py, pz, sub_cols = x[idx], y[idx], z[idx], cols[:, idx]
        ne = [v[idx] for v in ne]
        prev2 = prev2[idx]
        act = np.ones(idx.size, dtype=bool)
    for _ in range(GN_MAX_ITER):
        sx, sy, sz, solvable = _solve_normal(ne)
        step2 = sx * sx + sy * sy + sz * sz
        nx, ny, nz = px - sx, py - sy, pz - sz
        if mirror is not None:
            # Reflect points above the mirror plane (masked ufuncs are slow; this is not).
            nz -= mirror
            np.abs(nz, out=nz)
            np.subtract(mirror, nz, out=nz)
        # Done without another evaluation: singular normal equations (keep the point) or a
        # small step whose successor is predicted below tolerance.
        fin = (step2 < 1e-12) & ((step2 <= tol2) | (step2 * step2 < GN_NEXT_TOL2 * prev2))
        fin &= solvable
        fin &= act
        stuck = ~solvable
        stuck &= act
        done = fin | stuck
        if full:
            if done.any():
                x[...] = np.where(fin, nx, x)
                y[...] = np.where(fin, ny, y)
                z[...] = np.where(fin, nz, z)
                residual[...] = np.where(done, np.sqrt(_cost_after(ne, sx, sy, sz) / n), residual)
            act = act & ~done
            left = int(np.count_nonzero(act))
            if left == 0:
                break
            if left * 4 < m:  # few left: gather them
                full = False
                idx = np.nonzero(act)[0]
                px, py, pz = nx[idx], ny[idx], nz[idx]
                old_cost, prev2 = ne[0][idx], step2[idx]
                sub_cols = cols[:, idx]
                act = np.ones(idx.size, dtype=bool)
            else:
                px, py, pz = nx, ny, nz
                old_cost, prev2 = ne[0], step2
        else:
            if done.any():
                rows = idx[fin]
                x[rows], y[rows], z[rows] = nx[fin], ny[fin], nz[fin]
                rows = idx[done]
                residual[rows] = np.sqrt(_cost_after(ne, sx, sy, sz)[done] / n)
            go = np.nonzero(~done)[0]
            if go.size == 0:
                idx = idx[:0]
                break
            idx, px, py, pz = idx[go], nx[go], ny[go], nz[go]
            old_cost, prev2 = ne[0][go], step2[go]
            sub_cols = sub_cols[:, go]
            act = np.ones(idx.size, dtype=bool)
        ne = [np.zeros(idx.size) for _ in range(10)]
        _accumulate(ne, list(anchors), sub_cols, px, py, pz, None)
        worse = ne[0] > old_cost + (GN_COST_REL_TOL * old_cost + GN_COST_ABS_TOL)
        worse &= act
        if worse.any():
            slow.append(idx[worse])
            act = act & ~worse
            if not act.any():
                idx = idx[:0]
                break
    else:
        slow.append(idx[act])  # not converged in GN_MAX_ITER steps
    for rows in slow:
        for r in rows.tolist():
            sx_, sy_, sz_ = _seed_row(geom, lens[r])
            fx, fy, fz, rms = _gauss_newton(anchors, lens[r].tolist(), sx_, sy_, sz_, mirror)
            x[r], y[r], z[r], residual[r] = fx, fy, fz, rms


def _seed_row(geom: Geometry, row: FloatArray) -> Vec3:
    sd = geom._seed
    r1, r2, r3 = float(row[sd.i1]), float(row[sd.i2]), float(row[sd.i3])
    if isinstance(sd, _EqualSeed):
        return _seed_equal(sd, r1, r2, r3)
    return _seed_general(sd, r1, r2, r3)


def _cost_after(ne: list[FloatArray], sx: FloatArray, sy: FloatArray, sz: FloatArray) -> FloatArray:
    """Cost after the Gauss-Newton step s (model |r - J s|^2 = cost - g.s), never below 0.

    Where the step is zero (singular rows) this is the cost itself.
    """
    post = ne[0] - (ne[7] * sx + ne[8] * sy + ne[9] * sz)
    np.maximum(post, 0.0, out=post)
    return post


def _solve_normal(
    ne: list[FloatArray],
) -> tuple[FloatArray, FloatArray, FloatArray, npt.NDArray[np.bool_]]:
    """Gauss-Newton steps from vectorised normal equations; zero where singular."""
    _, a11, a12, a13, a22, a23, a33, g1, g2, g3 = ne
    c11 = a22 * a33 - a23 * a23
    c12 = a13 * a23 - a12 * a33
    c13 = a12 * a23 - a13 * a22
    c22 = a11 * a33 - a13 * a13
    c23 = a12 * a13 - a11 * a23
    c33 = a11 * a22 - a12 * a12
    det = a11 * c11 + a12 * c12 + a13 * c13
    solvable = det > GN_DET_MIN
    inv = np.reciprocal(det)
    inv[~solvable] = 0.0
    sx = (c11 * g1 + c12 * g2 + c13 * g3) * inv
    sy = (c12 * g1 + c22 * g2 + c23 * g3) * inv
    sz = (c13 * g1 + c23 * g2 + c33 * g3) * inv
    return sx, sy, sz, solvable


def _accumulate_jtj(
    ne: list[FloatArray],
    anchors: Sequence[Vec3],
    cols: FloatArray,
    x: FloatArray,
    y: FloatArray,
    z: FloatArray,
) -> None:
    """Add the J^T J terms of cables whose length is met exactly (u = (P - B) / L)."""
    _, a11, a12, a13, a22, a23, a33, _, _, _ = ne
    m = x.shape[0]
    dx, dy, dz, inv, tmp = (np.empty(m) for _ in range(5))
    for (ax, ay, az), ln in zip(anchors, cols, strict=True):
        np.divide(1.0, ln, out=inv)
        np.subtract(x, ax, out=dx)
        dx *= inv
        np.subtract(y, ay, out=dy)
        dy *= inv
        np.subtract(z, az, out=dz)
        dz *= inv
        a11 += np.multiply(dx, dx, out=tmp)
        a12 += np.multiply(dx, dy, out=tmp)
        a13 += np.multiply(dx, dz, out=tmp)
        a22 += np.multiply(dy, dy, out=tmp)
        a23 += np.multiply(dy, dz, out=tmp)
        a33 += np.multiply(dz, dz, out=tmp)


def _accumulate(
    ne: list[FloatArray],
    anchors: Sequence[Vec3],
    cols: FloatArray,
    x: FloatArray,
    y: FloatArray,
    z: FloatArray,
    worst: FloatArray | None,
) -> None:
    """Add cost, J^T J and J^T r of the given cables; track the largest squared residual."""
    cost, a11, a12, a13, a22, a23, a33, g1, g2, g3 = ne
    m = x.shape[0]
    dx, dy, dz, d, res, tmp = (np.empty(m) for _ in range(6))
    for (ax, ay, az), ln in zip(anchors, cols, strict=True):
        np.subtract(x, ax, out=dx)
        np.subtract(y, ay, out=dy)
        np.subtract(z, az, out=dz)
        np.multiply(dx, dx, out=d)
        d += np.multiply(dy, dy, out=tmp)
        d += np.multiply(dz, dz, out=tmp)
        np.sqrt(d, out=d)
        np.subtract(d, ln, out=res)
        np.multiply(res, res, out=tmp)
        cost += tmp
        if worst is not None:
            np.maximum(worst, tmp, out=worst)
        np.divide(1.0, d, out=d)  # d > 0: P is below the anchors
        dx *= d
        dy *= d
        dz *= d
        a11 += np.multiply(dx, dx, out=tmp)
        a12 += np.multiply(dx, dy, out=tmp)
        a13 += np.multiply(dx, dz, out=tmp)
        a22 += np.multiply(dy, dy, out=tmp)
        a23 += np.multiply(dy, dz, out=tmp)
        a33 += np.multiply(dz, dz, out=tmp)
        g1 += np.multiply(dx, res, out=tmp)
        g2 += np.multiply(dy, res, out=tmp)
        g3 += np.multiply(dz, res, out=tmp)
