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

__all__ = ["Face", "disk_polygon", "face_polygons", "shrunk_faces", "solid_vertices", "wall_planes"]

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


def wall_planes(polygon_m: Sequence[Vec2]) -> list[Face]:
    """The vertical planes through the edges of the convex counter-clockwise `polygon_m`, their
    normals outward: the walls of its prism."""
    out: list[Face] = []
    for k, (ax, ay) in enumerate(polygon_m):
        bx, by = polygon_m[(k + 1) % len(polygon_m)]
        length = math.hypot(bx - ax, by - ay)
        if length > 0.0:
            nx, ny = (by - ay) / length, (ax - bx) / length
            out.append((nx, ny, 0.0, nx * ax + ny * ay))
    return out


def _clip_face(poly: list[Vec3], plane: Face) -> list[Vec3]:
    """The convex polygon `poly` cut to ``n . p <= c`` (Sutherland-Hodgman, one plane)."""
    nx, ny, nz, c = plane
    out: list[Vec3] = []
    m = len(poly)
    for k in range(m):
        p = poly[k]
        q = poly[(k + 1) % m]
        sp = nx * p[0] + ny * p[1] + nz * p[2] - c
        sq = nx * q[0] + ny * q[1] + nz * q[2] - c
        if sp <= 0.0:
            out.append(p)
        if (sp < 0.0 < sq) or (sq < 0.0 < sp):
            t = sp / (sp - sq)
            out.append(
                (p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1]), p[2] + t * (q[2] - p[2]))
            )
    return out


def _area(poly: Sequence[Vec3]) -> float:
    """The area of the planar polygon `poly` (half the length of its vector area)."""
    sx = sy = sz = 0.0
    ox, oy, oz = poly[0]
    for k in range(1, len(poly) - 1):
        ax, ay, az = poly[k][0] - ox, poly[k][1] - oy, poly[k][2] - oz
        bx, by, bz = poly[k + 1][0] - ox, poly[k + 1][1] - oy, poly[k + 1][2] - oz
        sx += ay * bz - az * by
        sy += az * bx - ax * bz
        sz += ax * by - ay * bx
    return 0.5 * math.sqrt(sx * sx + sy * sy + sz * sz)


def face_polygons(planes: Sequence[Face], reach_m: float) -> tuple[tuple[Vec3, ...], ...]:
    """The boundary of the convex solid ``nx x + ny y + nz z <= c`` over `planes` (unit
    normals), which lies within `reach_m` of the origin: for each plane that bounds it over an
    area (once when given twice), that face's corners, counter-clockwise seen from outside.
    A plane that only touches
    the solid (along an edge, at a corner) or misses it gives nothing; empty when nothing is
    left."""
    unique: list[Face] = []
    for f in planes:  # a plane given twice (a wall of the hull and of the outline) once
        if all(max(abs(a - b) for a, b in zip(f, g, strict=True)) > _VERTEX_TOL_M for g in unique):
            unique.append(f)
    planes = unique
    out: list[tuple[Vec3, ...]] = []
    for i, (nx, ny, nz, c) in enumerate(planes):
        # (e1, e2) spanning the plane, e1 x e2 = n: a square about the origin's foot on it,
        # wider than the solid, is cut by every other plane.
        hx, hy, hz = (1.0, 0.0, 0.0) if abs(nz) > 0.9 else (0.0, 0.0, 1.0)
        e1x, e1y, e1z = hy * nz - hz * ny, hz * nx - hx * nz, hx * ny - hy * nx
        norm = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
        e1x, e1y, e1z = e1x / norm, e1y / norm, e1z / norm
        e2x, e2y, e2z = ny * e1z - nz * e1y, nz * e1x - nx * e1z, nx * e1y - ny * e1x
        ox, oy, oz = nx * c, ny * c, nz * c
        r = 2.0 * reach_m + abs(c) + 1.0
        poly: list[Vec3] = [
            (
                ox + r * (s * e1x + t * e2x),
                oy + r * (s * e1y + t * e2y),
                oz + r * (s * e1z + t * e2z),
            )
            for s, t in ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0))
        ]
        for j, plane in enumerate(planes):
            if j != i:
                poly = _clip_face(poly, plane)
                if len(poly) < 3:
                    break
        kept: list[Vec3] = []
        for p in poly:  # corners where two cuts met at one point
            if not kept or math.dist(p, kept[-1]) > _VERTEX_TOL_M:
                kept.append(p)
        if len(kept) > 1 and math.dist(kept[0], kept[-1]) <= _VERTEX_TOL_M:
            kept.pop()
        if len(kept) >= 3 and _area(kept) > _VERTEX_TOL_M:
            out.append(tuple(kept))
    return tuple(out)
