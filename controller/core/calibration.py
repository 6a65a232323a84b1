"""Anchor calibration: the anchors and reel offsets that best explain encoder samples.

Pure: numpy, and scipy's `least_squares` (imported when a calibration runs); no I/O.

The samples
-----------
At K poses of the effector the reels' motor positions are recorded (motor turns, as the drives
report them) together with the pose the controller believed (computed from the configured
anchors, so only a starting guess). `parse_samples` reads them from CSV text; the format is
written by `samples_preamble` / `samples_header` / `format_sample_row`:

* lines starting with ``#`` are comments, blank lines are skipped;
* the first other line is the header: one column ``node_<id>_rev`` per reel and ``x_m``,
  ``y_m``, ``z_m``, in any order, nothing else;
* then one row per pose, every value a finite number.

The model
---------
Cable i at pose k has the length the reel model gives for its motor turns, with the reel's
offset unknown (``ReelModel.offset_rev``, what homing sets), and the straight-line distance
from the anchor::

    r_ik = reel_i.length_m(rev_ik - offset_i) - |P_k - A_i|

Elastic cables (`[[reels]] cable_ea_n`) are longer than their reels paid out: by the factor
``s_ik = (EA_i + t_ik) / EA_i`` under the tension ``t_ik`` the controller planned at the pose
(`controller.core.stretch`); with `stretch` given the reel length is multiplied by it,
``r_ik = s_ik * reel_i.length_m(rev_ik - offset_i) - |P_k - A_i|``, so the stretch is not
mistaken for anchors moved (millimetres of it on a Hangprinter's lines would move the anchors
by a centimetre).

Unknowns: the anchors A (3N), the offsets (N) and the poses P (3K). `calibrate` minimises
sum r_ik^2 with `scipy.optimize.least_squares` (Levenberg-Marquardt, analytic Jacobian).
Metres per turn, gear ratio, direction and build-up come from the configuration: scaling the
anchors, the poses and every reel's metres per turn together leaves every sample consistent,
so the scale cannot be fitted from these samples.

The frame
---------
Every sample is unchanged by a rigid motion of the whole robot (anchors and poses together),
so the solution is fixed by a convention: **the new anchors are the best-fit rigid (Kabsch)
alignment to the configured ones**. Equivalently the anchor changes ``d_i = A_i - A_cfg,i``
contain no rigid motion, ``sum d_i = 0`` and ``sum (A_cfg,i - c) x d_i = 0`` (c the configured
centroid); for a symmetric positive-definite cross-covariance these are exactly the conditions
under which the Kabsch rotation is the identity and its translation zero. The solve uses
coordinates of the 3N - 6 dimensional space orthogonal to the rigid motions at the configured
anchors, so the condition holds at every step.

What the samples cannot see
---------------------------
The information the samples carry about the anchors, with the offsets and poses left free, is
the Schur complement S of the Gauss-Newton matrix J^T J. Its eigenvectors (in the space
without rigid motions) are anchor deformations; a direction's predicted standard deviation is
sigma / sqrt(lambda), sigma the cable-length noise (assumed `Settings.assumed_noise_m` at first,
then estimated from the residuals). Directions the samples determine worse than
`Settings.hold_std_m` are **held near the configured values**: the fit adds, for each, the
residual (sigma / hold_std_m) * (change of the anchors along it), a prior that trusts the
configured anchors to `hold_std_m` along directions the samples cannot see. Where the samples
are blind the anchors stay at the configured values, so the result is never worse than the
configuration there; where a direction is blind only to first order but seen to second order
(stretching a flat layout by e changes cable lengths by about e^2 / d, d the horizontal
distance: millimetres for centimetres on a desk rig), the samples pull against the prior and
the result moves toward them, by as much as the two balance (reported per direction). The
blind set is found at the starting point and again at each solution (with the new noise
estimate) until it stops growing. Directions worse than `Settings.weak_std_m` but better than
`hold_std_m` are fitted and named as poorly determined.

With all anchors in one plane (four poles of equal height, most rigs) some deformations of
the layout change no cable length to first order (with four anchors the two stretches of the
layout along its axes, its width and its depth; with five, one; six or more anchors in general
position have none): they are reported and held. Anchors off one plane (Hangprinter-style, or
poles of different heights) leave every direction observable.

Quality gates (all must pass before a configuration is written): the RMS residual per
redundant equation, sqrt(sum r^2 / (equations - unknowns)), <= `max_rms_m` (1 mm) (the plain
RMS is smaller than the noise by sqrt(redundancy / equations), 0.4 for four cables and 25
poses); the worst residual <= `max_residual_m` (3 mm); no direction worse than `hold_std_m`
left free; the solver converged; every pose fitted below the anchors. Refused outright
(`CalibrationError`): fewer than four cables, fewer poses than the unknowns need (with some
redundancy), poses within a few per cent of one plane, or the same pose repeated.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from controller.core.calibration_geometry import (
    kabsch,
    orthogonal_complement,
    plane_fit,
    rigid_basis,
    spread_poses,
)
from controller.core.calibration_samples import (
    POSE_COLUMNS,
    CalibrationError,
    Samples,
    format_sample_row,
    parse_samples,
    rev_column,
    samples_header,
    samples_preamble,
)
from controller.core.calibration_toml import format_metres, replace_anchor_values
from controller.core.reel import ReelModel

__all__ = [
    "ANCHORS_COPLANAR_RATIO",
    "COPLANAR_POSES_RATIO",
    "DISTINCT_POSE_M",
    "MIN_CABLES",
    "POSE_COLUMNS",
    "RECOMMENDED_POSES",
    "START_BELOW_ANCHORS_RATIO",
    "THIN_POSES_RATIO",
    "Calibration",
    "CalibrationError",
    "CalibrationUnavailable",
    "Direction",
    "Gate",
    "Samples",
    "Settings",
    "calibrate",
    "format_metres",
    "format_sample_row",
    "kabsch",
    "minimum_poses",
    "parse_samples",
    "plane_fit",
    "replace_anchor_values",
    "rev_column",
    "rigid_basis",
    "samples_header",
    "samples_preamble",
    "spread_poses",
]

FloatArray = NDArray[np.float64]
Vec3 = tuple[float, float, float]

MIN_CABLES = 4
"""With three cables every pose fits any anchors: nothing can be calibrated."""

COPLANAR_POSES_RATIO = 0.05
"""Poses whose RMS distance from their best plane is below this fraction of their RMS spread
are refused (the height of the anchors above them is then not determined)."""

THIN_POSES_RATIO = 0.2
"""Below this fraction the poses are accepted with a warning, unless they already use the
height the workspace allows (THIN_POSES_OF_HEIGHT): a wide, low workspace (a stadium) cannot
hold thicker poses, and a warning to spread them more in height would ask the impossible."""

THIN_POSES_OF_HEIGHT = 0.4
"""Poses whose RMS distance from their plane is at least this fraction of the most a pose
height range H allows (H / 2: half at the floor, half at the top) use the height well: no
warning whatever their width. `cablebot calibrate collect --auto` spreads poses to about 0.6."""

DISTINCT_POSE_M = 1e-3
"""Poses closer than this count as one pose."""

RECOMMENDED_POSES = 20
"""Fewer poses (or fewer than twice the minimum) give a warning; see `recommended_poses`."""

ANCHORS_COPLANAR_RATIO = 1e-3
"""Anchors within this fraction of their spread from one plane count as coplanar (reported)."""

START_BELOW_ANCHORS_RATIO = 0.05
"""Believed poses higher than the lowest anchor less this fraction of the height range (lowest
anchor to lowest pose) start the solve at that height instead."""

_UNBOUNDED_STD_M = 1e3
"""Standard deviations above this are reported as unbounded (None in JSON)."""


class CalibrationUnavailable(RuntimeError):
    """scipy (needed for the least-squares solve) is not installed."""


# --------------------------------------------------------------------------------------------
# The calibration


@dataclass(frozen=True, slots=True)
class Settings:
    """Thresholds of the calibration (metres)."""

    hold_std_m: float = 0.01
    """How well the configured anchors are trusted: directions the samples determine worse
    than this (1 sigma) are held near the configured values by a prior of this width."""
    weak_std_m: float = 0.001
    """Free directions and anchors worse than this are named as poorly determined."""
    max_rms_m: float = 0.001
    """Gate: RMS residual."""
    max_residual_m: float = 0.003
    """Gate: worst residual."""
    noise_floor_m: float = 1e-5
    """Lower bound of the noise estimate (encoder resolution) in the predicted uncertainties."""
    assumed_noise_m: float = 1e-4
    """Cable-length noise assumed for the first round, before the residuals estimate it."""

    def __post_init__(self) -> None:
        for name in (
            "hold_std_m",
            "weak_std_m",
            "max_rms_m",
            "max_residual_m",
            "noise_floor_m",
            "assumed_noise_m",
        ):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0.0):
                raise CalibrationError(f"{name} must be a finite number > 0, got {v!r}")


@dataclass(frozen=True, slots=True)
class Direction:
    """An anchor deformation: `vector` (unit, one row per anchor) and how well it is seen."""

    kind: str
    """"held" (kept at the configured values) or "weak" (fitted, poorly determined)."""
    std_m: float | None
    """Predicted 1-sigma of the samples along it; None = not seen at all."""
    vector: tuple[Vec3, ...]
    words: str
    change_m: float | None = None
    """Held directions: how far the anchors moved along it (the samples' pull against the
    prior); None for fitted ones."""


@dataclass(frozen=True, slots=True)
class Gate:
    """One quality gate: its name, whether it passed, and the figures."""

    name: str
    ok: bool
    detail: str


@dataclass(frozen=True, slots=True)
class Calibration:
    """The result of `calibrate` (arrays in cable order; poses in sample order)."""

    node_ids: tuple[int, ...]
    anchors_m: FloatArray
    config_anchors_m: FloatArray
    offsets_rev: FloatArray
    poses_m: FloatArray
    residuals_m: FloatArray
    rms_m: float
    rms_per_dof_m: float
    """sqrt(sum r^2 / redundancy): the cable-length noise the fit implies (gated)."""
    worst_m: float
    worst_at: tuple[int, int]
    """(sample, cable), both 0-based."""
    noise_m: float
    redundancy: int
    """Equations minus free unknowns."""
    anchor_std_m: FloatArray
    """Predicted 1-sigma position uncertainty of each anchor (RMS radius), free directions."""
    directions: tuple[Direction, ...]
    warnings: tuple[str, ...]
    gates: tuple[Gate, ...]
    converged: bool
    anchors_coplanar: bool

    @property
    def ok(self) -> bool:
        """True when every quality gate passed."""
        return all(g.ok for g in self.gates)

    @property
    def held(self) -> tuple[Direction, ...]:
        """The directions held at the configured values."""
        return tuple(d for d in self.directions if d.kind == "held")

    def reels(self, reels: Sequence[ReelModel]) -> list[ReelModel]:
        """The given reel models with the calibrated offsets (cable order)."""
        return [
            replace(r, offset_rev=float(o)) for r, o in zip(reels, self.offsets_rev, strict=True)
        ]

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready description (no NaN or inf: unbounded deviations are None)."""
        return {
            "ok": self.ok,
            "node_ids": list(self.node_ids),
            "anchors_m": self.anchors_m.tolist(),
            "config_anchors_m": self.config_anchors_m.tolist(),
            "anchor_change_m": (self.anchors_m - self.config_anchors_m).tolist(),
            "anchor_std_m": [_finite_or_none(v) for v in self.anchor_std_m],
            "offsets_rev": self.offsets_rev.tolist(),
            "rms_residual_m": self.rms_m,
            "rms_per_dof_m": self.rms_per_dof_m,
            "worst_residual_m": self.worst_m,
            "worst_at": {"sample": self.worst_at[0], "cable": self.worst_at[1] + 1},
            "noise_m": self.noise_m,
            "redundancy": self.redundancy,
            "n_poses": int(self.poses_m.shape[0]),
            "poses_m": self.poses_m.tolist(),
            "frame": "best-fit rigid (Kabsch) alignment to the configured anchors",
            "anchors_coplanar": self.anchors_coplanar,
            "directions": [
                {
                    "kind": d.kind,
                    "std_m": d.std_m,
                    "vector": [list(v) for v in d.vector],
                    "words": d.words,
                    "change_m": d.change_m,
                }
                for d in self.directions
            ],
            "warnings": list(self.warnings),
            "gates": [{"name": g.name, "ok": g.ok, "detail": g.detail} for g in self.gates],
            "converged": self.converged,
        }


def _finite_or_none(v: float) -> float | None:
    f = float(v)
    return f if math.isfinite(f) and f <= _UNBOUNDED_STD_M else None


def _length(v: float) -> str:
    return f"{v:.3g} m" if v >= 1.0 else f"{v * 1e3:.3g} mm"


def minimum_poses(n_cables: int) -> int:
    """The fewest poses `calibrate` accepts for `n_cables` cables (>= 4).

    Each pose adds N equations and 3 unknowns; the anchors and offsets are 4N unknowns less
    the 6 of the frame; at least N equations are left over as a check. Raises
    CalibrationError for fewer than four cables.
    """
    n = int(n_cables)
    if n < MIN_CABLES:
        raise CalibrationError(
            f"{n} cables: with three cables every pose fits any anchors, so the samples say "
            f"nothing about them; calibration needs {MIN_CABLES} or more"
        )
    return math.ceil((4 * n - 6 + n) / (n - 3))


def recommended_poses(n_cables: int) -> int:
    """How many poses to record for `n_cables` cables: RECOMMENDED_POSES, or twice the
    minimum when that is more (28 for four cables). Fewer give a warning; `calibrate collect
    --auto` visits this many by default. Raises CalibrationError for fewer than four cables."""
    return max(RECOMMENDED_POSES, 2 * minimum_poses(n_cables))


def _check_samples(samples: Samples, n: int, pose_height_m: float | None = None) -> list[str]:
    """Refuse degenerate sample sets; return warnings for weak ones (`pose_height_m`: the
    height range the workspace allows poses, when known)."""
    k_min = minimum_poses(n)
    k_rec = recommended_poses(n)
    k = samples.n_poses
    if samples.motor_rev.shape != (k, n) or samples.believed_m.shape != (k, 3):
        raise CalibrationError(
            f"samples hold {samples.motor_rev.shape[1]} reels, the configuration has {n}"
        )
    if k < k_min:
        unknowns = 4 * n - 6 + 3 * k
        raise CalibrationError(
            f"{k} poses give {k * n} equations for {unknowns} unknowns ({n} anchors, {n} "
            f"offsets, {k} poses, less the 6 of the frame); {n} cables need at least {k_min} "
            f"poses (recommended {k_rec})"
        )
    distinct = np.unique(np.round(samples.believed_m / DISTINCT_POSE_M), axis=0).shape[0]
    if distinct < k_min:
        raise CalibrationError(
            f"only {distinct} distinct poses among {k} samples (closer than "
            f"{DISTINCT_POSE_M * 1e3:g} mm count as one); {n} cables need at least {k_min}"
        )
    _, thick, spread = plane_fit(samples.believed_m)
    if thick < COPLANAR_POSES_RATIO * spread:
        raise CalibrationError(
            f"the {k} poses lie within {_length(thick)} (RMS) of one plane while they "
            f"spread {spread:.3g} m: the anchors' distance from that plane is not determined; "
            "record poses at different heights as well as different x and y"
        )
    warnings: list[str] = []
    height_used = pose_height_m is not None and thick >= THIN_POSES_OF_HEIGHT * pose_height_m / 2
    if thick < THIN_POSES_RATIO * spread and not height_used:
        room = "" if pose_height_m is None else f" (the workspace allows {pose_height_m:.3g} m)"
        warnings.append(
            f"poses nearly coplanar: RMS {_length(thick)} from one plane against a spread "
            f"of {spread:.3g} m; spread them more in height{room}"
        )
    if k < k_rec:
        warnings.append(f"few poses ({k}): {k_rec} or more give a better check")
    return warnings


class _Problem:
    """Residuals, Jacobian and information matrix for fixed samples and reel models."""

    def __init__(
        self, reels0: Sequence[ReelModel], rev: FloatArray, stretch: FloatArray | None = None
    ) -> None:
        self.reels0 = list(reels0)
        self.rev = rev
        self.k, self.n = rev.shape
        self.stretch = np.ones((self.k, self.n)) if stretch is None else stretch

    def lengths(self, offsets: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Cable lengths (K, N), stretched by the planned tensions, and their slopes
        d length / d motor turn."""
        length = np.empty((self.k, self.n))
        slope = np.empty((self.k, self.n))
        for i, reel in enumerate(self.reels0):
            o = float(offsets[i])
            for kk in range(self.k):
                x = float(self.rev[kk, i]) - o
                length[kk, i] = reel.length_m(x)
                slope[kk, i] = reel.length_rate_mps(x, 1.0)
        return length * self.stretch, slope * self.stretch

    @staticmethod
    def units(anchors: FloatArray, poses: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Distances (K, N) and unit vectors anchor -> pose (K, N, 3)."""
        d = poses[:, None, :] - anchors[None, :, :]
        dist = np.linalg.norm(d, axis=2)
        return dist, d / dist[:, :, None]

    def residuals(self, anchors: FloatArray, offsets: FloatArray, poses: FloatArray) -> FloatArray:
        """r_ik = reel length - distance, (K, N)."""
        length, _ = self.lengths(offsets)
        dist, _ = self.units(anchors, poses)
        return np.asarray(length - dist, dtype=np.float64)

    def information(
        self, anchors: FloatArray, offsets: FloatArray, poses: FloatArray
    ) -> FloatArray:
        """The (3N, 3N) information about the anchors for unit noise, offsets and poses free.

        Per pose the pose's three columns are projected out (their 3x3 block is inverted in
        closed form), then the offsets are eliminated: the Schur complement of J^T J.
        """
        n, k = self.n, self.k
        _, slope = self.lengths(offsets)
        _, e = self.units(anchors, poses)
        jc = np.zeros((k, n, 4 * n))
        for i in range(n):
            jc[:, i, 3 * i : 3 * i + 3] = e[:, i, :]
            jc[:, i, 3 * n + i] = -slope[:, i]
        ete = np.einsum("kic,kid->kcd", e, e)
        proj = np.einsum("kic,kcd,kjd->kij", e, np.linalg.pinv(ete), e)
        m = np.eye(n)[None, :, :] - proj
        mj = np.einsum("kij,kjb->kib", m, jc)
        sc = jc.reshape(-1, 4 * n).T @ mj.reshape(-1, 4 * n)
        saa, sao, soo = sc[: 3 * n, : 3 * n], sc[: 3 * n, 3 * n :], sc[3 * n :, 3 * n :]
        s = saa - sao @ np.linalg.pinv(soo) @ sao.T
        return np.asarray(0.5 * (s + s.T), dtype=np.float64)


@dataclass
class _Spectrum:
    std_per_noise: FloatArray
    """sqrt(1/lambda) per direction, descending (inf: not seen)."""
    coords: FloatArray
    """Eigenvectors in the rigid-free coordinates, columns matching std_per_noise."""
    vectors: FloatArray
    """The same as (3N,) anchor displacement vectors, columns."""


def _spectrum(info: FloatArray, q: FloatArray) -> _Spectrum:
    c = q.T @ info @ q
    lam, w = np.linalg.eigh(0.5 * (c + c.T))
    floor = 1e-13 * max(float(lam.max()), 1e-300)
    with np.errstate(divide="ignore"):
        std = np.where(lam > floor, 1.0 / np.sqrt(np.maximum(lam, floor)), math.inf)
    return _Spectrum(std_per_noise=std, coords=w, vectors=q @ w)


def _describe(vec: FloatArray, anchors_m: FloatArray) -> str:
    """Words for an anchor deformation: a stretch of the layout along an axis when it is one
    (to 95 %), else which anchors move which way."""
    n = anchors_m.shape[0]
    v = vec.reshape(n, 3)
    c = anchors_m - anchors_m.mean(axis=0)
    for axis in range(3):
        stretch = np.zeros_like(c)
        stretch[:, axis] = c[:, axis]
        size = float(np.linalg.norm(stretch))
        if size > 0.0 and abs(float(np.sum(stretch * v))) / size >= 0.95:
            low = [i + 1 for i in range(n) if c[i, axis] < -1e-9 * size]
            high = [i + 1 for i in range(n) if c[i, axis] > 1e-9 * size]
            return (
                f"the layout's spread along {'xyz'[axis]} (anchors "
                f"{', '.join(map(str, low))} against {', '.join(map(str, high))})"
            )
    norms = np.linalg.norm(v, axis=1)
    parts = []
    for i in range(n):
        if norms[i] < 0.3 * norms.max():
            continue
        comps = [
            f"{'+' if v[i, ax] > 0 else '-'}{'xyz'[ax]}"
            for ax in np.argsort(-np.abs(v[i]))
            if abs(v[i, ax]) >= 0.3 * np.abs(v[i]).max()
        ]
        parts.append(f"{i + 1} {' '.join(comps)}")
    return f"anchors {', '.join(parts)}"


def _readable(coords: FloatArray, q: FloatArray, n: int) -> FloatArray:
    """The subspace spanned by `coords` (columns, in the rigid-free coordinates) in a readable
    basis: the first vector moves the anchors along x as much as the subspace allows, the
    others are orthogonal to it; signs make the first large component positive."""
    vectors = q @ coords
    sel = np.zeros(3 * n)
    sel[0::3] = 1.0
    m = vectors.T @ (sel[:, None] * vectors)
    _, w = np.linalg.eigh(0.5 * (m + m.T))
    out = coords @ w[:, ::-1]
    for j in range(out.shape[1]):
        col = q @ out[:, j]
        if col[int(np.argmax(np.abs(col) > 0.3 * np.abs(col).max()))] < 0:
            out[:, j] = -out[:, j]
    return np.asarray(out, dtype=np.float64)


def _marginal_std(spec: _Spectrum, coords: FloatArray) -> float:
    """Predicted std per unit noise along one direction (rigid-free coordinates)."""
    weights = (spec.coords.T @ coords) ** 2
    used = weights > 1e-12
    return math.sqrt(float(np.sum(weights[used] * spec.std_per_noise[used] ** 2)))


def _direction(kind: str, std_m: float, vec: FloatArray, anchors_m: FloatArray) -> Direction:
    n = anchors_m.shape[0]
    return Direction(
        kind=kind,
        std_m=_finite_or_none(std_m),
        vector=tuple((float(x), float(y), float(z)) for x, y, z in vec.reshape(n, 3).tolist()),
        words=_describe(vec, anchors_m),
    )


def _solve(
    problem: _Problem,
    a_cfg: FloatArray,
    basis: FloatArray,
    a_start: FloatArray,
    o_start: FloatArray,
    p_start: FloatArray,
    z_max: float | None,
    prior: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, bool]:
    """Least squares over the anchors (a_cfg + basis @ z), offsets and poses; `prior` (h, f)
    adds the residuals prior @ z (the pull toward the configured anchors). `z_max` keeps
    every pose below it (a hanging robot); None leaves the poses free (among the anchors,
    whose other cables tell a pose from its mirror image)."""
    try:
        from scipy.optimize import least_squares
    except ImportError as exc:
        raise CalibrationUnavailable(
            "the anchor calibration needs scipy (pip install 'cablebot[bench]')"
        ) from exc
    k, n = problem.k, problem.n
    nf = basis.shape[1]
    bi = basis.reshape(n, 3, nf)
    rows = np.arange(k * n)
    cable = rows % n
    pose = rows // n
    # Pose k is (x, y, w) with z = z_max - exp(w): every pose stays below z_max (hanging);
    # (x, y, z) itself among the anchors.

    def unpack(x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        a = a_cfg + (basis @ x[:nf]).reshape(n, 3)
        q = x[nf + n :].reshape(k, 3)
        if z_max is None:
            return a, x[nf : nf + n], q
        p = np.column_stack([q[:, 0], q[:, 1], z_max - np.exp(np.minimum(q[:, 2], 30.0))])
        return a, x[nf : nf + n], p

    h = prior.shape[0]

    def fun(x: FloatArray) -> FloatArray:
        r = problem.residuals(*unpack(x)).ravel()
        return np.concatenate([r, prior @ x[:nf]]) if h else r

    def jac(x: FloatArray) -> FloatArray:
        a, o, p = unpack(x)
        _, slope = problem.lengths(o)
        _, e = problem.units(a, p)
        j = np.zeros((k * n + h, nf + n + 3 * k))
        j[: k * n, :nf] = np.einsum("kic,icf->kif", e, bi).reshape(k * n, nf)
        j[rows, nf + cable] = -slope.ravel()
        ef = e.reshape(-1, 3)
        j[rows, nf + n + 3 * pose] = -ef[:, 0]
        j[rows, nf + n + 3 * pose + 1] = -ef[:, 1]
        if z_max is None:
            j[rows, nf + n + 3 * pose + 2] = -ef[:, 2]
        else:
            j[rows, nf + n + 3 * pose + 2] = ef[:, 2] * (z_max - p[pose, 2])
        j[k * n :, :nf] = prior
        return j

    q0 = (
        p_start
        if z_max is None
        else np.column_stack(
            [p_start[:, 0], p_start[:, 1], np.log(np.maximum(z_max - p_start[:, 2], 1e-9))]
        )
    )
    x0 = np.concatenate([basis.T @ (a_start - a_cfg).ravel(), o_start, q0.ravel()])
    res = least_squares(
        fun,
        x0,
        jac=jac,
        method="lm",
        x_scale="jac",
        xtol=1e-14,
        ftol=1e-14,
        gtol=1e-14,
        max_nfev=100 * (x0.size + 1),
    )
    a, o, p = unpack(np.asarray(res.x, dtype=np.float64))
    return a, o.copy(), p.copy(), bool(res.status > 0)


def _starting_point(
    a_cfg: FloatArray,
    reels0: Sequence[ReelModel],
    samples: Samples,
    problem: _Problem,
    hanging: bool,
) -> tuple[FloatArray, float | None, FloatArray]:
    """The solve's start: the believed poses (lowered where needed), the height every pose
    stays below (None among the anchors), and the offsets that fit them. Raises
    CalibrationError when every pose of a hanging robot is at or above the lowest anchor or a
    reel cannot reach the believed lengths."""
    if not hanging:
        p_free = samples.believed_m.copy()
        return p_free, None, _offsets(a_cfg, reels0, samples, problem, p_free)
    # Starting point: the configured anchors, the believed poses and the offsets that fit them.
    # A pose believed near the anchors' height (the controller's FPK of inconsistent lengths
    # meets the anchor plane there) starts a little lower. During the solve every pose stays
    # below z_max, halfway between the highest start and the lowest anchor: with the anchors
    # (nearly) in one plane a pose can otherwise settle in that plane, cables horizontal, the
    # offsets absorbing the difference: a second solution no suspended robot can be in.
    p0 = samples.believed_m.copy()
    a_low = float(a_cfg[:, 2].min())
    height = a_low - float(p0[:, 2].min())
    if not height > 0.0:
        raise CalibrationError(
            "every believed pose is at or above the lowest anchor: the samples do not belong "
            "to this configuration"
        )
    p0[:, 2] = np.minimum(p0[:, 2], a_low - START_BELOW_ANCHORS_RATIO * height)
    z_max = a_low - 0.5 * (a_low - float(p0[:, 2].max()))
    return p0, z_max, _offsets(a_cfg, reels0, samples, problem, p0)


def _offsets(
    a_cfg: FloatArray,
    reels0: Sequence[ReelModel],
    samples: Samples,
    problem: _Problem,
    p0: FloatArray,
) -> FloatArray:
    """The reel offsets that fit the poses `p0` with the configured anchors (mean over the
    poses). Raises CalibrationError when a reel cannot reach the believed lengths."""
    n = a_cfg.shape[0]
    k = samples.n_poses
    dist0, _ = problem.units(a_cfg, p0)
    dist0 = dist0 / problem.stretch  # what the reels paid out for those lengths
    o0 = np.empty(n)
    for i, reel in enumerate(reels0):
        try:
            o0[i] = np.mean(
                [
                    reel.with_home(float(samples.motor_rev[kk, i]), float(dist0[kk, i])).offset_rev
                    for kk in range(k)
                ]
            )
        except ValueError as exc:
            raise CalibrationError(f"reel of cable {i + 1}: {exc}") from exc
    return o0


def _add_warnings(
    warnings: list[str],
    directions: Sequence[Direction],
    anchor_std: FloatArray,
    coplanar: bool,
    st: Settings,
) -> None:
    """Append to `warnings` what the solution leaves uncertain: coplanar anchors, held and
    weak directions, poorly determined anchors. Raises nothing."""
    n = anchor_std.shape[0]
    if coplanar:
        warnings.append(
            "the anchors lie in one plane: stretches of the layout within that plane change "
            "the cable lengths little or not at all"
        )
    for d in directions:
        if d.kind == "held":
            seen = "not at all" if d.std_m is None else f"to ±{d.std_m * 1e3:.2g} mm"
            warnings.append(
                f"not seen by the samples ({seen}, worse than the {st.hold_std_m * 1e3:g} mm "
                f"hold threshold): {d.words}; held near the configured values (moved "
                f"{(d.change_m or 0.0) * 1e3:+.2g} mm)"
            )
    for d in directions:
        if d.kind == "weak":
            warnings.append(f"poorly determined (±{(d.std_m or math.inf) * 1e3:.2g} mm): {d.words}")
    for i in range(n):
        if anchor_std[i] > st.weak_std_m:
            warnings.append(f"anchor {i + 1} is poorly determined (±{anchor_std[i] * 1e3:.2g} mm)")


def _inside_gate(anchors_m: FloatArray, poses_m: FloatArray) -> Gate:
    """Among the anchors: every fitted pose inside the fitted anchors' hull (a pose outside
    is a mirror image, or the anchors moved where no robot could be)."""
    from controller.core.kinematics import Geometry, KinematicsError

    try:
        faces = Geometry(anchors_m, hanging=False).hull_faces
    except KinematicsError as exc:
        return Gate("inside_hull", False, f"the fitted anchors have no hull to work in: {exc}")
    tol = 1e-6 * float(np.ptp(anchors_m, axis=0).max())
    out = sum(
        1
        for x, y, z in poses_m.tolist()
        if any(nx * x + ny * y + nz * z > c + tol for nx, ny, nz, c, _ in faces)
    )
    return Gate(
        "inside_hull",
        out == 0,
        f"{out} pose(s) fitted outside the anchors' hull (a mirror solution)"
        if out
        else "every pose fitted inside the anchors' hull",
    )


def _gates(
    st: Settings,
    rms_dof: float,
    rms: float,
    worst: float,
    free_bad: int,
    held: int,
    converged: bool,
    a: FloatArray,
    p: FloatArray,
    hanging: bool,
) -> tuple[Gate, ...]:
    """The quality gates of a calibration (module docstring)."""
    inside_gate = _inside_gate(a, p) if not hanging else None
    high = int(np.sum(p[:, 2] >= float(a[:, 2].min())))
    return (
        Gate(
            "rms",
            rms_dof <= st.max_rms_m,
            f"RMS residual per redundant equation {rms_dof * 1e3:.3g} mm <= "
            f"{st.max_rms_m * 1e3:g} mm (plain RMS {rms * 1e3:.3g} mm)",
        ),
        Gate(
            "worst",
            worst <= st.max_residual_m,
            f"worst residual {worst * 1e3:.3g} mm <= {st.max_residual_m * 1e3:g} mm",
        ),
        Gate(
            "observable",
            free_bad == 0,
            f"{free_bad} direction(s) seen worse than {st.hold_std_m * 1e3:g} mm left free, "
            f"{held} held near the configured values",
        ),
        Gate("converged", converged, "the least-squares solve converged"),
        inside_gate
        or Gate(
            "below_anchors",
            high <= 0,
            f"{high} pose(s) fitted above the lowest anchor (a mirror solution)"
            if high
            else "every pose fitted below the anchors",
        ),
    )


StretchFactors = Callable[[FloatArray, FloatArray], FloatArray]
"""(anchors (N, 3), poses (K, 3)) -> (K, N): how much longer than paid out each elastic cable
is at each pose, ``(EA + t) / EA`` under the tension planned there with those anchors (1 for a
rigid cable); raises CalibrationError where there are no tensions."""


def calibrate(
    anchors_m: Any,
    reels: Sequence[ReelModel],
    samples: Samples,
    settings: Settings | None = None,
    *,
    pose_height_m: float | None = None,
    hanging: bool = True,
    stretch: StretchFactors | None = None,
) -> Calibration:
    """Estimate the anchors and reel offsets that best explain `samples`.

    `pose_height_m` is the height range the workspace allows poses (floor to top), when
    known: poses that use it well are not warned about as nearly coplanar however wide.
    `hanging` (the layout's `Geometry.hanging`): the effector hangs below every anchor, and
    the solve keeps every pose below them (a pose in the anchors' plane is a second solution
    no hanging robot can be in); False: the effector works among its anchors (a Hangprinter),
    the poses are free and the last gate asks that they stay inside the anchors' hull.
    `stretch` (elastic cables; None: rigid): the stretch factors at given anchors and poses.
    The tensions depend on the anchors, which the configuration has centimetres off: the fit
    is made with the factors at the configured anchors and the believed poses, then again
    with those at the anchors and poses it found (a third fit changes the anchors by
    hundredths of a millimetre on a Hangprinter with 3-10 cm anchor errors).

    `anchors_m` (N, 3) and `reels` are the configuration's, in cable order (the reels' own
    offsets are ignored). See the module docstring for the model, the frame convention, the
    held directions and the gates; the result carries the gates, it does not raise on them.
    Raises CalibrationError for degenerate samples (fewer than four cables, too few or
    repeated poses, coplanar poses), stretch factors that are not (K, N) finite numbers
    >= 1 (and what `stretch` raises), or a reel that cannot reach the believed lengths, and
    CalibrationUnavailable when scipy is missing.
    """
    a_cfg = np.asarray(anchors_m, dtype=np.float64)
    if stretch is None:
        return _calibrate(a_cfg, reels, samples, settings, pose_height_m, hanging, None)
    first = _calibrate(
        a_cfg,
        reels,
        samples,
        settings,
        pose_height_m,
        hanging,
        stretch(a_cfg, samples.believed_m),
    )
    return _calibrate(
        a_cfg,
        reels,
        samples,
        settings,
        pose_height_m,
        hanging,
        stretch(first.anchors_m, first.poses_m),
    )


def _calibrate(
    anchors_m: Any,
    reels: Sequence[ReelModel],
    samples: Samples,
    settings: Settings | None,
    pose_height_m: float | None,
    hanging: bool,
    stretch_factors: Any,
) -> Calibration:
    """`calibrate` with fixed stretch factors (K, N) (None: rigid cables)."""
    st = settings if settings is not None else Settings()
    a_cfg = np.asarray(anchors_m, dtype=np.float64)
    n = a_cfg.shape[0]
    if a_cfg.shape != (n, 3) or len(reels) != n:
        raise CalibrationError(f"{len(reels)} reels for anchors of shape {a_cfg.shape}")
    warnings = _check_samples(samples, n, pose_height_m)
    k = samples.n_poses
    reels0 = [replace(r, offset_rev=0.0) for r in reels]
    stretch = None
    if stretch_factors is not None:
        stretch = np.asarray(stretch_factors, dtype=np.float64)
        if stretch.shape != (k, n) or not bool(np.all(np.isfinite(stretch) & (stretch >= 1.0))):
            raise CalibrationError(
                f"stretch factors must be ({k}, {n}) finite numbers >= 1, got shape {stretch.shape}"
            )
    problem = _Problem(reels0, samples.motor_rev, stretch)

    p0, z_max, o0 = _starting_point(a_cfg, reels0, samples, problem, hanging)

    q = orthogonal_complement(rigid_basis(a_cfg))
    dq = q.shape[1]
    # Rounds: find the directions the samples see worse than hold_std_m (linearised, at the
    # current estimate, with the current noise estimate), fit with a prior holding them near
    # the configured values, re-estimate the noise; until the held set stops growing.
    sigma = max(st.noise_floor_m, st.assumed_noise_m)
    a, o, p = a_cfg.copy(), o0, p0
    held_c = np.zeros((dq, 0))
    converged = False
    for _ in range(4):
        spec = _spectrum(problem.information(a, o, p), q)
        blind = spec.coords[:, spec.std_per_noise * sigma > st.hold_std_m]
        if blind.shape[1]:
            # Add what is new, orthogonal to what is held already.
            new = blind - held_c @ (held_c.T @ blind)
            u, sv, _ = np.linalg.svd(new, full_matrices=False)
            new = u[:, sv > 0.5]
        else:
            new = np.zeros((dq, 0))
        if converged and new.shape[1] == 0:
            break
        if new.shape[1]:
            held_c = _readable(np.column_stack([held_c, new]), q, n)
        prior = (sigma / st.hold_std_m) * held_c.T
        a, o, p, converged = _solve(problem, a_cfg, q, a_cfg, o0, p0, z_max, prior)
        r_now = problem.residuals(a, o, p)
        dof = k * n - (dq - held_c.shape[1] + n + 3 * k)
        sigma = max(st.noise_floor_m, math.sqrt(float((r_now**2).sum()) / max(dof, 1)))
    free = q @ orthogonal_complement(held_c) if held_c.shape[1] else q
    solved_free = free.shape[1]
    spec = _spectrum(problem.information(a, o, p), q)

    r = problem.residuals(a, o, p)
    rms = float(math.sqrt(float((r**2).mean())))
    redundancy = k * n - (solved_free + n + 3 * k)
    # The residuals' RMS understates the noise: the fit absorbed part of it in its unknowns.
    # Per redundant equation it estimates the cable-length noise itself; the gate uses that.
    rms_dof = float(math.sqrt(float((r**2).sum()) / max(redundancy, 1)))
    worst_idx = np.unravel_index(int(np.argmax(np.abs(r))), r.shape)
    worst = float(abs(r[worst_idx]))

    info = problem.information(a, o, p)
    directions: list[Direction] = []
    change_c = q.T @ (a - a_cfg).ravel()
    for j in range(held_c.shape[1]):
        std = _marginal_std(spec, held_c[:, j]) * sigma
        d = _direction("held", std, q @ held_c[:, j], a_cfg)
        directions.append(replace(d, change_m=float(held_c[:, j] @ change_c)))
    # What the samples see at the solution, in the directions left free.
    lam, w = np.linalg.eigh(free.T @ info @ free)
    floor = 1e-13 * max(float(lam.max()), 1e-300)
    free_std = np.full(lam.shape, math.inf)
    cov = np.zeros((3 * n, 3 * n))
    for j in range(lam.size):
        vec = free @ w[:, j]
        if lam[j] > floor:
            free_std[j] = sigma / math.sqrt(float(lam[j]))
            cov += np.outer(vec, vec) * free_std[j] ** 2
        if free_std[j] > st.weak_std_m:
            directions.append(_direction("weak", float(free_std[j]), vec, a_cfg))
    anchor_std = np.sqrt(
        np.array([np.trace(cov[3 * i : 3 * i + 3, 3 * i : 3 * i + 3]) for i in range(n)])
    )

    _, a_thick, a_spread = plane_fit(a_cfg)
    coplanar = a_thick <= ANCHORS_COPLANAR_RATIO * a_spread
    free_bad = [float(v) for v in free_std if v > st.hold_std_m]
    _add_warnings(warnings, directions, anchor_std, bool(coplanar), st)

    gates = _gates(
        st, rms_dof, rms, worst, len(free_bad), held_c.shape[1], converged, a, p, hanging
    )
    return Calibration(
        node_ids=samples.node_ids,
        anchors_m=a,
        config_anchors_m=a_cfg.copy(),
        offsets_rev=o,
        poses_m=p,
        residuals_m=r,
        rms_m=rms,
        rms_per_dof_m=rms_dof,
        worst_m=worst,
        worst_at=(int(worst_idx[0]), int(worst_idx[1])),
        noise_m=sigma,
        redundancy=int(redundancy),
        anchor_std_m=anchor_std,
        directions=tuple(directions),
        warnings=tuple(warnings),
        gates=gates,
        converged=converged,
        anchors_coplanar=bool(coplanar),
    )
