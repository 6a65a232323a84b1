"""The derivative of the three- and four-cable tension distribution with respect to the
effector's position (``CableStatics.tension_derivative``).

Differentiating ``U(P) t = f`` (f fixed) gives ``U T' = G`` with ``G = sum_i t_i (I - u_i
u_i^T) / L_i``; for four cables the distribution also keeps its two binding distances to the
limits equal (the rising and the falling line of ``tension_math.maxmin_lambda`` that cross at
its optimum), which fixes the null-space part.  Pure module (``math``), plain floats.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from controller.core.statics_errors import SingularConfiguration
from controller.core.tension_math import TRIPLES4, det3, triple_solve

__all__ = ["derivative34"]


def derivative34(
    anchors_t: Sequence[tuple[float, float, float]],
    t_min_n: float,
    t_max_n: float,
    point_m: Sequence[float],
    u: list[tuple[float, float, float]],
    tensions_n: Sequence[float],
    nv: list[float] | None,
) -> tuple[tuple[float, float, float], ...] | None:
    """d t_i / d P of the three- or four-cable distribution at P (``CableStatics
    .tension_derivative``) from the unit vectors `u` at P and, for four cables, the null
    vector `nv` of the solve (None: computed here).  Raises ``SingularConfiguration`` where
    the directions do not span space."""
    nc = len(anchors_t)
    # G = sum_i t_i (I - u_i u_i^T) / L_i: how the directions turn with P, weighted by tension
    px, py, pz = float(point_m[0]), float(point_m[1]), float(point_m[2])
    g11 = g12 = g13 = g22 = g23 = g33 = 0.0
    for i, (ax, ay, az) in enumerate(anchors_t):
        ux, uy, uz = u[i]
        dx, dy, dz = ax - px, ay - py, az - pz
        k = float(tensions_n[i]) / math.sqrt(dx * dx + dy * dy + dz * dz)
        g11 += k * (1.0 - ux * ux)
        g22 += k * (1.0 - uy * uy)
        g33 += k * (1.0 - uz * uz)
        g12 -= k * ux * uy
        g13 -= k * ux * uz
        g23 -= k * uy * uz
    gc = ((g11, g12, g13), (g12, g22, g23), (g13, g23, g33))  # columns (symmetric)
    if nc == 3:
        x = triple_solve(u, (0, 1, 2), gc)
        if x is None:
            raise SingularConfiguration(
                "the three cable directions are coplanar: they cannot balance the weight"
            )
        return (x[0], x[1], x[2])
    # Four cables: a particular solution on the best-conditioned triple, plus mu n.
    if nv is None:
        nv = []
        for q, (a, b, c) in enumerate(TRIPLES4):
            ax, ay, az = u[a]
            bx, by, bz = u[b]
            cx, cy, cz = u[c]
            d = det3(ax, ay, az, bx, by, bz, cx, cy, cz)
            nv.append(-d if q & 1 else d)
    j = 0
    for q in range(1, 4):
        if abs(nv[q]) > abs(nv[j]):
            j = q
    triple = TRIPLES4[j]
    xt = triple_solve(u, triple, gc)
    if xt is None:
        raise SingularConfiguration(
            "the four cable directions do not span space: they cannot balance the weight"
        )
    rows: list[tuple[float, float, float]] = [(0.0, 0.0, 0.0)] * 4
    for q, i in enumerate(triple):
        rows[i] = xt[q]
    # The binding pair: the lowest rising and the lowest falling distance-to-limit line in
    # the null-space coordinate (rising: grows along +n); sigma = +1 for t - t_min, -1 for
    # t_max - t.  Lines tied with the lowest (a symmetric pose: the robot's centre) are
    # candidates; per axis the pair whose lines stay lowest on the + side is taken (the
    # forward derivative, the same on both sides where the tensions are smooth).
    lo, hi = t_min_n, t_max_n
    n0, n1, n2, n3 = nv
    flat_nv = 1e-12 * max(abs(n0), abs(n1), abs(n2), abs(n3))
    fast = _one_pair(t_min_n, t_max_n, tensions_n, nv, rows, flat_nv)
    if fast is not None:
        return fast
    big = hi
    best_r = best_f = flat = math.inf
    lines: list[tuple[float, int, float, bool]] = []  # (distance, cable, sigma, rising)
    for i in range(4):
        ti = float(tensions_n[i])
        if abs(ti) > big:
            big = abs(ti)
        ni = nv[i]
        d_lo, d_hi = ti - lo, hi - ti
        if abs(ni) <= flat_nv:
            flat = min(flat, d_lo, d_hi)
            continue
        if ni > 0.0:  # t - t_min rises along +n, t_max - t falls
            lines.append((d_lo, i, 1.0, True))
            lines.append((d_hi, i, -1.0, False))
            best_r = min(best_r, d_lo)
            best_f = min(best_f, d_hi)
        else:
            lines.append((d_hi, i, -1.0, True))
            lines.append((d_lo, i, 1.0, False))
            best_r = min(best_r, d_hi)
            best_f = min(best_f, d_lo)
    tol = 1e-9 * (big + hi)
    if best_r == math.inf or best_f == math.inf or flat <= max(best_r, best_f) + tol:
        return None  # no crossing, or a flat line binds
    cand_r = [(i, sg) for d, i, sg, up in lines if up and d <= best_r + tol]
    cand_f = [(i, sg) for d, i, sg, up in lines if not up and d <= best_f + tol]
    pairs: list[tuple[int, float, int, float, float, float, float]] = []
    for r_i, r_sig in cand_r:
        xr = rows[r_i]
        for f_i, f_sig in cand_f:
            cn = r_sig * nv[r_i] - f_sig * nv[f_i]
            if abs(cn) > 0.0:
                xf = rows[f_i]
                pairs.append(
                    (
                        r_i,
                        r_sig,
                        f_i,
                        f_sig,
                        -(r_sig * xr[0] - f_sig * xf[0]) / cn,
                        -(r_sig * xr[1] - f_sig * xf[1]) / cn,
                        -(r_sig * xr[2] - f_sig * xf[2]) / cn,
                    )
                )
    if not pairs:
        return None
    if len(pairs) == 1:
        _, _, _, _, m0, m1, m2 = pairs[0]
        return tuple(
            [
                (rows[i][0] + m0 * nv[i], rows[i][1] + m1 * nv[i], rows[i][2] + m2 * nv[i])
                for i in range(4)
            ]
        )
    cols: list[list[float]] = []
    for k in range(3):
        col: list[float] | None = None
        for r_i, r_sig, f_i, f_sig, *mus in pairs:
            mk = mus[k]
            dc = [rows[i][k] + mk * nv[i] for i in range(4)]
            if col is None:
                col = dc
            rate_r = r_sig * dc[r_i] - tol
            rate_f = f_sig * dc[f_i] - tol
            if all(sg * dc[i] >= rate_r for i, sg in cand_r) and all(
                sg * dc[i] >= rate_f for i, sg in cand_f
            ):
                col = dc
                break
        assert col is not None
        cols.append(col)
    return tuple([(cols[0][i], cols[1][i], cols[2][i]) for i in range(4)])


def _one_pair(
    t_min_n: float,
    t_max_n: float,
    tensions_n: Sequence[float],
    nv: list[float],
    rows: list[tuple[float, float, float]],
    flat_nv: float,
) -> tuple[tuple[float, float, float], ...] | None:
    """``_derivative``'s usual case for four cables, without its candidate lists: one
    rising and one falling line lowest by more than the tolerance and no flat line near
    them bind on both sides.  None when that is not the case (``_derivative`` then
    decides)."""
    lo, hi = t_min_n, t_max_n
    big = hi
    br = bf = second_r = second_f = flat = math.inf
    ir = jf = -1
    sig_r = sig_f = 0.0
    for i in range(4):
        ti = float(tensions_n[i])
        if ti > big:
            big = ti
        elif -ti > big:
            big = -ti
        ni = nv[i]
        d_lo = ti - lo
        d_hi = hi - ti
        if -flat_nv <= ni <= flat_nv:
            flat = min(flat, d_lo, d_hi)
            continue
        if ni > 0.0:
            dr, gr, df, gf = d_lo, 1.0, d_hi, -1.0
        else:
            dr, gr, df, gf = d_hi, -1.0, d_lo, 1.0
        if dr < br:
            second_r, br, ir, sig_r = br, dr, i, gr
        elif dr < second_r:
            second_r = dr
        if df < bf:
            second_f, bf, jf, sig_f = bf, df, i, gf
        elif df < second_f:
            second_f = df
    tol = 1e-9 * (big + hi)
    if not (ir >= 0 and second_r > br + tol and second_f > bf + tol):
        return None
    if not flat > max(br, bf) + tol:
        return None
    cn = sig_r * nv[ir] - sig_f * nv[jf]
    if cn == 0.0:
        return None
    xr = rows[ir]
    xf = rows[jf]
    m0 = -(sig_r * xr[0] - sig_f * xf[0]) / cn
    m1 = -(sig_r * xr[1] - sig_f * xf[1]) / cn
    m2 = -(sig_r * xr[2] - sig_f * xf[2]) / cn
    return tuple(
        [
            (rows[i][0] + m0 * nv[i], rows[i][1] + m1 * nv[i], rows[i][2] + m2 * nv[i])
            for i in range(4)
        ]
    )
