"""What the least-squares fit (``fit``) precomputes from the anchors, once per ``Geometry``.

``_Fit``: the cables outside the seed triple and, when that triple is tilted, its plane.
``_Planar4``: the constants of the one-multiplier fit for four anchors at one height (see the
``fit`` module docstring). Pure Python floats; depends only on the seed (``spheres``), so that
``geometry`` can build these without importing the fit itself.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from controller.core.kinematics.spheres import Vec3, _EqualSeed


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
