"""The intersection of three spheres: Williams & Needler, DETC2014-35185, eqs. (1)-(17).

Pure Python floats (no numpy on scalars): these run once per control tick.

Three cables of lengths r1, r2, r3 from the anchors c1, c2, c3 meet where the three spheres
meet.  Two such points exist, mirror images in the plane of the centres; the robot hangs from
the cables, so the *lower* one is returned (the paper's ``z_m``, eq. 12, minus sign).

* ``three_spheres_equal_height``: the paper's simplified algorithm for centres at one height.
  Subtracting sphere 3 from spheres 1 and 2 gives two lines in plan view (eqs. 7-8), whose
  crossing (eq. 10) gives x and y; sphere 3 then gives z (eqs. 11-12).  Eqs. 7-12 are used
  with the origin moved to the third centre, the factor 2 of eq. 9 folded into the
  determinant and the quadratic of eq. 11 solved directly on the third sphere.
* ``three_spheres``: any heights.  Subtracting sphere 1 from spheres 2 and 3 gives two planes
  whose intersection (the radical line) is parametrised by s = z - z1; sphere 1 then gives
  A s^2 + 2 B s + C = 0, solved with one square root and the root chosen without
  cancellation.  Its only singularity is the true one, centres collinear in plan view
  (eq. 14), where "lower" is undefined; equal heights reduce it to the simplified algorithm.
* ``_seed_equal`` / ``_seed_general``: the same two algorithms with every term that depends on
  the anchors alone precomputed once per geometry (``_EqualSeed`` / ``_GeneralSeed``); they
  seed every FPK.

A tangent (discriminant zero up to a shortfall of ``TANGENT_TOL_M``) is accepted and gives z
at the centres' plane; beyond that the lengths cannot meet (eq. 17) and ``UnreachableError``
names the cable to blame and by how much.  Eq. 17 singles out cable 1 only because the paper
substitutes back into sphere 1; in fact the radical line misses all three spheres at once.
So the error names the one cable whose length alone needs the smallest change for the three
spheres to meet (the others held), with ``shortfall_m`` > 0 when it is too short by that much
(the usual case, eq. 17) and < 0 when it is too long (``_diagnose``).

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
* ``three_spheres_equal_height`` (everything from the centres on each call): 18 / 18 / 1;
  its per-tick form ``_seed_equal`` (anchor-only terms precomputed): 11 / 9 / 1.
* ``three_spheres`` (general, any heights): 31 / 37 / 1; its per-tick form
  ``_seed_general``: 16 / 18 / 1.
  Comparisons and the sign flips of the tangent / unreachable branches are not counted.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NoReturn

from controller.core.kinematics.errors import (
    KinematicsError,
    SingularGeometryError,
    UnreachableError,
)

__all__ = ["TANGENT_TOL_M", "three_spheres", "three_spheres_equal_height"]

Vec3 = tuple[float, float, float]

#: Shortfall (metres) up to which a negative discriminant is treated as a tangent.
TANGENT_TOL_M = 1e-9

# Module-level alias: one global lookup per call, and the operation-count test swaps it for a
# counting square root.
_sqrt = math.sqrt


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
    form with anchor-only terms precomputed is ``_seed_equal``).  Returns (x, y, z_m) with
    z_m the solution below the centres (eq. 12, minus sign).
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
# Per-tick forms: the anchor-only terms of one triple computed once per geometry
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


def _raise_unreachable(
    tri: tuple[int, int, int], centres: tuple[Vec3, Vec3, Vec3], rs: Vec3, power: float
) -> NoReturn:
    k, change = _diagnose(centres, rs, power)
    raise UnreachableError(tri[k - 1] + 1, change)


def _equal_xy(sd: _EqualSeed, s1: Any, s2: Any, s3: Any) -> tuple[Any, Any, Any]:
    """dx, dy (from the triple's first anchor) and discriminant of the simplified algorithm
    from the squared lengths s_i = r_i^2 (``_seed_equal``); floats or numpy arrays alike, the
    arguments left untouched (the planar fit, and the batch on columns)."""
    u = s1 - s3
    v = s2 - s3
    dx = u * sd.e1
    dx += v * sd.e2
    dx += sd.dx0
    u *= sd.f1
    v *= sd.f2
    dy = u + v
    dy += sd.dy0
    disc = s1 - dx * dx
    disc -= dy * dy
    return dx, dy, disc


def _seed_equal(sd: _EqualSeed, r1: float, r2: float, r3: float, clamp: bool = False) -> Vec3:
    """Per-tick simplified algorithm with hoisted constants; 11 add, 9 mul, 1 sqrt.

    Raises ``UnreachableError`` naming the 1-based cable of the geometry, unless `clamp`:
    then lengths that cannot meet give the radical line's point in the centres' plane.
    """
    # ``_equal_xy`` written out, not called: this runs every tick, and the call would add about
    # a fifth to its cost.
    s1 = r1 * r1
    s3 = r3 * r3
    u = s1 - s3
    v = r2 * r2 - s3
    dx = u * sd.e1 + v * sd.e2 + sd.dx0
    dy = u * sd.f1 + v * sd.f2 + sd.dy0
    disc = s1 - dx * dx - dy * dy
    if disc < 0.0:
        if not (clamp or _is_tangent(r1, r2, r3, -disc)):
            _raise_unreachable(sd.tri, sd.centres, (r1, r2, r3), -disc)
        disc = 0.0 * disc
    return (sd.x1 + dx, sd.y1 + dy, sd.zn - _sqrt(disc))


def _seed_general(sd: _GeneralSeed, r1: float, r2: float, r3: float, clamp: bool = False) -> Vec3:
    """Per-tick general algorithm with hoisted constants; 16 add, 18 mul, 1 sqrt.

    Raises ``UnreachableError`` naming the 1-based cable of the geometry, unless `clamp`:
    then lengths that cannot meet give the radical line's point nearest the three spheres.
    """
    s1 = r1 * r1
    h2 = 0.5 * (s1 - r2 * r2) + sd.q2
    h3 = 0.5 * (s1 - r3 * r3) + sd.q3
    x0 = h2 * sd.p1 + h3 * sd.p2
    y0 = h2 * sd.s1 + h3 * sd.s2
    qb = x0 * sd.wx + y0 * sd.wy
    qc = x0 * x0 + y0 * y0 - s1
    disc = qb * qb - qc / sd.inv_a
    if disc < 0.0:
        if not (clamp or _is_tangent(r1, r2, r3, -disc * sd.inv_a)):
            _raise_unreachable(sd.tri, sd.centres, (r1, r2, r3), -disc * sd.inv_a)
        disc = 0.0 * disc
    sq = _sqrt(disc)
    if qb > 0.0:
        s = -(qb + sq) * sd.inv_a
    else:
        den = sq - qb
        s = qc / den if den != 0.0 else 0.0 * qb
    return (sd.x1 + x0 + sd.wx * s, sd.y1 + y0 + sd.wy * s, sd.z1 + s)
