"""Forward pose kinematics of many poses at once: ``fpk_batch`` on an (M, N) array of lengths.

For offline analysis and the benchmark; the control loop solves one pose per tick (``fpk``).

The batch computes the single-pose fit (``fit``) row by row, with one fast path: four anchors
at one height (the usual rig), where the whole fit is a fixed sequence of arithmetic (the
seed, one multiplier equation solved in two Newton steps, the fitted lengths' point; see
``fit``) that runs vectorised on columns of lengths, through the same functions as the single
pose.  Rows that path cannot vouch for (lengths that are not finite and positive, a seed
triple that cannot meet, a fit ``_planar4_solve`` does not vouch for or a tangent: rare), and
every row of other layouts, go through the single-pose code one by one, which also names the
cable to blame for lengths that cannot meet.  So ``fpk`` and ``fpk_batch`` agree to ~1e-12 m.
(Within about a millimetre of the plane of level anchors they may differ by up to ~1e-6 m:
there z = zn - sqrt(disc) turns a rounding difference of 1e-12 m^2 in disc into 1e-6 m, and
the lengths fix z no better.)

Rows are processed in chunks of ``BATCH_CHUNK`` so the working set stays in cache, and the
shared functions are written with augmented assignments so that on arrays they make few
temporaries: allocating a fresh chunk-sized array can cost as much as the arithmetic on it.
``FpkBatchResult.position_m`` is the (M, 3) transpose of a (3, M) array.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from controller.core.kinematics.errors import KinematicsError, UnreachableError
from controller.core.kinematics.fit import _fpk, _planar4_solve
from controller.core.kinematics.fitplan import GN_STEP_TOL_M, _Planar4
from controller.core.kinematics.geometry import Geometry
from controller.core.kinematics.spheres import Vec3, _equal_xy

__all__ = ["BATCH_CHUNK", "FpkBatchResult", "fpk_batch"]

FloatArray = npt.NDArray[np.float64]

#: Rows per chunk of the batch FPK (its working set stays in cache).
BATCH_CHUNK = 16384


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


def fpk_batch(geom: Geometry, lengths_m: Any) -> FpkBatchResult:
    """FPK of M poses from an (M, N) array of lengths; never raises per row.

    Each row gets what ``fpk`` gives for it.  Rows with non-finite or non-positive lengths,
    or where ``fpk`` raises ``UnreachableError``, get ``valid`` False, position and
    residual 0 (never NaN).  Raises ``KinematicsError`` only for a wrong shape.
    """
    lens = np.asarray(lengths_m, dtype=np.float64)
    n = geom.n_cables
    if lens.ndim != 2 or lens.shape[1] != n:
        raise KinematicsError(f"lengths must have shape (M, {n}), got {lens.shape}")
    m = lens.shape[0]
    xyz = np.zeros((3, m), dtype=np.float64)
    residual = np.zeros(m, dtype=np.float64)
    ok = np.ones(m, dtype=bool)
    short_cable = np.zeros(m, dtype=np.int64)
    shortfall = np.zeros(m, dtype=np.float64)
    p4 = geom._p4
    for s in range(0, m, BATCH_CHUNK):
        e = min(m, s + BATCH_CHUNK)
        if p4 is None:
            rows: Any = range(s, e)
        else:
            with np.errstate(all="ignore"):
                rows = s + _planar_chunk(p4, lens[s:e], xyz[:, s:e], residual[s:e])
        for r in rows:
            try:
                res = _fpk(geom, lens[r].tolist())
            except KinematicsError as exc:
                ok[r] = False
                xyz[:, r] = 0.0
                residual[r] = 0.0
                if isinstance(exc, UnreachableError):
                    short_cable[r] = exc.cable
                    shortfall[r] = exc.shortfall_m
                continue
            xyz[:, r] = res.position_m
            residual[r] = res.residual_m
    return FpkBatchResult(xyz.T, residual, ok, geom.seed_triple, short_cable, shortfall)


def _planar_chunk(
    p4: _Planar4, lens: FloatArray, xyz: FloatArray, residual: FloatArray
) -> npt.NDArray[np.intp]:
    """The planar fit on one chunk of rows, into ``xyz`` (3, m) and ``residual``; returns the
    rows (chunk indices) it leaves to the single-pose code."""
    sd = p4.sd
    x, y, z = xyz
    # Lengths finite and > 0: one check on the chunk, per row only where it fails.
    lo, big = float(lens.min(initial=math.inf)), float(lens.max(initial=0.0))
    if lo > 0.0 and big < math.inf:
        handoff = np.zeros(lens.shape[0], dtype=bool)
    else:
        good = (lens.min(axis=1) > 0.0) & (lens.max(axis=1) < math.inf)
        handoff = ~good
        big = float(np.max(lens, where=good[:, None], initial=0.0))
    cols = np.ascontiguousarray(lens.T)  # one row per cable
    sq = np.square(cols)
    l1, l2, l3, l4 = cols[sd.i1], cols[sd.i2], cols[sd.i3], cols[p4.k4]
    s1, s2, s3, t = sq[sd.i1], sq[sd.i2], sq[sd.i3], sq[p4.k4]
    # The seed (``_seed_equal``); rows whose seed spheres miss are handed off.
    dx, dy, disc = _equal_xy(sd, s1, s2, s3)
    handoff |= disc < 0.0
    np.add(dx, sd.x1, out=x)
    np.add(dy, sd.y1, out=y)
    _lower_z(sd.zn, disc, z)
    # The fourth cable at the seed (``_others_cost``): rows it agrees with are done.
    root0 = _dist(p4.b4, x, y, z)
    root0 -= l4
    np.abs(root0, out=root0)
    np.multiply(root0, 0.5, out=residual)
    act = root0 > GN_STEP_TOL_M
    act &= ~handoff
    if not act.any():
        return np.nonzero(handoff)[0]
    dx, dy, disc, cost, trusted = _planar4_solve(
        p4, l1, l2, l3, l4, s1, s2, s3, t, big, root0 * root0, root0
    )
    trusted &= disc >= 0.0  # a tangent (or a miss): the single-pose code decides
    handoff |= act & ~trusted
    if act.all():
        np.add(dx, sd.x1, out=x)
        np.add(dy, sd.y1, out=y)
        _lower_z(sd.zn, disc, z)
        np.multiply(cost, 0.25, out=residual)
        np.sqrt(residual, out=residual)
    else:  # rows needing no fit keep the seed
        dx += sd.x1
        dy += sd.y1
        cost *= 0.25
        np.sqrt(cost, out=cost)
        np.copyto(x, dx, where=act)
        np.copyto(y, dy, where=act)
        np.copyto(z, _lower_z(sd.zn, disc, disc), where=act)
        np.copyto(residual, cost, where=act)
    return np.nonzero(handoff)[0]


def _lower_z(zn: float, disc: FloatArray, out: FloatArray) -> FloatArray:
    """zn - sqrt(max(disc, 0)) into ``out``: the lower solution's height."""
    np.maximum(disc, 0.0, out=out)
    np.sqrt(out, out=out)
    return np.subtract(zn, out, out=out)


def _dist(b: Vec3, x: FloatArray, y: FloatArray, z: FloatArray) -> FloatArray:
    """|P - b| for the rows' points P = (x, y, z)."""
    d = np.subtract(x, b[0])
    d *= d
    tmp = np.subtract(y, b[1])
    tmp *= tmp
    d += tmp
    np.subtract(z, b[2], out=tmp)
    tmp *= tmp
    d += tmp
    return np.sqrt(d, out=d)
