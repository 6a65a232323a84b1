"""Tensions of five or more cables: the max-min rule made strictly convex, fast enough to tick.

Pure module (``math``, ``numpy``), no I/O; a degenerate tie beyond rounding is left to the
statics module's linear program.

The rule (``controller.core.statics``): maximise the smallest distance ``s`` of any tension to
the limits ``[lo, hi]`` subject to ``U t = f``.  With the middle of the range ``c = (lo + hi)
/ 2`` and its half ``r = (hi - lo) / 2``, write ``t = c + d``: then ``s = r - max_i |d_i|``,
so the answer is the distribution nearest the middle of the range in the max norm,

    minimise rho = max_i |d_i|   subject to   U d = g,   g = f - c sum_i u_i.

Its dual is ``rho = max over w of (w . g) / sum_i |u_i . w|``.  The ratio is homogeneous in w
and linear-fractional on each cell of the arrangement of the planes ``u_i . w = 0``, so its
maximum is at a vertex of the arrangement: ``w = u_a x u_b`` for a pair of cables (either
sign gives the same absolute ratio).  So

    rho = max over the N (N - 1) / 2 pairs (a, b) of |w . g| / sum_i |u_i . w|,

and at the best pair complementary slackness puts every other cable at the same distance from
a limit, ``d_i = rho sgn(w . g) sgn(u_i . w)``, while the pair's own two follow from ``U d =
g``: with ``h = g - sum_others d_i u_i`` (which is perpendicular to w), ``d_a = ((h x u_b) .
w) / |w|^2`` and ``d_b = ((u_a x h) . w) / |w|^2``.  A pair whose two are within ``rho`` is
optimal (the primal and dual values agree); when every other cable has ``u_i . w`` away from
zero the optimum is unique (strict complementarity).

``pivot_solve`` reaches the optimal pair by the dual simplex from the last one (none between
ticks) or, far from the last pose, from the two cables most nearly perpendicular to g
(``freest_pair``: one or two pivots); ``best_pairs`` computes every pair's ratio at
once with numpy where a pair on the way is degenerate (a symmetric pose: cables in the pair's
plane share the rest of g, again as near the middle as they can, ``_plane_solve``).

With two or more spare dimensions (N >= 5) the optimum of this linear program can jump from
one vertex to another as the pose moves (by tens of newtons on an eight-cable cube, where the
optimal pair switches).  The planned distribution is therefore the unique minimiser of the
strictly convex ``rho + eps / 2 |d|^2`` (``regularised``; ``eps = 2 REGULARISE / (N r)`` bounds
its largest deviation by ``(1 + REGULARISE) rho*`` where the limits can be kept), solved by an
active set started from the last pose's bound cables (the tick: one 3x3 solve) or from the
max-min vertex.  ``project`` takes the rounding out of the equilibrium.  Nearly everywhere
that answer frees two cables and binds the rest, and then it is the max-min vertex itself:
``settles`` tells so from the vertex's own numbers (its bound cables' multipliers are not
negative) and ``vertex_tensions`` returns it with one refinement, with no active-set solve.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from controller.core.statics_errors import SingularConfiguration
from controller.core.tension_batch import ANCHOR_TOL_M, UP_TOL
from controller.core.tension_math import RANK_TOL

__all__ = [
    "MANY_TOL",
    "REGULARISE",
    "PairSolution",
    "Pairs",
    "best_pairs",
    "finite_tensions",
    "freest_pair",
    "pair_solution",
    "pivot_solve",
    "project",
    "regularised",
    "settles",
    "sum_units",
    "units_and_sum",
    "vertex_tensions",
]

Vec3 = tuple[float, float, float]


MANY_TOL = 1e-9
"""Relative tolerance of the pair tests: a pair's own distances may exceed the others' by
this fraction of the tensions' scale (rounding), and a cable with ``|u_i . w|`` below this
fraction of ``|w|`` lies in the pair's plane (the optimum may not be unique there)."""

REGULARISE = 0.05
"""The strictly convex term of the planned distribution: its largest deviation from the middle
of the range is at most this fraction more than the max-min's where the limits can be kept
(``regularised``)."""

# w = a x b from the outer product a b^T flattened (index 3 i + j): the Levi-Civita map.
_CROSS = np.zeros((9, 3))
_CROSS[5, 0], _CROSS[7, 0] = 1.0, -1.0
_CROSS[6, 1], _CROSS[2, 1] = 1.0, -1.0
_CROSS[1, 2], _CROSS[3, 2] = 1.0, -1.0
_CROSS.setflags(write=False)


@dataclass(frozen=True, slots=True)
class Pairs:
    """The pairs of cables of an N-cable layout, as index arrays and as tuples."""

    first: NDArray[np.intp]
    second: NDArray[np.intp]
    pairs: tuple[tuple[int, int], ...]

    @classmethod
    def of(cls, n: int) -> Pairs:
        """Every pair (a, b), a < b, of ``n`` cables."""
        pairs = tuple(itertools.combinations(range(n), 2))
        first = np.array([p[0] for p in pairs], dtype=np.intp)
        second = np.array([p[1] for p in pairs], dtype=np.intp)
        first.setflags(write=False)
        second.setflags(write=False)
        return cls(first, second, pairs)


@dataclass(slots=True)
class PairSolution:
    """The distribution a pair (a, b) gives: the deviations ``d`` from the middle of the range,
    ``rho`` (the others' common distance), whether the pair's own two are within it
    (``optimal``), whether no other cable lies in the pair's plane (``unique``), and the signs
    ``sgn_i`` of the others (0 for the pair itself and for cables in its plane)."""

    a: int
    b: int
    d: list[float]
    rho: float
    optimal: bool
    unique: bool
    signs: list[float]
    w: Vec3
    """``u_a x u_b``, turned so that ``w . g >= 0``."""
    q: list[float]
    """``u_i . w`` per cable (0 for the pair)."""
    v: Vec3 | None = None
    """``sum_i sgn_i u_i`` over the others when every other cable has a sign (``pivot_solve``'s
    answers; None otherwise): what ``settles`` and ``vertex_tensions`` need."""
    den: float = 0.0
    """``sum_i |u_i . w|`` over the others (``w . v``)."""
    qmin: float = 0.0
    """The smallest ``|u_i . w|`` of the others: how far the nearest lies from the pair's
    plane."""


def pair_solution(u: Sequence[Vec3], g: Vec3, a: int, b: int, scale: float) -> PairSolution | None:
    """The distribution of the pair (a, b) for directions `u` and ``g = f - c sum u_i`` (module
    docstring); `scale` sizes the tolerance (newtons).  None when the pair's directions are
    parallel or every other cable lies in their plane.

    Cables in the pair's plane (a symmetric pose) have no sign: any deviation up to ``rho``
    keeps the optimum, so they share the plane's part of g with the pair, again as near the
    middle as they can (``_plane_solve``: the max-min rule applied once more among them)."""
    ax, ay, az = u[a]
    bx, by, bz = u[b]
    wx = ay * bz - az * by
    wy = az * bx - ax * bz
    wz = ax * by - ay * bx
    ww = wx * wx + wy * wy + wz * wz
    if not ww > 1e-24:
        return None
    gx, gy, gz = g
    wg = wx * gx + wy * gy + wz * gz
    sg = -1.0 if wg < 0.0 else 1.0
    flat = MANY_TOL * math.sqrt(ww)
    n = len(u)
    signs = [0.0] * n
    qs = [0.0] * n
    den = 0.0
    plane = [a, b]
    for i in range(n):
        if i in (a, b):
            continue
        x, y, z = u[i]
        q = x * wx + y * wy + z * wz
        qs[i] = sg * q
        if q > flat:
            signs[i] = sg
            den += q
        elif q < -flat:
            signs[i] = -sg
            den -= q
        else:
            plane.append(i)
            den += abs(q)
    if not den > 0.0:
        return None
    rho = abs(wg) / den
    d = [0.0] * n
    hx, hy, hz = gx, gy, gz
    for i in range(n):
        si = signs[i]
        if si != 0.0:
            di = si * rho
            d[i] = di
            x, y, z = u[i]
            hx -= di * x
            hy -= di * y
            hz -= di * z
    lim = rho + MANY_TOL * scale
    if len(plane) == 2:
        # h = d_a u_a + d_b u_b: cross with u_b (resp. u_a) and project on w.
        da = ((hy * bz - hz * by) * wx + (hz * bx - hx * bz) * wy + (hx * by - hy * bx) * wz) / ww
        db = ((ay * hz - az * hy) * wx + (az * hx - ax * hz) * wy + (ax * hy - ay * hx) * wz) / ww
        d[a] = da
        d[b] = db
        ok = abs(da) <= lim and abs(db) <= lim
        return PairSolution(a, b, d, rho, ok, True, signs, (sg * wx, sg * wy, sg * wz), qs)
    inner = _plane_solve(u, plane, (hx, hy, hz), (wx, wy, wz), scale)
    if inner is None:
        return None
    for i, di in zip(plane, inner, strict=True):
        d[i] = di
    ok = max(abs(v) for v in inner) <= lim
    return PairSolution(a, b, d, rho, ok, False, signs, (sg * wx, sg * wy, sg * wz), qs)


def pivot_solve(
    u: Sequence[Vec3], g: Vec3, a: int, b: int, scale: float, max_pivots: int
) -> PairSolution | None:
    """The unique optimal pair reached from the pair (a, b) by the dual simplex: while one
    of the pair's own deviations exceeds rho, w turns about the other cable of the pair
    (along an edge of the arrangement, the ratio growing) to the next plane ``u_j . w = 0``
    it meets, and j joins the pair.  None when a pair on the way is degenerate (a cable in
    its plane) or `max_pivots` did not reach the optimum (the caller then looks at every
    pair).  The per-tick path: plain floats, one pass over the cables per pair."""
    n = len(u)
    gx, gy, gz = g
    tol = MANY_TOL * scale
    qs = [0.0] * n
    for _ in range(max_pivots + 1):
        ax, ay, az = u[a]
        bx, by, bz = u[b]
        wx = ay * bz - az * by
        wy = az * bx - ax * bz
        wz = ax * by - ay * bx
        ww = wx * wx + wy * wy + wz * wz
        if not ww > 1e-24:
            return None
        wg = wx * gx + wy * gy + wz * gz
        sg = 1.0
        if wg < 0.0:  # turned so that w . g >= 0 (d_a, d_b below need u_a x u_b itself)
            wx, wy, wz, wg, sg = -wx, -wy, -wz, -wg, -1.0
        flat = MANY_TOL * math.sqrt(ww)
        den = sx = sy = sz = 0.0  # sum |q_i| and S = sum sgn(q_i) u_i over the others
        qmin = math.inf
        for i, (x, y, z) in enumerate(u):
            if i in (a, b):
                qs[i] = 0.0
                continue
            q = x * wx + y * wy + z * wz
            qs[i] = q
            if q > flat:
                den += q
                sx += x
                sy += y
                sz += z
                if q < qmin:
                    qmin = q
            elif q < -flat:
                den -= q
                sx -= x
                sy -= y
                sz -= z
                if -q < qmin:
                    qmin = -q
            else:
                return None  # a cable in the pair's plane: pair_solution's case
        rho = wg / den
        hx, hy, hz = gx - rho * sx, gy - rho * sy, gz - rho * sz
        k = sg / ww
        da = ((hy * bz - hz * by) * wx + (hz * bx - hx * bz) * wy + (hx * by - hy * bx) * wz) * k
        db = ((ay * hz - az * hy) * wx + (az * hx - ax * hz) * wy + (ax * hy - ay * hx) * wz) * k
        lim = rho + tol
        if abs(da) <= lim and abs(db) <= lim:
            signs = [1.0 if q > 0.0 else -1.0 for q in qs]
            signs[a] = signs[b] = 0.0
            d = [si * rho for si in signs]
            d[a] = da
            d[b] = db
            return PairSolution(
                a, b, d, rho, True, True, signs, (wx, wy, wz), qs, (sx, sy, sz), den, qmin
            )
        out, keep, dv = (a, b, da) if abs(da) >= abs(db) else (b, a, db)
        kx, ky, kz = u[keep]
        vx, vy, vz = ky * wz - kz * wy, kz * wx - kx * wz, kx * wy - ky * wx
        ox, oy, oz = u[out]
        if (ox * vx + oy * vy + oz * vz) * dv < 0.0:
            vx, vy, vz = -vx, -vy, -vz
        best = -math.inf
        nxt = -1
        for j, (x, y, z) in enumerate(u):
            qj = qs[j]
            if qj == 0.0:
                continue
            c = -(x * vx + y * vy + z * vz) / qj
            if c > best:
                best = c
                nxt = j
        if nxt < 0:
            return None
        a, b = (keep, nxt) if keep < nxt else (nxt, keep)
    return None


def _plane_solve(
    u: Sequence[Vec3], plane: Sequence[int], h: Vec3, w: Vec3, scale: float
) -> list[float] | None:
    """Deviations of the cables `plane` (their directions perpendicular to `w`) that make up
    `h` (in their plane) nearest the middle in the max norm: the module's rule in two
    dimensions, where the dual's vertices are the perpendiculars to one cable (``w x u_j``),
    and the cables along that one cable (with it, or opposite) share the rest equally.  None
    when the cables do not span the plane."""
    hx, hy, hz = h
    best: list[tuple[float, int]] = []
    for j in plane:
        ux, uy, uz = u[j]
        px, py, pz = w[1] * uz - w[2] * uy, w[2] * ux - w[0] * uz, w[0] * uy - w[1] * ux
        den = 0.0
        for i in plane:
            x, y, z = u[i]
            den += abs(x * px + y * py + z * pz)
        if den > 0.0:
            best.append((-abs(px * hx + py * hy + pz * hz) / den, j))
    best.sort()
    for _, j in best:
        ux, uy, uz = u[j]
        px, py, pz = w[1] * uz - w[2] * uy, w[2] * ux - w[0] * uz, w[0] * uy - w[1] * ux
        pp = math.sqrt(px * px + py * py + pz * pz)
        flat = MANY_TOL * pp
        ph = px * hx + py * hy + pz * hz
        sg = -1.0 if ph < 0.0 else 1.0
        den = 0.0
        line: list[tuple[int, float]] = []
        for i in plane:
            x, y, z = u[i]
            q = x * px + y * py + z * pz
            if abs(q) > flat:
                den += abs(q)
            else:
                line.append((i, 1.0 if x * ux + y * uy + z * uz > 0.0 else -1.0))
        rho2 = abs(ph) / den if den > 0.0 else 0.0
        out: dict[int, float] = {}
        rx, ry, rz = hx, hy, hz
        for i in plane:
            x, y, z = u[i]
            q = x * px + y * py + z * pz
            if abs(q) > flat:
                di = rho2 * sg * (1.0 if q > 0.0 else -1.0)
                out[i] = di
                rx -= di * x
                ry -= di * y
                rz -= di * z
        # The rest lies along u_j: each cable on that line takes an equal share.
        share = (rx * ux + ry * uy + rz * uz) / len(line)
        for i, s in line:
            out[i] = s * share
        if abs(share) <= rho2 + MANY_TOL * scale or den == 0.0:
            return [out[i] for i in plane]
    return None


def best_pairs(u: Sequence[Vec3], g: Vec3, pairs: Pairs) -> tuple[list[tuple[int, int]], float]:
    """The pairs whose ratio ``|w . g| / sum |u_i . w|`` is within rounding of the largest,
    best first, and ``sqrt(det(U U^T))`` (how well the directions span space; by
    Cauchy-Binet the sum of the squared triple products, each pair's row holding three)."""
    um = np.array(u, dtype=np.float64)  # (N, 3)
    w = (um[pairs.first][:, :, None] * um[pairs.second][:, None, :]).reshape(-1, 9) @ _CROSS
    q = w @ um.T  # (P, N): u_i . (u_a x u_b), zero for i in the pair
    span = math.sqrt(max(float(np.einsum("ij,ij->", q, q)) / 3.0, 0.0))
    if not span >= RANK_TOL:
        return [], span
    num = np.abs(w @ np.array(g, dtype=np.float64))
    den = np.abs(q).sum(axis=1)
    ratio = np.divide(num, den, out=np.zeros_like(num), where=den > 0.0)
    best = float(ratio.max())
    near = np.flatnonzero(ratio >= best - MANY_TOL * best - 1e-300)
    order = near[np.argsort(-ratio[near], kind="stable")]
    return [pairs.pairs[k] for k in order.tolist()], span


def settles(u: Sequence[Vec3], vertex: PairSolution, eps: float) -> bool:
    """Whether the pair vertex `vertex` of ``pivot_solve`` (its pair free, every other cable
    bound at ``rho``) is also the answer of ``regularised``: with that active set its
    equilibrium has one solution, the vertex itself, so the vertex is the strictly convex
    answer exactly when the bound cables' multipliers are not negative.

    The multipliers are ``sgn_i u_i . nu - eps rho`` with ``nu`` from ``u_a . nu = eps d_a``,
    ``u_b . nu = eps d_b``, ``v . nu = e3 = 1 + k eps rho`` (``regularised``; k the bound
    count).  Write ``nu = lam w + m`` with m in the pair's plane: ``|m| <= M = eps (|d_a| +
    |d_b|) / |w|`` (the plane's dual basis has length ``1 / |w|``), ``lam = (e3 - v . m) /
    (w . v)``, so each multiplier is at least ``(e3 - M |v|) |u_i . w| / (w . v) - M - eps
    rho``, smallest at the cable nearest the pair's plane (``qmin``): where that bound is not
    negative it settles them all at once; otherwise each one is computed.  False for a vertex
    without ``v`` (not a ``pivot_solve`` answer)."""
    v = vertex.v
    if v is None:
        return False
    a, b = vertex.a, vertex.b
    rho = vertex.rho
    da, db = vertex.d[a], vertex.d[b]
    k = len(u) - 2
    vx, vy, vz = v
    wx, wy, wz = vertex.w
    erho = eps * rho
    e3 = 1.0 + k * erho
    big_m = eps * (abs(da) + abs(db)) / math.sqrt(wx * wx + wy * wy + wz * wz)
    vn = math.sqrt(vx * vx + vy * vy + vz * vz)
    if (e3 - big_m * vn) * vertex.qmin >= vertex.den * (erho + big_m):
        return True
    # Each multiplier: nu by Cramer on the rows u_a, u_b, v.
    ax, ay, az = u[a]
    bx, by, bz = u[b]
    px, py, pz = by * vz - bz * vy, bz * vx - bx * vz, bx * vy - by * vx  # u_b x v
    qx, qy, qz = vy * az - vz * ay, vz * ax - vx * az, vx * ay - vy * ax  # v x u_a
    rx, ry, rz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx  # u_a x u_b
    det = ax * px + ay * py + az * pz
    if det == 0.0:
        return False
    e1, e2 = eps * da, eps * db
    nx = (e1 * px + e2 * qx + e3 * rx) / det
    ny = (e1 * py + e2 * qy + e3 * ry) / det
    nz = (e1 * pz + e2 * qz + e3 * rz) / det
    for (x, y, z), si in zip(u, vertex.signs, strict=True):
        if si != 0.0 and si * (x * nx + y * ny + z * nz) - erho < -1e-12:
            return False
    return True


def vertex_tensions(u: Sequence[Vec3], g: Vec3, c: float, vertex: PairSolution) -> list[float]:
    """The tensions ``c + d`` of a pair vertex of ``pivot_solve`` (it must have ``v``), with
    the rounding of its solve taken out of the equilibrium: one refinement of ``d_a u_a + d_b
    u_b + rho v = g`` (its residual solved again the way the vertex was)."""
    v = vertex.v
    assert v is not None
    a, b = vertex.a, vertex.b
    rho = vertex.rho
    da, db = vertex.d[a], vertex.d[b]
    ax, ay, az = u[a]
    bx, by, bz = u[b]
    vx, vy, vz = v
    hx = g[0] - (da * ax + db * bx + rho * vx)
    hy = g[1] - (da * ay + db * by + rho * vy)
    hz = g[2] - (da * az + db * bz + rho * vz)
    wx, wy, wz = vertex.w  # u_a x u_b turned to w . g >= 0: w . v = den, w . u_a = w . u_b = 0
    dr = (wx * hx + wy * hy + wz * hz) / vertex.den
    rho += dr
    hx -= dr * vx
    hy -= dr * vy
    hz -= dr * vz
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx  # u_a x u_b itself
    ww = cx * cx + cy * cy + cz * cz
    da += ((hy * bz - hz * by) * cx + (hz * bx - hx * bz) * cy + (hx * by - hy * bx) * cz) / ww
    db += ((ay * hz - az * hy) * cx + (az * hx - ax * hz) * cy + (ax * hy - ay * hx) * cz) / ww
    t = [c + si * rho for si in vertex.signs]
    t[a] = c + da
    t[b] = c + db
    return t


def freest_pair(u: Sequence[Vec3], g: Vec3) -> tuple[int, int]:
    """The two cables most nearly perpendicular to `g`: where the directions spread evenly
    (``U U^T`` near a multiple of the identity) the least-squares distribution ``U^T (U
    U^T)^-1 g`` presses them least, and the max-min vertex frees the two cables least pressed
    toward a limit, so this is often its pair: a cold start for ``pivot_solve`` (a pivot or
    two otherwise)."""
    gx, gy, gz = g
    b1 = b2 = math.inf
    i1 = 0
    i2 = 1
    for i, (x, y, z) in enumerate(u):
        d = abs(x * gx + y * gy + z * gz)
        if d < b1:
            b2, i2 = b1, i1
            b1, i1 = d, i
        elif d < b2:
            b2, i2 = d, i
    return (i1, i2) if i1 < i2 else (i2, i1)


def regularised(
    u: Sequence[Vec3], g: Vec3, eps: float, signs: Sequence[float], tol: float, max_iter: int
) -> tuple[list[float], float, list[float]] | None:
    """The distribution minimising ``rho + eps / 2 |d|^2`` subject to ``U d = g``, ``|d_i| <=
    rho`` (``d`` the deviations from the middle of the range): the max-min rule made strictly
    convex, so that its answer is unique and moves continuously with the pose.

    An active-set method from `signs` (+1 / -1: the cable at ``+rho`` / ``-rho``, 0: free, e.g.
    the max-min vertex's or the last pose's): with the set fixed, the conditions ``eps d_i =
    u_i . nu`` (free), ``d_i = sgn_i rho`` (bound, multiplier ``sgn_i u_i . nu - eps rho >= 0``)
    and ``sum of the multipliers = 1`` give ``(M + v v^T / k) nu = eps g + v / k`` (M the free
    cables' ``sum u u^T``, v the bound ones' ``sum sgn u``, k their count) and ``rho = (v . nu
    - 1) / (eps k)``; free cables beyond ``rho`` are bound and bound ones with a negative
    multiplier freed until neither happens (by `tol`).  Returns ``(d, rho, signs)`` or None
    when the system is singular or `max_iter` steps did not settle."""
    n = len(u)
    sig = list(signs)
    gx, gy, gz = g
    for _ in range(max_iter):
        m11 = m12 = m13 = m22 = m23 = m33 = 0.0
        vx = vy = vz = 0.0
        k = 0
        for (x, y, z), si in zip(u, sig, strict=True):
            if si == 0.0:
                m11 += x * x
                m12 += x * y
                m13 += x * z
                m22 += y * y
                m23 += y * z
                m33 += z * z
            else:
                vx += si * x
                vy += si * y
                vz += si * z
                k += 1
        if k == 0:
            return None
        ik = 1.0 / k
        m11 += vx * vx * ik
        m12 += vx * vy * ik
        m13 += vx * vz * ik
        m22 += vy * vy * ik
        m23 += vy * vz * ik
        m33 += vz * vz * ik
        b1, b2, b3 = eps * gx + vx * ik, eps * gy + vy * ik, eps * gz + vz * ik
        c11 = m22 * m33 - m23 * m23
        c12 = m13 * m23 - m12 * m33
        c13 = m12 * m23 - m13 * m22
        det = m11 * c11 + m12 * c12 + m13 * c13
        if not abs(det) > 1e-18 * (m11 * m22 * m33 + 1e-300):
            return None
        c22 = m11 * m33 - m13 * m13
        c23 = m12 * m13 - m11 * m23
        c33 = m11 * m22 - m12 * m12
        nx = (c11 * b1 + c12 * b2 + c13 * b3) / det
        ny = (c12 * b1 + c22 * b2 + c23 * b3) / det
        nz = (c13 * b1 + c23 * b2 + c33 * b3) / det
        rho = ((vx * nx + vy * ny + vz * nz) - 1.0) / (eps * k)
        erho = eps * rho
        lim = rho + tol
        d = [0.0] * n
        changed = False
        for i, (x, y, z) in enumerate(u):
            p = x * nx + y * ny + z * nz
            si = sig[i]
            if si == 0.0:
                di = p / eps
                d[i] = di
                if abs(di) > lim:
                    sig[i] = 1.0 if di > 0.0 else -1.0
                    changed = True
            else:
                d[i] = si * rho
                if si * p - erho < -1e-12:  # its multiplier (they sum to 1)
                    sig[i] = 0.0
                    changed = True
        if not changed:
            if not (math.isfinite(rho) and all(map(math.isfinite, d))):
                return None
            return d, rho, sig
    return None


def project(u: Sequence[Vec3], f: Vec3, c: float, d: Sequence[float]) -> list[float]:
    """The tensions ``t = c + d`` (the middle of the range and the deviations from it) moved
    the least (in the 2-norm) onto ``U t = f``: the rounding a solve leaves in the
    equilibrium taken out (``t + U^T (U U^T)^-1 (f - U t)``); ``c + d`` itself when ``U U^T``
    is singular."""
    rx, ry, rz = f
    t = [c + di for di in d]
    g11 = g12 = g13 = g22 = g23 = g33 = 0.0
    for (x, y, z), ti in zip(u, t, strict=True):
        rx -= ti * x
        ry -= ti * y
        rz -= ti * z
        g11 += x * x
        g12 += x * y
        g13 += x * z
        g22 += y * y
        g23 += y * z
        g33 += z * z
    c11 = g22 * g33 - g23 * g23
    c12 = g13 * g23 - g12 * g33
    c13 = g12 * g23 - g13 * g22
    det = g11 * c11 + g12 * c12 + g13 * c13
    if not det > 1e-18:
        return t
    c22 = g11 * g33 - g13 * g13
    c23 = g12 * g13 - g11 * g23
    c33 = g11 * g22 - g12 * g12
    ax = (c11 * rx + c12 * ry + c13 * rz) / det
    ay = (c12 * rx + c22 * ry + c23 * rz) / det
    az = (c13 * rx + c23 * ry + c33 * rz) / det
    return [ti + x * ax + y * ay + z * az for (x, y, z), ti in zip(u, t, strict=True)]


def sum_units(u: Sequence[Vec3]) -> Vec3:
    """``sum_i u_i``, summed in order (as ``units_and_sum`` sums them)."""
    sx = sy = sz = 0.0
    for x, y, z in u:
        sx += x
        sy += y
        sz += z
    return sx, sy, sz


def units_and_sum(
    anchors: Sequence[Vec3], point_m: Sequence[float]
) -> tuple[list[Vec3], Vec3] | None:
    """The unit vectors from `point_m` to `anchors` and their sum in one pass, when the point
    is three finite numbers, off every anchor, with some cable pulling up (a weight's solve);
    None otherwise (``CableStatics._units`` then names the problem)."""
    if len(point_m) != 3:
        return None
    px, py, pz = float(point_m[0]), float(point_m[1]), float(point_m[2])
    total = px + py + pz
    if total - total != 0.0:  # not finite
        return None
    units: list[Vec3] = []
    up = -1.0
    sx = sy = sz = 0.0
    for ax, ay, az in anchors:
        dx, dy, dz = ax - px, ay - py, az - pz
        d = math.sqrt(dx * dx + dy * dy + dz * dz)
        if not d > ANCHOR_TOL_M:
            return None
        x = dx / d
        y = dy / d
        z = dz / d
        if z > up:
            up = z
        units.append((x, y, z))
        sx += x
        sy += y
        sz += z
    return (units, (sx, sy, sz)) if up > UP_TOL else None


def finite_tensions(t: list[float]) -> list[float]:
    """`t`; ``SingularConfiguration`` when a tension is not finite (the pair arithmetic
    overflowed on a pathological pose: never a NaN or inf out)."""
    total = sum(t)
    if total - total != 0.0:
        raise SingularConfiguration("tensions overflow: the configuration is singular")
    return t
