"""The vectorised tension solve of three and four cables for many poses at once
(``CableStatics.solve_batch``), and the margin of a batch of distributions.

Pure module (``numpy``): the same arithmetic as the single-pose solve of
``controller.core.statics``, on (M, N) arrays; rows it cannot solve are flagged, never raised.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from controller.core.tension_math import RANK_TOL, SLACK, TRIPLES4

__all__ = ["ANCHOR_TOL_M", "UP_TOL", "batch_closed", "batch_margin"]

ANCHOR_TOL_M = 1e-9
"""P closer than this to an anchor has no cable direction."""

UP_TOL = 1e-12
"""A cable whose unit vector rises by at most this pulls no weight up."""


def batch_margin(
    t: NDArray[np.float64], lo: float, hi: float
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Smallest distance to a limit per row and the cable (0-based) at it."""
    d = np.minimum(t - lo, hi - t)
    with np.errstate(invalid="ignore"):
        d = np.where(np.isfinite(d), d, -np.inf)
    lim = np.argmin(d, axis=1).astype(np.int64)
    mg = np.take_along_axis(d, lim[:, None], axis=1)[:, 0]
    return mg, lim


def batch_closed(
    anchors: NDArray[np.float64], p: NDArray[np.float64], w: float, lo: float, hi: float
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Vectorised N = 3 / N = 4 tensions; ``ok`` False for singular or non-finite rows (their
    tensions are garbage, possibly NaN, and are replaced by the caller)."""
    nc = anchors.shape[0]
    rows = p.shape[0]
    ok = np.asarray(np.isfinite(p).all(axis=1), dtype=np.bool_)
    p = np.where(ok[:, None], p, 0.0)
    with np.errstate(all="ignore"):
        dv = anchors[None, :, :] - p[:, None, :]  # (M, N, 3)
        dist = np.sqrt(np.einsum("mij,mij->mi", dv, dv))
        ok &= (dist > ANCHOR_TOL_M).all(axis=1)
        u = dv / np.where(dist > ANCHOR_TOL_M, dist, 1.0)[:, :, None]
        ok &= (u[:, :, 2] > UP_TOL).any(axis=1)
        ux, uy, uz = u[:, :, 0], u[:, :, 1], u[:, :, 2]
        if nc == 3:
            a, b, c = 0, 1, 2
            det = (
                ux[:, a] * (uy[:, b] * uz[:, c] - uz[:, b] * uy[:, c])
                - uy[:, a] * (ux[:, b] * uz[:, c] - uz[:, b] * ux[:, c])
                + uz[:, a] * (ux[:, b] * uy[:, c] - uy[:, b] * ux[:, c])
            )
            ok &= np.abs(det) >= RANK_TOL
            inv = w / np.where(ok, det, 1.0)
            t = np.empty((rows, 3))
            t[:, a] = (ux[:, b] * uy[:, c] - uy[:, b] * ux[:, c]) * inv
            t[:, b] = (ux[:, c] * uy[:, a] - uy[:, c] * ux[:, a]) * inv
            t[:, c] = (ux[:, a] * uy[:, b] - uy[:, a] * ux[:, b]) * inv
            return t, ok
        # N = 4: cz[k, l] = z of u_k x u_l, shared by the four triples.
        cz = ux[:, :, None] * uy[:, None, :] - uy[:, :, None] * ux[:, None, :]  # (M, 4, 4)
        tp = np.zeros((rows, 4))
        n = np.empty((rows, 4))
        for j, (a, b, c) in enumerate(TRIPLES4):
            d = (
                ux[:, a] * (uy[:, b] * uz[:, c] - uz[:, b] * uy[:, c])
                - uy[:, a] * (ux[:, b] * uz[:, c] - uz[:, b] * ux[:, c])
                + uz[:, a] * cz[:, b, c]
            )
            n[:, j] = -d if j & 1 else d
            tp[:, a] += d * cz[:, b, c]
            tp[:, b] += d * cz[:, c, a]
            tp[:, c] += d * cz[:, a, b]
        nn = np.einsum("mi,mi->m", n, n)
        norm = np.sqrt(nn)
        ok &= norm >= RANK_TOL
        nn_safe = np.where(ok, nn, 1.0)
        tp *= (w / nn_safe)[:, None]
        s = n / np.where(ok, norm, 1.0)[:, None]
        rising = s >= 0.0
        ra = np.where(rising, tp - lo, hi - tp)  # (M, 4)
        fa = np.where(rising, hi - tp, tp - lo)
        r = np.abs(s)
        den = r[:, :, None] + r[:, None, :]  # rising i, falling j
        valid = den > 0.0
        v = (ra[:, :, None] * r[:, None, :] + fa[:, None, :] * r[:, :, None]) / np.where(
            valid, den, 1.0
        )
        v = np.where(valid, v, np.inf)
        best = v.reshape(rows, 16).min(axis=1)
        pos = r > 0.0
        r_safe = np.where(pos, r, 1.0)
        big = np.maximum(np.abs(tp).max(axis=1), hi)
        floor = (best - SLACK * (big + hi))[:, None]
        lam_lo = np.where(pos, (floor - ra) / r_safe, -np.inf).max(axis=1)
        lam_hi = np.where(pos, (fa - floor) / r_safe, np.inf).min(axis=1)
        lam = 0.5 * (lam_lo + lam_hi)
        t = tp + lam[:, None] * s
        ok &= np.isfinite(t).all(axis=1)
    return t, ok
