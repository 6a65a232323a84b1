"""Geometry for anchor calibration: rigid alignment (Kabsch), plane fits, the rigid motions of
an anchor set, and poses spread over a region for collecting samples.

Pure: numpy; no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from controller.core.calibration_samples import CalibrationError

FloatArray = NDArray[np.float64]
Vec3 = tuple[float, float, float]


def kabsch(src: Any, dst: Any) -> tuple[FloatArray, FloatArray]:
    """The rigid motion (R, t) minimising sum |R src_i + t - dst_i|^2 (proper rotation).

    Raises CalibrationError if the point sets differ in shape or hold fewer than 3 points.
    """
    a = np.asarray(src, dtype=np.float64)
    b = np.asarray(dst, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2 or a.shape[1] != 3 or a.shape[0] < 3:
        raise CalibrationError(f"kabsch needs two (N >= 3, 3) point sets, got {a.shape}, {b.shape}")
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    h = (a - ca).T @ (b - cb)
    u, _, vt = np.linalg.svd(h)
    d = 1.0 if np.linalg.det(vt.T @ u.T) >= 0.0 else -1.0
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return rot, cb - rot @ ca


def plane_fit(points: Any) -> tuple[FloatArray, float, float]:
    """Best plane through `points` (M, 3): (unit normal, RMS distance from it, RMS spread).

    The spread is the RMS distance from the centroid along the widest direction. Raises
    nothing for M >= 1 (one point: normal z, zeros).
    """
    p = np.asarray(points, dtype=np.float64)
    c = p - p.mean(axis=0)
    _, s, vt = np.linalg.svd(c, full_matrices=True)
    m = max(1, p.shape[0])
    s_full = np.zeros(3)
    s_full[: len(s)] = s
    return vt[2], float(s_full[2] / math.sqrt(m)), float(s_full[0] / math.sqrt(m))


def rigid_basis(anchors_m: Any) -> FloatArray:
    """Orthonormal basis (3N, 6) of the infinitesimal rigid motions of the anchor set."""
    a = np.asarray(anchors_m, dtype=np.float64)
    n = a.shape[0]
    c = a - a.mean(axis=0)
    cols = [np.tile(t, n) for t in np.eye(3)]
    cols += [np.cross(np.broadcast_to(w, c.shape), c).ravel() for w in np.eye(3)]
    q, _ = np.linalg.qr(np.array(cols).T)
    return np.asarray(q[:, :6], dtype=np.float64)


def orthogonal_complement(basis: FloatArray) -> FloatArray:
    """Orthonormal basis of the orthogonal complement of the columns of `basis`."""
    q, _ = np.linalg.qr(basis, mode="complete")
    return np.asarray(q[:, basis.shape[1] :], dtype=np.float64)


# --------------------------------------------------------------------------------------------
# Poses for collecting samples


def _radical_inverse(i: int, base: int) -> float:
    f, r = 1.0, 0.0
    while i > 0:
        f /= base
        r += f * (i % base)
        i //= base
    return r


def spread_poses(
    n: int,
    lo_m: Sequence[float],
    hi_m: Sequence[float],
    inside: Callable[[Vec3], bool],
    *,
    start_m: Sequence[float] | None = None,
    candidates: int = 4096,
) -> list[Vec3]:
    """`n` poses spread over the region {p in the box lo..hi : inside(p)}, in visiting order.

    Candidates are a Halton sequence in the box; farthest-point sampling picks `n` of them
    (extremes first, which is what calibration needs), then they are ordered as a
    nearest-neighbour tour from `start_m` (or from the first). Deterministic. Raises
    CalibrationError for n < 1, an empty or inverted box, or fewer than n candidates inside.
    """
    if n < 1:
        raise CalibrationError(f"need at least one pose, got {n}")
    lo = np.asarray(lo_m, dtype=np.float64)
    hi = np.asarray(hi_m, dtype=np.float64)
    if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite(lo) & np.isfinite(hi)):
        raise CalibrationError("the pose box needs finite 3-vectors")
    if not np.all(hi > lo):
        raise CalibrationError(f"empty pose box {lo.tolist()} .. {hi.tolist()}")
    pts: list[Vec3] = []
    for i in range(1, candidates + 1):
        u = (_radical_inverse(i, 2), _radical_inverse(i, 3), _radical_inverse(i, 5))
        p = (
            float(lo[0] + (hi[0] - lo[0]) * u[0]),
            float(lo[1] + (hi[1] - lo[1]) * u[1]),
            float(lo[2] + (hi[2] - lo[2]) * u[2]),
        )
        if inside(p):
            pts.append(p)
    if len(pts) < n:
        raise CalibrationError(
            f"only {len(pts)} of {candidates} candidate poses lie inside the region; "
            f"cannot spread {n} (use a smaller margin or fewer poses)"
        )
    cand = np.array(pts)
    centre = cand.mean(axis=0)
    chosen = [int(np.argmax(np.linalg.norm(cand - centre, axis=1)))]
    dmin = np.linalg.norm(cand - cand[chosen[0]], axis=1)
    while len(chosen) < n:
        j = int(np.argmax(dmin))
        chosen.append(j)
        dmin = np.minimum(dmin, np.linalg.norm(cand - cand[j], axis=1))
    left = [pts[j] for j in chosen]
    here: Sequence[float] = left[0] if start_m is None else start_m
    order: list[Vec3] = []
    while left:
        k = min(range(len(left)), key=lambda m: math.dist(here, left[m]))
        here = left.pop(k)
        order.append(here)
    return order
