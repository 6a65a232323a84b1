"""Scalar pieces of the tension solve for three and four cables: 3x3 determinants and Cramer
solves on a triple of cable directions, and the max-min of the distances to the tension limits
along the null space (``controller.core.statics`` builds the distribution and its derivative
from them).

Pure module (``math`` only), no I/O; plain floats and tuples, as the per-tick path wants them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["RANK_TOL", "SLACK", "TRIPLES4", "det3", "maxmin_lambda", "triple_solve"]

RANK_TOL = 1e-9
"""Smallest ``sqrt(det(U U^T))`` (unit columns, dimensionless) accepted as spanning space.

Below it the tensions would exceed about 1e9 times the weight."""

# N = 4: lambda is chosen among the lines within this fraction of the largest intercept of the
# optimum (see maxmin_lambda); the margin given up is at most that, ~1e-12 relative.
SLACK = 1e-12


def det3(
    ax: float,
    ay: float,
    az: float,
    bx: float,
    by: float,
    bz: float,
    cx: float,
    cy: float,
    cz: float,
) -> float:
    """The determinant of the 3x3 matrix of rows a, b, c."""
    return ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)


# For N = 4: the triple left when cable j is removed, in ascending order.
TRIPLES4 = ((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2))


def triple_solve(
    u: Sequence[tuple[float, float, float]],
    triple: tuple[int, int, int],
    cols: tuple[tuple[float, float, float], ...],
) -> tuple[tuple[float, float, float], ...] | None:
    """x with ``sum_{i in triple} u_i x_i[k] = cols[k]`` for each k (Cramer: row i of the
    inverse of [u_a u_b u_c] is the cross product of the other two over the determinant), one
    row (x[k] for k = 0..2) per cable of the triple; None when the triple is coplanar."""
    a, b, c = triple
    ax, ay, az = u[a]
    bx, by, bz = u[b]
    cx, cy, cz = u[c]
    det = det3(ax, ay, az, bx, by, bz, cx, cy, cz)
    if not abs(det) >= RANK_TOL:
        return None
    inv = 1.0 / det
    ra = ((by * cz - bz * cy) * inv, (bz * cx - bx * cz) * inv, (bx * cy - by * cx) * inv)
    rb = ((cy * az - cz * ay) * inv, (cz * ax - cx * az) * inv, (cx * ay - cy * ax) * inv)
    rc = ((ay * bz - az * by) * inv, (az * bx - ax * bz) * inv, (ax * by - ay * bx) * inv)
    out = []
    for r in (ra, rb, rc):
        out.append(
            (
                r[0] * cols[0][0] + r[1] * cols[0][1] + r[2] * cols[0][2],
                r[0] * cols[1][0] + r[1] * cols[1][1] + r[2] * cols[1][2],
                r[0] * cols[2][0] + r[1] * cols[2][1] + r[2] * cols[2][2],
            )
        )
    return tuple(out)


def maxmin_lambda(tp: list[float], s: list[float], lo: float, hi: float) -> float:
    """lambda maximising min_i min(tp_i + lambda s_i - lo, hi - tp_i - lambda s_i) (|s| = 1).

    Cable i contributes a rising line (intercept a_i, slope |s_i|) and a falling one
    (intercept b_i, slope |s_i|): (tp_i - lo, hi - tp_i) when s_i >= 0, the other way round
    when s_i < 0.  The maximum of the lower envelope is the least crossing value of a rising
    and a falling line (a flat line, s_i = 0, enters through its pairs with sloped lines), and
    lambda is the middle of the interval where every line is within ``SLACK`` of it (a point
    up to rounding unless a flat line binds; the slack keeps a nearly flat line from turning
    the rounding of the maximum into a large error in lambda).
    """
    # Per-tick path (every tension solve of four cables): indexed lists and plain loops.
    n = len(tp)
    ra = [0.0] * n
    fa = [0.0] * n
    rs = [0.0] * n
    big = hi
    for i in range(n):
        ti = tp[i]
        si = s[i]
        if si >= 0.0:
            ra[i] = ti - lo
            fa[i] = hi - ti
            rs[i] = si
        else:
            ra[i] = hi - ti
            fa[i] = ti - lo
            rs[i] = -si
        if ti > big:
            big = ti
        elif -ti > big:
            big = -ti
    best = math.inf
    for i in range(n):
        a = ra[i]
        r = rs[i]
        for j in range(n):
            f = rs[j]
            den = r + f
            if den > 0.0:
                v = (a * f + fa[j] * r) / den
                if v < best:
                    best = v
    floor = best - SLACK * (big + hi)
    lam_lo = -math.inf
    lam_hi = math.inf
    for i in range(n):
        r = rs[i]
        if r > 0.0:
            x = (floor - ra[i]) / r
            if x > lam_lo:
                lam_lo = x
            x = (fa[i] - floor) / r
            if x < lam_hi:
                lam_hi = x
    return 0.5 * (lam_lo + lam_hi)
