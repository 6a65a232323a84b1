"""What the least-squares fit (``fit``) precomputes from the anchors, once per ``Geometry``.

``_Fit``: the cables outside the seed triple and, when that triple is tilted, its plane.
``_Planar4``: the constants of the one-multiplier fit for four anchors at one height (see the
``fit`` module docstring); the Gauss-Newton fit's tolerances (``fit``, ``fitgen``). Pure
Python floats; depends only on the seed (``spheres``), so that
``geometry`` can build these without importing the fit itself.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from controller.core.kinematics.spheres import Vec3, _EqualSeed

#: Gauss-Newton stops when the step is below this; other cables agreeing with the seed to
#: this are consistent (no fit).
GN_STEP_TOL_M = 1e-12
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
#: Among the anchors Gauss-Newton stops once the next step, predicted from the convergence rate,
#: is under sqrt(this) = 1e-8 m (10 nm, far below any encoder): one evaluation fewer per call.
GN_AMONG_NEXT_TOL2 = 1e-16


@dataclass(frozen=True, slots=True)
class _Fit:
    """The cables outside the seed triple, and the triple's plane when it is tilted."""

    others: tuple[int, ...]  # 0-based
    anchors: tuple[Vec3, ...]  # their anchors
    # Unit normal (n_z > 0) and a point of a tilted triple's plane (None when level): the
    # three spheres also meet at the seed's mirror image in that plane, which can be the
    # robot's position (above the plane yet below every anchor).
    tilt: tuple[Vec3, Vec3] | None


def _make_fit(pts: Sequence[Vec3], tri: tuple[int, int, int]) -> _Fit:
    (x0, y0, z0), (x1, y1, z1), (x2, y2, z2) = (pts[k] for k in tri)
    ux, uy, uz = x2 - x0, y2 - y0, z2 - z0
    vx, vy, vz = x2 - x1, y2 - y1, z2 - z1
    ax, ay, az = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx  # the plane's normal
    norm = math.sqrt(ax * ax + ay * ay + az * az)
    sg = 1.0 if az > 0.0 else -1.0
    others = tuple(k for k in range(len(pts)) if k not in tri)
    return _Fit(
        others=others,
        anchors=tuple(pts[j] for j in others),
        tilt=None
        if ax == 0.0 and ay == 0.0
        else ((ax / norm * sg, ay / norm * sg, az / norm * sg), pts[tri[0]]),
    )


@dataclass(frozen=True, slots=True)
class _Planar4:
    """Constants of the fit for four anchors at one height (see the module docstring)."""

    sd: _EqualSeed  # the seed triple
    k4: int  # the fourth cable (0-based)
    b4: Vec3  # its anchor
    c: Vec3  # barycentric coordinates of the fourth anchor
    m0: float
    curv: float  # bound on |phi'' / (2 phi')|: Newton's error is curv * step^2


def _make_planar4(pts: Sequence[Vec3], sd: _EqualSeed, others: tuple[int, ...]) -> _Planar4 | None:
    if len(others) != 1:
        return None
    k4 = others[0]
    if any(pts[k][2] != sd.zn for k in (*sd.tri, k4)):
        return None  # the identity for D2 needs the fourth anchor exactly at the seed's height
    (x1, y1, _), (x2, y2, _), (x3, y3, _) = sd.centres
    b4 = pts[k4]
    # Plan-view barycentric coordinates (the triple is not collinear in plan view).
    det = (x1 - x3) * (y2 - y3) - (x2 - x3) * (y1 - y3)
    c1 = ((b4[0] - x3) * (y2 - y3) - (x2 - x3) * (b4[1] - y3)) / det
    c2 = ((x1 - x3) * (b4[1] - y3) - (b4[0] - x3) * (y1 - y3)) / det
    c3 = 1.0 - c1 - c2
    m0 = -sum(ck * math.dist(pts[k], b4) ** 2 for ck, k in zip((c1, c2, c3), sd.tri, strict=True))
    cmax = max(1.0, abs(c1), abs(c2), abs(c3))
    return _Planar4(sd, k4, b4, (c1, c2, c3), m0, 3.0 * cmax)


@dataclass(frozen=True, slots=True)
class _Linear:
    """The linearised trilateration of anchors not in one plane: subtracting the mean of the
    spheres ``|P - A_i|^2 = L_i^2`` from each leaves ``2 (A_i - A_mean) . P = c_i - L_i^2 +
    mean(L^2)``, linear in P; its least-squares solution is ``p0 - sum_i w_i L_i^2`` (the
    mean's term drops out, the ``A_i - A_mean`` summing to zero). Exact for consistent
    lengths, within the noise otherwise, and with no mirror image."""

    p0: Vec3
    w: tuple[Vec3, ...]


def _make_linear(pts: Sequence[Vec3]) -> _Linear | None:
    """The linearised trilateration's constants; None when the anchors lie in one plane."""
    n = len(pts)
    mx = sum(p[0] for p in pts) / n
    my = sum(p[1] for p in pts) / n
    mz = sum(p[2] for p in pts) / n
    sq = [p[0] * p[0] + p[1] * p[1] + p[2] * p[2] for p in pts]
    msq = sum(sq) / n
    d = [(p[0] - mx, p[1] - my, p[2] - mz) for p in pts]
    a11 = 2.0 * sum(x * x for x, _, _ in d)
    a12 = 2.0 * sum(x * y for x, y, _ in d)
    a13 = 2.0 * sum(x * z for x, _, z in d)
    a22 = 2.0 * sum(y * y for _, y, _ in d)
    a23 = 2.0 * sum(y * z for _, y, z in d)
    a33 = 2.0 * sum(z * z for _, _, z in d)
    c11 = a22 * a33 - a23 * a23
    c12 = a13 * a23 - a12 * a33
    c13 = a12 * a23 - a13 * a22
    det = a11 * c11 + a12 * c12 + a13 * c13
    scale = (a11 + a22 + a33) ** 3
    if not abs(det) > 1e-12 * scale:
        return None
    c22 = a11 * a33 - a13 * a13
    c23 = a12 * a13 - a11 * a23
    c33 = a11 * a22 - a12 * a12

    def k(v: Vec3) -> Vec3:
        return (
            (c11 * v[0] + c12 * v[1] + c13 * v[2]) / det,
            (c12 * v[0] + c22 * v[1] + c23 * v[2]) / det,
            (c13 * v[0] + c23 * v[1] + c33 * v[2]) / det,
        )

    w = tuple(k(di) for di in d)
    cx = sum(di[0] * (sq[i] - msq) for i, di in enumerate(d))
    cy = sum(di[1] * (sq[i] - msq) for i, di in enumerate(d))
    cz = sum(di[2] * (sq[i] - msq) for i, di in enumerate(d))
    return _Linear(k((cx, cy, cz)), w)
