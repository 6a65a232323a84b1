"""The anchor layout of a point-mass cable robot, and its inverse kinematics.

Pure module: ``math`` and ``numpy`` only.

Conventions (the whole package)
-------------------------------
* SI units, metres.  The world frame {A} has z up; the anchors (pulley exit points) ``B_i``
  are the rows of ``Geometry.anchors_m``.  All cables meet in one point P (no rotation).
* Cable *indices* in data (``seed_triple``, arrays) are 0-based, as in Python; cable *names*
  in error messages are 1-based (``cable 1`` is row 0), as in the paper (B1..B4).
* Nothing returns NaN or inf: inputs are checked, and outputs are finite or an exception is
  raised (single pose) / the row is flagged invalid (batch).

Two kinds of layout (``Geometry.hanging``): the effector *hangs* below every anchor (the
paper's robot, camera rigs: a suspended robot), or it works *among* the anchors, some of them
below it (a Hangprinter's three or four low anchors and one on the ceiling), inside their
convex hull, which then must have a volume.  The two differ in which of the two mirror
solutions of three cables the FPK starts from (``controller.core.kinematics.fit``).

``Geometry`` validates the anchors once and precomputes everything the FPK needs that depends
on them alone.  A triple of anchors is usable by the three-spheres algorithms unless it is
collinear in plan view: the paper's algorithmic singularity (eqs. 13-14) is twice the signed
plan-view area of the triangle, here compared with ``SINGULAR_REL_TOL`` times the squared
plan-view span of all anchors.  The *seed triple* is the usable triple with the largest
plan-view triangle (the best conditioned), an equal-height one preferred among equals so that
the paper's simplified algorithm applies; among the anchors (not hanging) only a face of
their hull qualifies, so that the effector is always on one known side of its plane
(``seed_up``: above it).

IPK is the distance from P to each anchor: ``ipk_point`` in pure Python floats for the
control tick, ``ipk`` vectorised over rows.  ``Geometry.footprint_m`` is the anchors' plan-view
convex hull; whether a point is inside it (with a margin) is decided by
``controller.core.workspace``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from controller.core.kinematics.errors import KinematicsError, SingularGeometryError
from controller.core.kinematics.fitgen import AmongFit, _make_among
from controller.core.kinematics.fitplan import (
    _Fit,
    _Linear,
    _make_fit,
    _make_linear,
    _make_planar4,
    _Planar4,
)
from controller.core.kinematics.spheres import (
    Vec3,
    _EqualSeed,
    _GeneralSeed,
    _make_equal_seed,
    _make_general_seed,
)

__all__ = [
    "COINCIDENT_TOL_M",
    "COPLANAR_REL_TOL",
    "HEIGHT_TOL_M",
    "SINGULAR_REL_TOL",
    "Geometry",
    "HullFace",
    "ipk",
    "ipk_point",
    "paper_anchors",
]

FloatArray = npt.NDArray[np.float64]

#: Anchors closer than this are coincident.
COINCIDENT_TOL_M = 1e-6
#: Anchor heights within this of each other count as equal (simplified algorithm allowed).
HEIGHT_TOL_M = 1e-9
#: A triple is singular (eq. 14) when its plan-view triangle's doubled area |ae-bd|/4 is below
#: this fraction of the squared plan-view span of the anchors.
SINGULAR_REL_TOL = 1e-6
#: Anchors within this fraction of their span from one plane lie in it (no hull volume).
COPLANAR_REL_TOL = 1e-6

# Module-level alias: one global lookup per call.
_sqrt = math.sqrt


def _plan_cross(a: Sequence[float], b: Sequence[float], c: Sequence[float]) -> float:
    """(x3-x1)(y3-y2) - (y3-y1)(x3-x2): eq. 13 divided by 4 (twice the signed plan area)."""
    return (c[0] - a[0]) * (c[1] - b[1]) - (c[1] - a[1]) * (c[0] - b[0])


def _convex_hull(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Counter-clockwise convex hull (Andrew's monotone chain), collinear points dropped."""
    pts = sorted(set(points))
    if len(pts) < 3:
        return pts

    def cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[tuple[float, float]] = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0.0:
            lower.pop()
        lower.append(p)
    upper: list[tuple[float, float]] = []
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0.0:
            upper.pop()
        upper.append(p)
    return lower[:-1] + upper[:-1]


HullFace = tuple[float, float, float, float, tuple[int, ...]]
"""A face of the anchors' hull: its outward unit normal (nx, ny, nz), c (inside is
``nx x + ny y + nz z <= c``) and the anchors (0-based) on it."""


def _hull_faces(
    pts: Sequence[Vec3],
) -> tuple[dict[tuple[int, int, int], bool], tuple[HullFace, ...]]:
    """The triples of anchors that are faces of their convex hull (every other anchor on one
    side of the triple's plane, or in it), each with whether that side is above the plane
    (its normal turned up); and the hull's faces as planes, one per plane.  Raises
    ``SingularGeometryError`` when the anchors lie in one plane (a hull without volume)."""
    span = max(math.dist(a, b) for a, b in itertools.combinations(pts, 2))
    tol = COPLANAR_REL_TOL * span
    faces: dict[tuple[int, int, int], bool] = {}
    planes: list[HullFace] = []
    flat = True
    for tri in itertools.combinations(range(len(pts)), 3):
        a, b, c = (pts[k] for k in tri)
        ux, uy, uz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
        vx, vy, vz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        norm = math.sqrt(nx * nx + ny * ny + nz * nz)
        if not norm > tol * span:
            continue  # collinear
        if nz < 0.0 or (nz == 0.0 and (ny < 0.0 or (ny == 0.0 and nx < 0.0))):
            nx, ny, nz = -nx, -ny, -nz
        sides = [
            ((p[0] - a[0]) * nx + (p[1] - a[1]) * ny + (p[2] - a[2]) * nz) / norm
            for k, p in enumerate(pts)
            if k not in tri
        ]
        if any(abs(d) > tol for d in sides):
            flat = False
        if all(d >= -tol for d in sides):
            faces[tri] = True
            out = -1.0  # the hull is above: the outward normal points down
        elif all(d <= tol for d in sides):
            faces[tri] = False
            out = 1.0
        else:
            continue
        ox, oy, oz = out * nx / norm, out * ny / norm, out * nz / norm
        on = tuple(
            k
            for k, p in enumerate(pts)
            if abs((p[0] - a[0]) * ox + (p[1] - a[1]) * oy + (p[2] - a[2]) * oz) <= tol
        )
        if not any(f[4] == on for f in planes):
            planes.append((ox, oy, oz, ox * a[0] + oy * a[1] + oz * a[2], on))
    if flat:
        raise SingularGeometryError(
            "the anchors lie in one plane: an effector among them (some anchors below it) "
            "cannot be held; only a robot hanging below them can"
        )
    return faces, tuple(planes)


def _usable_triples(pts: Sequence[Vec3]) -> list[tuple[float, tuple[int, int, int]]]:
    """(doubled plan-view area, triple) of every triple not collinear in plan view (eq. 14).

    Raises ``SingularGeometryError`` when there is none.
    """
    n = len(pts)
    span2 = max((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 for a, b in itertools.combinations(pts, 2))
    limit = SINGULAR_REL_TOL * span2
    usable: list[tuple[float, tuple[int, int, int]]] = []
    for tri in itertools.combinations(range(n), 3):
        area2 = abs(_plan_cross(pts[tri[0]], pts[tri[1]], pts[tri[2]]))
        if area2 > limit:
            usable.append((area2, tri))
    if not usable:
        raise SingularGeometryError(
            "algorithmic singularity (eq. 14): "
            + ("the three anchors are" if n == 3 else "every triple of anchors is")
            + " collinear in plan view"
        )
    return usable


class Geometry:
    """Anchor layout of an N-cable point-mass robot (N >= 3), validated at construction.

    ``anchors_m`` is an (N, 3) array-like of the pulley exit points.  Raises
    ``KinematicsError`` for a wrong shape, N < 3 or non-finite numbers, and
    ``SingularGeometryError`` for coincident anchors or when no triple of anchors is usable
    by the FPK (every triple collinear in plan view, eq. 14; with N == 3 the only triple).
    Triples that are singular are simply not used when N > 3; ``triples`` lists the usable
    ones (0-based), ``seed_triple`` is the best-conditioned one (largest plan-view area),
    which seeds every FPK.

    ``height_tol_m``: anchor heights within this count as equal (``equal_heights``).
    ``hanging``: True (the default) when the effector hangs below every anchor, False when
    it works among them inside their convex hull (some anchors below it: a Hangprinter);
    then the seed triple is a face of the hull, ``seed_up`` says whether the hull lies above
    its plane, ``hull_faces`` are the hull's faces (outward unit normal, offset, the anchors
    on it; empty for a hanging layout), and ``SingularGeometryError`` is raised for fewer
    than four anchors or anchors in one plane (no hull to work in).
    """

    __slots__ = (
        "_among",
        "_anchors_t",
        "_fit",
        "_lin",
        "_p4",
        "_seed",
        "anchor_height_max_m",
        "anchor_height_min_m",
        "anchors_m",
        "equal_heights",
        "footprint_m",
        "hanging",
        "height_tol_m",
        "hull_faces",
        "n_cables",
        "seed_triple",
        "seed_up",
        "seed_uses_simplified",
        "triples",
    )

    anchors_m: FloatArray
    n_cables: int
    equal_heights: bool
    anchor_height_min_m: float
    anchor_height_max_m: float
    height_tol_m: float
    triples: tuple[tuple[int, int, int], ...]
    seed_triple: tuple[int, int, int]
    seed_uses_simplified: bool
    hanging: bool
    seed_up: bool
    footprint_m: tuple[tuple[float, float], ...]
    _anchors_t: tuple[Vec3, ...]
    _seed: _EqualSeed | _GeneralSeed
    _fit: _Fit
    _lin: _Linear | None
    _p4: _Planar4 | None
    _among: AmongFit | None

    def __init__(
        self, anchors_m: Any, height_tol_m: float = HEIGHT_TOL_M, *, hanging: bool = True
    ) -> None:
        try:
            arr = np.array(anchors_m, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise KinematicsError(f"anchors must be an (N, 3) array of numbers: {exc}") from exc
        if arr.ndim != 2 or arr.shape[1] != 3:
            raise KinematicsError(f"anchors must have shape (N, 3), got {arr.shape}")
        n = int(arr.shape[0])
        if n < 3:
            raise KinematicsError(f"need at least 3 anchors, got {n}")
        if not np.all(np.isfinite(arr)):
            raise KinematicsError("anchors must be finite numbers")
        if not (math.isfinite(height_tol_m) and height_tol_m >= 0.0):
            raise KinematicsError("height_tol_m must be finite and >= 0")
        arr.setflags(write=False)
        pts: tuple[Vec3, ...] = tuple((float(r[0]), float(r[1]), float(r[2])) for r in arr.tolist())
        for i, j in itertools.combinations(range(n), 2):
            if math.dist(pts[i], pts[j]) <= COINCIDENT_TOL_M:
                raise SingularGeometryError(f"anchors {i + 1} and {j + 1} coincide")

        usable = _usable_triples(pts)
        self.hanging = bool(hanging)
        self.seed_up = False
        self.hull_faces: tuple[HullFace, ...] = ()
        if not self.hanging:
            if n < 4:
                raise SingularGeometryError(
                    f"{n} anchors cannot surround an effector: working among the anchors "
                    "(some below it) needs at least 4"
                )
            faces, self.hull_faces = _hull_faces(pts)
            usable = [(a, t) for a, t in usable if t in faces]
            if not usable:  # pragma: no cover - a hull always has a face seen from above
                raise SingularGeometryError("no face of the anchors' hull is usable by the FPK")

        zs = [p[2] for p in pts]
        self.anchors_m = arr
        self.n_cables = n
        self.height_tol_m = float(height_tol_m)
        self.anchor_height_min_m = min(zs)
        self.anchor_height_max_m = max(zs)
        self.equal_heights = (max(zs) - min(zs)) <= height_tol_m
        self.triples = tuple(t for _, t in usable)
        self._anchors_t = pts

        def tri_equal(t: tuple[int, int, int]) -> bool:
            h = [zs[k] for k in t]
            return max(h) - min(h) <= height_tol_m

        best = max(a for a, _ in usable)
        near_best = [(a, t) for a, t in usable if a >= best * (1.0 - 1e-9)]
        # Among the best-conditioned triples prefer one the simplified algorithm can use.
        near_best.sort(key=lambda at: (not tri_equal(at[1]), at[1]))
        seed = near_best[0][1]
        if not self.hanging:
            self.seed_up = faces[seed]
        self.seed_triple = seed
        self.seed_uses_simplified = tri_equal(seed)
        self._seed = (
            _make_equal_seed(pts, seed)
            if self.seed_uses_simplified
            else _make_general_seed(pts, seed)
        )
        self._fit = _make_fit(pts, seed)
        self._lin = None if self.hanging else _make_linear(pts)
        self._among = None if self.hanging else _make_among(pts, self._lin)
        self._p4 = (
            _make_planar4(pts, self._seed, self._fit.others)
            if isinstance(self._seed, _EqualSeed) and self.hanging
            else None
        )

        # The anchors' plan-view convex hull, counter-clockwise (x, y) vertices.
        self.footprint_m = tuple(_convex_hull([(p[0], p[1]) for p in pts]))

    def __repr__(self) -> str:
        extra = "" if self.hanging else ", hanging=False"
        return f"Geometry(anchors_m={self.anchors_m.tolist()!r}{extra})"


def paper_anchors(
    half_length_m: float = 40.46, half_width_m: float = 25.0, height_m: float = 7.62
) -> FloatArray:
    """The paper's rectangular layout B1..B4 (section 2) as a (4, 3) array.

    B1=(-L/2,-W/2,h), B2=(-L/2,W/2,h), B3=(L/2,W/2,h), B4=(L/2,-W/2,h).  The defaults are
    the paper's printed anchors (x = +/-40.46 m; L/2 would be 40.45).  Raises nothing.
    """
    hl, hw = half_length_m, half_width_m
    return np.array(
        [[-hl, -hw, height_m], [-hl, hw, height_m], [hl, hw, height_m], [hl, -hw, height_m]],
        dtype=np.float64,
    )


def ipk_point(geom: Geometry, position_m: Sequence[float]) -> tuple[float, ...]:
    """Cable lengths (metres) for one point, pure Python floats (the per-tick fast path).

    Raises ``KinematicsError`` for a non-finite position.
    """
    x, y, z = position_m
    out = tuple(
        [
            _sqrt((x - ax) * (x - ax) + (y - ay) * (y - ay) + (z - az) * (z - az))
            for ax, ay, az in geom._anchors_t
        ]
    )
    s = x + y + z
    if s - s != 0.0:
        raise KinematicsError(f"position must be finite, got {tuple(position_m)!r}")
    return out


def ipk(geom: Geometry, position_m: Any) -> FloatArray:
    """Cable lengths: shape (N,) for one point (3,), (M, N) for M points (M, 3).

    Raises ``KinematicsError`` for a wrong shape or non-finite positions.
    """
    p = np.asarray(position_m, dtype=np.float64)
    if p.shape[-1:] != (3,) or p.ndim not in (1, 2):
        raise KinematicsError(f"position must have shape (3,) or (M, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise KinematicsError("position must be finite")
    diff = p[..., None, :] - geom.anchors_m
    out: FloatArray = np.sqrt(np.einsum("...k,...k->...", diff, diff))
    return out
