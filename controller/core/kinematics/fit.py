"""Forward pose kinematics over N >= 3 cables: the three-spheres seed, then least squares.

Pure Python floats (no numpy on scalars): ``fpk`` runs once per control tick.

``fpk`` solves the geometry's ``seed_triple`` (see ``Geometry``) with the paper's simplified
algorithm when its anchors share a height, the general one otherwise (``spheres``).  With three
cables that is the answer.  With more, the other cables are checked against the seed: when
they agree to ``GN_STEP_TOL_M`` (consistent lengths, e.g. from IPK) the seed is the answer.
Otherwise the lengths disagree (noise, a slack or slipped cable) and ``fpk`` returns the
least-squares point, minimising sum (|P - B_i| - L_i)^2 over all N cables;
``residual_m`` is the RMS of |P - B_i| - L_i at the returned point.  Near the anchors' plane
the seed triple's spheres meet at a grazing angle, and a little noise makes them miss each
other; with more than three cables the fit then starts from another triple that meets, and
stands when it explains every cable to ``SEED_MISS_FIT_RMS_M`` (a real miss, a cable far too
short or long, still raises ``UnreachableError`` naming it).

Four anchors at one height (the usual rig): one multiplier equation
------------------------------------------------------------------------
The fourth anchor is the plan-view barycentric combination B4 = sum c_i B_i of the seed
triple's, so for any point on the three spheres |P - B4|^2 = sum c_i q_i^2 + m0 (q_i its
distances to the triple, m0 = |B4|^2 - sum c_i |B_i|^2).  The fit minimises
sum (q_i - L_i)^2 + (d - L4)^2 subject to d^2 = sum c_i q_i^2 + m0, whose Lagrange conditions
give q_i = L_i / (1 + lam c_i), d = L4 / (1 - lam) and, for the multiplier,
phi(lam) = sum c_i L_i^2 / (1 + lam c_i)^2 + m0 - L4^2 / (1 - lam)^2 = 0, strictly decreasing
between its poles.  Newton from lam = 0 gives lam_1 = (D2 - L4^2) / (2 (A + L4^2)) with
D2 = sum c_i L_i^2 + m0 and A = sum c_i^2 L_i^2; one more Newton step is taken, and its size
bounds the error left (``curv`` * step^2).  The cost is lam^2 (sum c_i^2 q_i^2 + d^2), and
P is the three-spheres point of the fitted lengths q_i: exact, with no linearisation in P,
which is why two steps reach 1e-12 m.  ``_fit_planar4`` returns nothing when it cannot vouch
for the result (multiplier near a pole, Newton not converged, the fitted lengths' spheres
missing each other, or a cost above the seed's).

Otherwise: Gauss-Newton in P
----------------------------
``_gauss_newton`` from the seed: the 3x3 normal equations solved in closed form, the step
halved until the cost does not increase (near the anchor plane z is poorly determined and a
full step can overshoot).  It stops when the step is below ``GN_STEP_TOL_M``, or is under
1 um with the next one, predicted from the linear convergence rate, below 1e-10 m.  With all
anchors at one height the cost is symmetric about their plane, and a point above it is
mirrored back to the lower solution.  With a tilted seed triple the seed's mirror image in the
triple's plane also meets the three spheres; when it is below every anchor and the other
cables agree with it better, the fit starts there.

Among the anchors (``Geometry.hanging`` False: a Hangprinter)
-------------------------------------------------------------
The effector is inside the anchors' hull, above some of them, so "the lower solution" can be
the wrong one: three low anchors meet at the effector and at its mirror image below their
plane (Klipper's ``winch`` trilaterates from three anchors and, above low ones, takes that
one).  With anchors not in one plane, subtracting the mean of the N spheres from each leaves a
linear system in P (``fitplan._Linear``): its least-squares point over every cable has no
mirror image, is exact for consistent lengths and within the noise otherwise, and seeds the
fit; the last pose, when the caller has it (``fpk(..., seed_m=...)``: the control loop's, a
tick old) seeds it instead.  Gauss-Newton over every cable then finds the pose, with J^T J
taken once at the start (``_gauss_newton_among``: the cable directions barely turn over the
millimetres of such a fit), stopping once the next step would be under 10 nm
(``GN_AMONG_NEXT_TOL2``).  A fit from the last pose that
leaves more than ``RETRY_RMS_M`` of residual (a stale or far guess) is done again from the
linear seed, and the better one is kept.  (The seed triple is also a face of the hull, with
the effector on the hull's side of its plane, ``Geometry.seed_up``.)  The seed and this fit
run as ``fitgen`` writes them out for the layout (made with the ``Geometry``): the same
arithmetic without the loop over the cables; a case it does not cover (a point on an anchor,
a singular J^T J, a step to halve, no convergence) goes to ``_gauss_newton_among`` from the
same start.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from controller.core.kinematics.errors import KinematicsError, UnreachableError
from controller.core.kinematics.fitplan import (
    GN_AMONG_NEXT_TOL2,
    GN_COST_REL_TOL,
    GN_COST_ROUND_M,
    GN_DET_MIN,
    GN_MAX_HALVINGS,
    GN_MAX_ITER,
    GN_NEXT_TOL2,
    GN_STEP_TOL_M,
    _Planar4,
)
from controller.core.kinematics.spheres import (
    Vec3,
    _equal_xy,
    _EqualSeed,
    _is_tangent,
    _seed_equal,
    _seed_general,
    three_spheres,
)

if TYPE_CHECKING:
    from controller.core.kinematics.geometry import Geometry

__all__ = ["FpkResult", "fpk"]

FloatArray = npt.NDArray[np.float64]

#: Among the anchors: a fit from the caller's last pose with a larger RMS residual (m) is done
#: again from the three-spheres seed on the hull's side.
RETRY_RMS_M = 0.002

#: A hanging robot with more than three cables whose seed triple's spheres miss each other
#: (noise on lengths near the anchors' plane, where the three meet at a grazing angle) is fitted
#: from another triple that meets; the fit stands when its RMS residual over every cable is at
#: most this (m), else the seed triple's miss is the answer (``UnreachableError``).
SEED_MISS_FIT_RMS_M = 0.01

# Module-level aliases: one global lookup per call.
_sqrt = math.sqrt
_dist = math.dist


@dataclass(frozen=True, slots=True)
class FpkResult:
    """One FPK solution: position, RMS cable-length mismatch, seed triple (0-based)."""

    position_m: Vec3
    residual_m: float
    seed_triple: tuple[int, int, int]


# The planar fit is written once for floats and numpy arrays alike: the batch (``batch``)
# runs the same functions on columns of lengths.  They never modify their arguments; the
# augmented assignments only save the arrays' temporaries.


def _planar4_solve(
    p4: _Planar4,
    l1: Any,
    l2: Any,
    l3: Any,
    l4: Any,
    s1: Any,
    s2: Any,
    s3: Any,
    t: Any,
    big: Any,
    cost0: Any,
    root0: Any,
) -> tuple[Any, Any, Any, Any, Any]:
    """The planar fit from the lengths L_i and their squares s_i (t = L4^2).

    lam takes the closed-form first step and one Newton step on phi; the seed cables' fitted
    lengths are q_i = L_i / (1 + lam c_i) and the cost lam^2 (sum c_i^2 q_i^2 + d^2),
    d = L4 / (1 - lam).  Returns the fitted point's dx, dy and discriminant
    (``_equal_xy`` of the q_i), the cost, and whether the fit can be vouched for: lam away
    from the poles, Newton converged (error ``curv`` * step^2 relative to the longest cable
    ``big`` below ``GN_STEP_TOL_M``) and the cost not above the seed's ``cost0``
    (= ``root0``^2) beyond rounding; NaN gives False.
    """
    c1, c2, c3 = p4.c
    a1 = s1 * c1
    a2 = s2 * c2
    a3 = s3 * c3
    lam = a1 + a2
    lam += a3
    lam += p4.m0
    lam -= t  # D2 - L4^2
    den = a1 * c1
    den += a2 * c2
    den += a3 * c3
    den += t
    lam /= 2.0 * den
    r1 = lam * c1 + 1.0
    r2 = lam * c2 + 1.0
    r3 = lam * c3 + 1.0
    a1 /= r1 * r1  # c_i L_i^2 / (1 + lam c_i)^2
    a2 /= r2 * r2
    a3 /= r3 * r3
    v = 1.0 - lam
    tv = t / (v * v)
    phi = a1 + a2
    phi += a3
    phi += p4.m0
    phi -= tv  # phi(lam)
    a1 *= c1 / r1
    a2 *= c2 / r2
    a3 *= c3 / r3
    tv /= v
    den = a1 + a2
    den += a3
    den += tv  # -phi'(lam) / 2
    step = phi / (2.0 * den)
    lam += step
    q1 = l1 / (lam * c1 + 1.0)
    q2 = l2 / (lam * c2 + 1.0)
    q3 = l3 / (lam * c3 + 1.0)
    q1 *= q1
    q2 *= q2
    q3 *= q3
    cost = l4 / (1.0 - lam)
    cost *= cost
    cost += q1 * (c1 * c1)
    cost += q2 * (c2 * c2)
    cost += q3 * (c3 * c3)
    cost *= lam * lam
    trusted = (
        (abs(lam) <= 0.75 / p4.curv)
        & (step * step <= GN_STEP_TOL_M / (big * p4.curv))
        & (cost <= cost0 * (1.0 + GN_COST_REL_TOL) + GN_COST_ROUND_M * root0)
    )
    dx, dy, disc = _equal_xy(p4.sd, q1, q2, q3)
    return dx, dy, disc, cost, trusted


def _fit_planar4(
    p4: _Planar4, lengths: Sequence[float], cost0: float
) -> tuple[float, float, float, float] | None:
    """The fit for four anchors at one height; x, y, z, RMS residual, or None when it cannot
    vouch for the result (see ``_planar4_solve``, or the fitted lengths' spheres miss)."""
    sd = p4.sd
    l1, l2, l3, l4 = lengths[sd.i1], lengths[sd.i2], lengths[sd.i3], lengths[p4.k4]
    dx, dy, disc, cost, trusted = _planar4_solve(
        p4,
        l1,
        l2,
        l3,
        l4,
        l1 * l1,
        l2 * l2,
        l3 * l3,
        l4 * l4,
        max(l1, l2, l3, l4),
        cost0,
        _sqrt(cost0),
    )
    if not trusted:
        return None
    if disc < 0.0:  # as ``_seed_equal``: a tangent is accepted, a miss is not
        if not _is_tangent(l1, l2, l3, -disc):
            return None
        disc = 0.0
    return sd.x1 + dx, sd.y1 + dy, sd.zn - _sqrt(disc), _sqrt(cost * 0.25)


def _mirror(tilt: tuple[Vec3, Vec3], x: float, y: float, z: float) -> Vec3:
    """(x, y, z) reflected in the plane of ``tilt`` (unit normal, point)."""
    (nx, ny, nz), (cx, cy, cz) = tilt
    t = 2.0 * ((x - cx) * nx + (y - cy) * ny + (z - cz) * nz)
    return x - t * nx, y - t * ny, z - t * nz


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
    next_tol2: float = GN_NEXT_TOL2,
) -> tuple[float, float, float, float]:
    """Least-squares fit over all cables from (x, y, z); returns x, y, z, RMS residual.

    Gauss-Newton in P with step halving (see the module docstring); ``z_mirror``: the height
    of the anchors when they all share one (points above it are mirrored below);
    ``next_tol2``: the square of the predicted next step it stops at.
    """
    n = len(anchors)
    cost, a11, a12, a13, a22, a23, a33, g1, g2, g3 = _normal_eq(anchors, lengths, x, y, z)
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
        if step2 < 1e-12 and (step2 <= tol2 or step2 * step2 < next_tol2 * prev2):
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


def _cost_grad(
    anchors: tuple[Vec3, ...], lengths: Sequence[float], x: float, y: float, z: float
) -> tuple[float, float, float, float]:
    """Sum of squared residuals and J^T r at (x, y, z) (``_normal_eq`` without J^T J)."""
    g1 = g2 = g3 = cost = 0.0
    for (ax, ay, az), ln in zip(anchors, lengths, strict=True):
        dx = x - ax
        dy = y - ay
        dz = z - az
        d = _sqrt(dx * dx + dy * dy + dz * dz)
        res = d - ln
        cost += res * res
        k = res / d if d > 0.0 else 0.0
        g1 += dx * k
        g2 += dy * k
        g3 += dz * k
    return cost, g1, g2, g3


def _gauss_newton_among(
    anchors: tuple[Vec3, ...], lengths: Sequence[float], x: float, y: float, z: float
) -> tuple[float, float, float, float]:
    """``_gauss_newton`` for an effector among its anchors from a start within millimetres (the
    last pose, the linearised trilateration): J^T J is taken once, at the start (the cable
    directions turn by about the step over the cable length between iterations), and each
    trial point costs only the residuals and J^T r; the same stopping rule with
    ``GN_AMONG_NEXT_TOL2``. Not settled within ``GN_MAX_ITER`` steps (a far start): the full
    Gauss-Newton from where it got. Returns x, y, z, RMS residual.

    The tick's path: ``_normal_eq`` and ``_cost_grad`` are written out here (the same
    quantities, with ``math.dist`` for the distances; J^T J's trace is N, its rows being unit
    vectors, so its last diagonal entry is taken from the other two; J^T r of a trial point as
    ``P sum k_i - sum A_i k_i`` with ``k_i = r_i / d_i``), a point on an anchor (a division by
    zero) handed to them."""
    n = len(anchors)
    cost = a11 = a12 = a13 = a22 = a23 = g1 = g2 = g3 = 0.0
    p = (x, y, z)
    try:
        for a, ln in zip(anchors, lengths, strict=True):
            d = _dist(p, a)
            t = 1.0 / d
            ax, ay, az = a
            ux = (x - ax) * t
            uy = (y - ay) * t
            uz = (z - az) * t
            res = d - ln
            cost += res * res
            a11 += ux * ux
            a12 += ux * uy
            a13 += ux * uz
            a22 += uy * uy
            a23 += uy * uz
            g1 += ux * res
            g2 += uy * res
            g3 += uz * res
        a33 = n - a11 - a22
    except ZeroDivisionError:
        cost, a11, a12, a13, a22, a23, a33, g1, g2, g3 = _normal_eq(anchors, lengths, x, y, z)
    c11 = a22 * a33 - a23 * a23
    c12 = a13 * a23 - a12 * a33
    c13 = a12 * a23 - a13 * a22
    det = a11 * c11 + a12 * c12 + a13 * c13
    if not det > GN_DET_MIN:  # cables (nearly) coplanar with P: keep the estimate
        return x, y, z, _sqrt(cost / n)
    inv = 1.0 / det
    c11 *= inv
    c12 *= inv
    c13 *= inv
    c22 = (a11 * a33 - a13 * a13) * inv
    c23 = (a12 * a13 - a11 * a23) * inv
    c33 = (a11 * a22 - a12 * a12) * inv
    prev2 = math.inf
    tol2 = GN_STEP_TOL_M * GN_STEP_TOL_M
    for _ in range(GN_MAX_ITER):
        sx = c11 * g1 + c12 * g2 + c13 * g3
        sy = c12 * g1 + c22 * g2 + c23 * g3
        sz = c13 * g1 + c23 * g2 + c33 * g3
        step2 = sx * sx + sy * sy + sz * sz
        if step2 < 1e-12 and (step2 <= tol2 or step2 * step2 < GN_AMONG_NEXT_TOL2 * prev2):
            # converged: the last small step, and the model's cost there (``_gauss_newton``)
            cost = max(0.0, cost - (g1 * sx + g2 * sy + g3 * sz))
            return x - sx, y - sy, z - sz, _sqrt(cost / n)
        prev2 = step2
        allowed = cost + (GN_COST_REL_TOL * cost + GN_COST_ROUND_M * _sqrt(cost))
        for _halving in range(GN_MAX_HALVINGS):
            tx, ty, tz = x - sx, y - sy, z - sz
            p = (tx, ty, tz)
            # J^T r = sum (P - A_i) k_i = P sum k_i - sum A_i k_i (k_i = r_i / d_i)
            tc = kk = h1 = h2 = h3 = 0.0
            try:
                for a, ln in zip(anchors, lengths, strict=True):
                    d = _dist(p, a)
                    res = d - ln
                    tc += res * res
                    k = res / d
                    kk += k
                    ax, ay, az = a
                    h1 += ax * k
                    h2 += ay * k
                    h3 += az * k
                h1 = tx * kk - h1
                h2 = ty * kk - h2
                h3 = tz * kk - h3
            except ZeroDivisionError:
                tc, h1, h2, h3 = _cost_grad(anchors, lengths, tx, ty, tz)
            if tc <= allowed:
                break
            sx, sy, sz = 0.5 * sx, 0.5 * sy, 0.5 * sz
        else:
            return x, y, z, _sqrt(cost / n)  # no decrease along the step: at the minimum
        x, y, z = tx, ty, tz
        cost, g1, g2, g3 = tc, h1, h2, h3
    return _gauss_newton(anchors, lengths, x, y, z, None, GN_AMONG_NEXT_TOL2)


def _others_cost(
    anchors: tuple[Vec3, ...], lo: Sequence[float], x: float, y: float, z: float
) -> tuple[float, float]:
    """Sum and largest of the squared residuals of the cables outside the seed triple."""
    sumsq = worst = 0.0
    for (ax, ay, az), ln in zip(anchors, lo, strict=True):
        dx = x - ax
        dy = y - ay
        dz = z - az
        res = _sqrt(dx * dx + dy * dy + dz * dz) - ln
        sq = res * res
        sumsq += sq
        if sq > worst:
            worst = sq
    return sumsq, worst


def _refine(
    geom: Geometry, lengths: Sequence[float], x: float, y: float, z: float
) -> tuple[float, float, float, float]:
    """The least-squares point over all cables from the seed (x, y, z), and its RMS residual."""
    fit = geom._fit
    lo = [lengths[j] for j in fit.others]
    cost, worst = _others_cost(fit.anchors, lo, x, y, z)
    if worst <= GN_STEP_TOL_M * GN_STEP_TOL_M:  # consistent lengths: the seed is the fit
        return x, y, z, _sqrt(cost / geom.n_cables)
    p4 = geom._p4
    if p4 is not None:
        done = _fit_planar4(p4, lengths, cost)
        if done is not None:
            return done
    if fit.tilt is not None:
        mx, my, mz = _mirror(fit.tilt, x, y, z)
        # Only a mirror image below every anchor is a place the robot can hang (above them,
        # with noisy lengths on a poorly conditioned layout, it can even fit better).
        if mz < geom.anchor_height_min_m and _others_cost(fit.anchors, lo, mx, my, mz)[0] < cost:
            # The other cables side with the mirror image: fit from there.
            return _gauss_newton(geom._anchors_t, lengths, mx, my, mz, None)
    sd = geom._seed
    mirror = sd.zn if geom.equal_heights and isinstance(sd, _EqualSeed) else None
    return _gauss_newton(geom._anchors_t, lengths, x, y, z, mirror)


def _inner_seed(geom: Geometry, x: float, y: float, z: float) -> Vec3:
    """The seed triple's three-spheres point on the hull's side of the triple's plane, from
    its lower one (x, y, z)."""
    if not geom.seed_up:
        return x, y, z
    sd = geom._seed
    if isinstance(sd, _EqualSeed):
        return x, y, 2.0 * sd.zn - z
    tilt = geom._fit.tilt
    assert tilt is not None  # a general seed's plane is not level
    return _mirror(tilt, x, y, z)


def _fpk_among(geom: Geometry, lengths: list[float], seed_m: Sequence[float] | None) -> FpkResult:
    """``fpk`` for an effector among its anchors (module docstring)."""
    anchors = geom._anchors_t
    tri = geom.seed_triple
    fit = geom._among
    assert fit is not None  # made with every geometry among its anchors
    best: tuple[float, float, float, float] | None = None
    if seed_m is not None and len(seed_m) == 3:
        gx, gy, gz = float(seed_m[0]), float(seed_m[1]), float(seed_m[2])
        if math.isfinite(gx) and math.isfinite(gy) and math.isfinite(gz):
            best = fit(lengths, gx, gy, gz) or _gauss_newton_among(anchors, lengths, gx, gy, gz)
            if best[3] <= RETRY_RMS_M:
                return FpkResult((best[0], best[1], best[2]), best[3], tri)
    lin = geom._lin
    res = fit(lengths, None, 0.0, 0.0) if lin is not None else None
    if res is None:
        if lin is not None:
            # The linearised trilateration of every cable: no mirror image, within the noise.
            x, y, z = lin.p0
            for (wx, wy, wz), ln in zip(lin.w, lengths, strict=True):
                s = ln * ln
                x -= wx * s
                y -= wy * s
                z -= wz * s
        else:  # pragma: no cover - among the anchors they never lie in one plane
            sd = geom._seed
            r1, r2, r3 = lengths[sd.i1], lengths[sd.i2], lengths[sd.i3]
            if isinstance(sd, _EqualSeed):
                x, y, z = _seed_equal(sd, r1, r2, r3, True)
            else:
                x, y, z = _seed_general(sd, r1, r2, r3, True)
            x, y, z = _inner_seed(geom, x, y, z)
        res = _gauss_newton_among(anchors, lengths, x, y, z)
    if best is not None and best[3] < res[3]:
        res = best
    return FpkResult((res[0], res[1], res[2]), res[3], tri)


def _fpk(geom: Geometry, lengths: list[float], seed_m: Sequence[float] | None = None) -> FpkResult:
    """``fpk`` on a list of floats."""
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
    if not geom.hanging:
        res = _fpk_among(geom, lengths, seed_m)
        p = res.position_m
        if not (math.isfinite(p[0] + p[1] + p[2]) and math.isfinite(res.residual_m)):
            raise KinematicsError("FPK produced a non-finite result")  # defensive
        return res
    r1, r2, r3 = lengths[sd.i1], lengths[sd.i2], lengths[sd.i3]
    tri = geom.seed_triple
    try:
        if isinstance(sd, _EqualSeed):
            x, y, z = _seed_equal(sd, r1, r2, r3)
        else:
            x, y, z = _seed_general(sd, r1, r2, r3)
    except UnreachableError:
        if n == 3:
            raise
        return _fpk_seed_missed(geom, lengths)
    if n == 3:
        return FpkResult((x, y, z), 0.0, tri)
    x, y, z, rms = _refine(geom, lengths, x, y, z)
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z) and math.isfinite(rms)):
        raise KinematicsError("FPK produced a non-finite result")  # defensive, not expected
    return FpkResult((x, y, z), rms, tri)


def _fpk_seed_missed(geom: Geometry, lengths: list[float]) -> FpkResult:
    """A hanging robot's fit when its seed triple's spheres miss each other (N > 3): from the
    first other usable triple whose spheres meet, over every cable; it stands when its RMS
    residual is at most ``SEED_MISS_FIT_RMS_M``.  Raises the seed triple's ``UnreachableError``
    otherwise (no triple meets, or no point explains the lengths)."""
    anchors = geom._anchors_t
    for tri in geom.triples:
        if tri == geom.seed_triple:
            continue
        i, j, k = tri
        try:
            x, y, z = three_spheres(
                anchors[i], anchors[j], anchors[k], lengths[i], lengths[j], lengths[k]
            )
        except KinematicsError:  # this triple misses too (or is singular in plan view)
            continue
        sd = geom._seed
        mirror = sd.zn if geom.equal_heights and isinstance(sd, _EqualSeed) else None
        x, y, z, rms = _gauss_newton(anchors, lengths, x, y, z, mirror)
        if rms <= SEED_MISS_FIT_RMS_M and math.isfinite(x + y + z):
            return FpkResult((x, y, z), rms, tri)
        break
    sd = geom._seed
    r = (lengths[sd.i1], lengths[sd.i2], lengths[sd.i3])
    if isinstance(sd, _EqualSeed):
        _seed_equal(sd, *r)
    else:
        _seed_general(sd, *r)
    raise KinematicsError("the seed triple's spheres miss each other")  # pragma: no cover


def fpk(
    geom: Geometry,
    lengths_m: Sequence[float] | FloatArray,
    seed_m: Sequence[float] | None = None,
) -> FpkResult:
    """Forward pose kinematics of one pose: the point P where the N cables meet.

    ``lengths_m``: the N cable lengths, a sequence or an array of shape (N,) (many poses at
    once: ``fpk_batch``).  The seed triple's three-spheres point, then for N > 3 the
    least-squares fit over all cables (see the module docstring); ``residual_m`` is the RMS
    cable-length mismatch.  ``seed_m``: the last pose, when the caller has one; it seeds the
    fit of an effector among its anchors (``Geometry.hanging`` False) and is not needed for
    a hanging one (ignored there).  Raises ``KinematicsError`` for a wrong shape or count or
    for non-finite / non-positive lengths, and ``UnreachableError`` (naming the 1-based cable
    and its shortfall) when the seed triple cannot meet (with more than three cables: unless
    another triple meets and the fit from it over every cable leaves at most
    ``SEED_MISS_FIT_RMS_M``).
    """
    if isinstance(lengths_m, np.ndarray):
        if lengths_m.ndim != 1:
            raise KinematicsError(
                f"lengths must have shape (N,), got {lengths_m.shape} (fpk_batch takes (M, N))"
            )
        return _fpk(geom, lengths_m.tolist(), seed_m)
    return _fpk(geom, list(map(float, lengths_m)), seed_m)
