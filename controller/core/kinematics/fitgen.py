"""The fit of an effector among its anchors, written out for one layout (built by ``Geometry``).

``fit._gauss_newton_among`` loops over the cables; in CPython the loop itself (the iteration,
unpacking each anchor and length) costs about as much as the arithmetic.  ``_make_among``
writes the same computation out once per layout, cable by cable, with the anchors as
constants, and compiles it: the linearised trilateration's seed (``fitplan._Linear``), J^T J
and J^T r at the start, J^T J factored once as L D L^T, then Gauss-Newton steps whose trial
points cost the residuals and J^T r, with ``fit``'s stopping rule.  Whatever the common case
does not cover (a point on an anchor, J^T J singular, a step that does not lower the cost,
no convergence within ``GN_MAX_ITER`` steps) returns None, and the caller runs the loop from
the same start, which handles it as before.  The source is made from floats only (their
``repr`` reads back exactly) and names the anchors it was made for.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import cast

from controller.core.kinematics.fitplan import (
    GN_AMONG_NEXT_TOL2,
    GN_COST_REL_TOL,
    GN_COST_ROUND_M,
    GN_DET_MIN,
    GN_MAX_ITER,
    GN_STEP_TOL_M,
    _Linear,
)
from controller.core.kinematics.spheres import Vec3

__all__ = ["AmongFit"]

#: ``fit(lengths, x, y, z)``: the fit from (x, y, z), or from the linearised trilateration
#: when x is None; x, y, z, RMS residual, or None for the loop to handle.
AmongFit = Callable[
    [Sequence[float], float | None, float, float], tuple[float, float, float, float] | None
]


def _c(v: float) -> str:
    """A float as source that reads back to the same float."""
    if not math.isfinite(v):
        raise ValueError(f"cannot write {v!r} into the fit's source")
    return repr(float(v))


def _source(pts: tuple[Vec3, ...], lin: _Linear | None) -> str:
    """The fit's source for anchors ``pts`` (see the module docstring)."""
    n = len(pts)
    ls = ", ".join(f"l{i}" for i in range(n))
    out = ["def fit(lengths, x, y, z):", f"    {ls}, = lengths"]
    if lin is not None:
        out.append("    if x is None:")
        out += [f"        s{i} = l{i} * l{i}" for i in range(n)]
        for k, name in enumerate("xyz"):
            terms = "".join(f" - {_c(w[k])} * s{i}" for i, w in enumerate(lin.w))
            out.append(f"        {name} = {_c(lin.p0[k])}{terms}")
    out.append("    try:")
    for i, (ax, ay, az) in enumerate(pts):
        op = "=" if i == 0 else "+="
        out += [
            f"        ux = x - {_c(ax)}",
            f"        uy = y - {_c(ay)}",
            f"        uz = z - {_c(az)}",
            "        d = _sqrt(ux * ux + uy * uy + uz * uz)",
            f"        res = d - l{i}",
            "        t = 1.0 / d",
            "        ux *= t",
            "        uy *= t",
            "        uz *= t",
            f"        cost {op} res * res",
            f"        a11 {op} ux * ux",
            f"        a12 {op} ux * uy",
            f"        a13 {op} ux * uz",
            f"        a22 {op} uy * uy",
            f"        a23 {op} uy * uz",
            f"        g1 {op} ux * res",
            f"        g2 {op} uy * res",
            f"        g3 {op} uz * res",
        ]
    out += [
        "    except ZeroDivisionError:",
        "        return None",
        f"    a33 = {n}.0 - a11 - a22",
        "    if not a11 > 0.0:",
        "        return None",
        "    l21 = a12 / a11",
        "    l31 = a13 / a11",
        "    d2 = a22 - l21 * a12",
        "    if not d2 > 0.0:",
        "        return None",
        "    e23 = a23 - l31 * a12",
        "    l32 = e23 / d2",
        "    d3 = a33 - l31 * a13 - l32 * e23",
        "    if not a11 * d2 * d3 > DET_MIN:",
        "        return None",
        "    i1 = 1.0 / a11",
        "    i2 = 1.0 / d2",
        "    i3 = 1.0 / d3",
        "    prev2 = INF",
        "    for _ in ITERS:",
        "        w2 = g2 - l21 * g1",
        "        sz = (g3 - l31 * g1 - l32 * w2) * i3",
        "        sy = w2 * i2 - l32 * sz",
        "        sx = g1 * i1 - l21 * sy - l31 * sz",
        "        step2 = sx * sx + sy * sy + sz * sz",
        "        if step2 < 1e-12 and (step2 <= TOL2 or step2 * step2 < NEXT_TOL2 * prev2):",
        "            cost -= g1 * sx + g2 * sy + g3 * sz",
        f"            return x - sx, y - sy, z - sz, _sqrt(cost / {n}.0) if cost > 0.0 else 0.0",
        "        prev2 = step2",
        "        tx = x - sx",
        "        ty = y - sy",
        "        tz = z - sz",
        "        p = (tx, ty, tz)",
        "        try:",
    ]
    for i, (ax, ay, az) in enumerate(pts):
        op = "=" if i == 0 else "+="
        out += [
            f"            d = _dist(p, A{i})",
            f"            res = d - l{i}",
            f"            tc {op} res * res",
            "            k = res / d",
            f"            kk {op} k",
            f"            h1 {op} {_c(ax)} * k",
            f"            h2 {op} {_c(ay)} * k",
            f"            h3 {op} {_c(az)} * k",
        ]
    out += [
        "        except ZeroDivisionError:",
        "            return None",
        "        if not tc <= cost + (COST_REL_TOL * cost + COST_ROUND_M * _sqrt(cost)):",
        "            return None",
        "        x = tx",
        "        y = ty",
        "        z = tz",
        "        cost = tc",
        "        g1 = tx * kk - h1",
        "        g2 = ty * kk - h2",
        "        g3 = tz * kk - h3",
        "    return None",
    ]
    return "\n".join(out) + "\n"


def _make_among(pts: tuple[Vec3, ...], lin: _Linear | None) -> AmongFit:
    """The fit for anchors ``pts`` with ``fitplan``'s tolerances (about a millisecond for
    eight anchors, once per ``Geometry``).  Raises ValueError for a non-finite anchor or
    constant."""
    ns: dict[str, object] = {
        "_sqrt": math.sqrt,
        "_dist": math.dist,
        "INF": math.inf,
        "ITERS": tuple(range(GN_MAX_ITER)),
        "DET_MIN": GN_DET_MIN,
        "TOL2": GN_STEP_TOL_M * GN_STEP_TOL_M,
        "NEXT_TOL2": GN_AMONG_NEXT_TOL2,
        "COST_REL_TOL": GN_COST_REL_TOL,
        "COST_ROUND_M": GN_COST_ROUND_M,
    }
    ns.update({f"A{i}": p for i, p in enumerate(pts)})
    src = _source(pts, lin)
    # The source names the anchors it was made for (shown in a traceback through it).
    code = compile(src, f"<among-anchors fit for {len(pts)} anchors {pts!r}>", "exec")
    exec(code, ns)
    return cast(AmongFit, ns["fit"])
