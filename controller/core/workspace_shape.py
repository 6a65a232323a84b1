"""The shape of a workspace among the anchors: the anchors' convex hull, each face moved in by a
margin measured across the plan view, cut by a floor and a top, and what that solid looks like
from above.  The rules and their reasons are ``controller.core.workspace``'s; this module only
computes shapes (once, when a ``Workspace`` is built).

Pure module (``math``), plain floats.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

from controller.core.kinematics.geometry import HullFace

__all__ = ["Face", "disk_polygon", "shrunk_faces", "solid_vertices"]

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]
Face = tuple[float, float, float, float]
"""(nx, ny, nz, c), (nx, ny, nz) a unit outward normal: inside is ``nx x + ny y + nz z <= c``."""

_VERTEX_TOL_M = 1e-9


def shrunk_faces(faces: Sequence[HullFace], margin_m: float) -> tuple[Face, ...]:
    """The hull's faces each moved inward so that, at every height, the solid's cross-section
    is the hull's shrunk by `margin_m` (the plan-view margin): a face moves by `margin_m` times
    the horizontal part of its normal (a wall by the margin, a floor-like face not at all)."""
    return tuple((nx, ny, nz, c - margin_m * math.hypot(nx, ny)) for nx, ny, nz, c, _ in faces)


def solid_vertices(faces: Sequence[Face], floor_z_m: float, top_z_m: float) -> list[Vec3]:
    """The corners of the solid ``faces`` cut to ``floor_z_m <= z <= top_z_m`` (every point
    where three of the planes meet and that is inside all of them); empty when nothing is
    left."""
    planes: list[Face] = [*faces, (0.0, 0.0, -1.0, -floor_z_m), (0.0, 0.0, 1.0, top_z_m)]
    out: list[Vec3] = []
    for (a1, a2, a3, c1), (b1, b2, b3, c2), (d1, d2, d3, c3) in itertools.combinations(planes, 3):
        det = a1 * (b2 * d3 - b3 * d2) - a2 * (b1 * d3 - b3 * d1) + a3 * (b1 * d2 - b2 * d1)
        if abs(det) < 1e-12:
            continue
        x = (c1 * (b2 * d3 - b3 * d2) - a2 * (c2 * d3 - b3 * c3) + a3 * (c2 * d2 - b2 * c3)) / det
        y = (a1 * (c2 * d3 - b3 * c3) - c1 * (b1 * d3 - b3 * d1) + a3 * (b1 * c3 - c2 * d1)) / det
        z = (a1 * (b2 * c3 - c2 * d2) - a2 * (b1 * c3 - c2 * d1) + c1 * (b1 * d2 - b2 * d1)) / det
        if all(nx * x + ny * y + nz * z <= c + _VERTEX_TOL_M for nx, ny, nz, c in planes):
            out.append((x, y, z))
    return out


def disk_polygon(radius_m: float, sides: int = 64) -> tuple[Vec2, ...]:
    """A regular polygon inscribed in the circle of `radius_m` about the origin, counter-
    clockwise: the print radius where a polygon is needed (drawing, sampling)."""
    return tuple(
        (
            radius_m * math.cos(2.0 * math.pi * k / sides),
            radius_m * math.sin(2.0 * math.pi * k / sides),
        )
        for k in range(sides)
    )
