"""The workspace: the one place that decides whether a point, a cable length or speed, a straight
segment or a path is allowed, with human-readable reasons.

Every user asks this module: the control step (each move, path and streamed target, and each
tick's set-point, cable lengths and cable speeds), configuration validation (the limits and
the power-up pose), the Zenoh interface's pre-check, the offline verbs (`cablebot ipk`),
`check-config`, `view`, `plot`, `calibrate --auto`, the demo and the benchmark.

The rule (`Workspace`) has two shapes, after the layout (`Geometry.hanging`):

* a robot hanging below every anchor (the paper's robot, camera rigs): in plan view, inside
  the anchors' plan-view convex hull (`Geometry.footprint_m`) with every edge moved
  `xy_margin_m` inwards (`footprint_contains` is the same test for any polygon and margin);
  in height, `floor_z_m <= z <= top_z_m`, where `top_z_m` is the lowest anchor minus
  `top_margin_m`;
* an effector among its anchors, some below it (a Hangprinter): inside the anchors' convex hull
  (`Geometry.hull_faces`) with every face moved in so that at each height the cross-section is
  the hull's shrunk by `xy_margin_m` (`workspace_shape.shrunk_faces`), `floor_z_m <= z`, and
  `z <= top_z_m`, the highest anchor minus `top_margin_m`;
* either: optionally `z <= ceiling_z_m`, and within `print_radius_m` of the origin in plan
  view (RepRapFirmware's M669 P); which shape a robot file gets is `effector_hangs`'s rule;
* cables: every length in `[min_cable_m, max_cable_m]`; no length changing faster than
  `max_cable_speed_mps` between two set-points;
* a straight segment: both ends allowed, and no cable shorter than `min_cable_m` on the way
  (the workspace is convex, and a cable is longest at an end);
* a path: every point, and every leg from the point before (and from a start, if given).

Each check returns None when the value is allowed and otherwise a reason string that names the
limit and the value, used verbatim in a `CommandRefused` or a fault. The tension rule
(`controller.core.statics.TensionCheck`: every cable within its limits while holding the
payload) is applied beside this one by its users; together they are the workspace. The point
and length checks also come as a `Violation` (which limit, which cable, the value and the bound) for
callers that word their own message, such as configuration validation naming the TOML keys.

`Workspace(geometry, xy_margin_m=..., ...)` takes plain floats; `Workspace.from_limits(limits,
geometry)` takes any object with those attributes (the service's `LimitsConfig`). Both raise
`WorkspaceError` (naming the limit) for non-finite values, a z band that is empty, a cable
range that is empty, or a margin that leaves no plan-view area. The half-planes, the shrunk
polygon (`polygon_m`) and the z band are computed once, so every per-tick check is a few float
operations in pure Python.

A tolerance of `TOL_M` (1 nm) absorbs floating-point rounding of set-points that lie exactly on
a boundary (a move to a point on the margin must not fault half-way).

Paths: `path_failure` / `check_path` check every point and every leg of a path of any length
in a few numpy passes (a 10,000-point path in about a millisecond): the arrays only screen for
candidates (anything within `_SCREEN_M` of a limit), and the scalar checks above decide each
candidate in order, so a path gets exactly the verdict and reason of checking it point by point.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from controller.core.kinematics import Geometry, KinematicsError
from controller.core.kinematics.geometry import _convex_hull
from controller.core.workspace_shape import (
    Face,
    disk_polygon,
    face_polygons,
    shrunk_faces,
    solid_vertices,
    wall_planes,
)

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]
HalfPlane = tuple[float, float, float]
"""(nx, ny, c) with (nx, ny) the unit outward normal of an edge: inside is nx*x + ny*y <= c."""

TOL_M = 1e-9

_SCREEN_M = 1e-12
"""The vectorised path screen flags anything within this of a limit (a margin far above the
rounding differences between numpy and the scalar checks); the scalar check then decides."""
_VECTOR_MIN_POINTS = 16
"""Shorter paths are checked point by point (numpy's fixed cost is larger there)."""
_CHUNK_POINTS = 1024
"""Points converted to an array per numpy call: each call holds the GIL, keep it short."""


class WorkspaceError(ValueError):
    """Limits that allow nothing (or are not finite). `limit` names the limit's key (e.g.
    ``xy_margin_m``), `detail` says what is wrong with it; the message is ``limit: detail``."""

    def __init__(self, limit: str, detail: str) -> None:
        super().__init__(f"{limit}: {detail}")
        self.limit = limit
        self.detail = detail


class LimitsLike(Protocol):
    """The limits a `Workspace` is built from (the service's `LimitsConfig` is one)."""

    @property
    def xy_margin_m(self) -> float:
        """Plan-view margin inside the anchors' convex hull (m)."""
        ...

    @property
    def floor_z_m(self) -> float:
        """Lowest allowed z (m)."""
        ...

    @property
    def top_margin_m(self) -> float:
        """Distance kept below the lowest anchor (m)."""
        ...

    @property
    def min_cable_m(self) -> float:
        """Shortest allowed cable (m)."""
        ...

    @property
    def max_cable_m(self) -> float:
        """Longest allowed cable (m)."""
        ...

    @property
    def max_cable_speed_mps(self) -> float:
        """Fastest allowed change of a cable length (m/s)."""
        ...


def effector_hangs(
    anchors_m: Sequence[Sequence[float]], floor_z_m: float, top_margin_m: float
) -> bool:
    """True when the workspace hangs below every anchor: the floor is below the lowest anchor
    minus `top_margin_m`, or the anchors lie in one plane (no hull to work in among them).
    Otherwise some anchors are at or below the workspace (a Hangprinter's low anchors) and
    the effector works among them.  Raises nothing."""
    if floor_z_m < min(float(a[2]) for a in anchors_m) - top_margin_m:
        return True
    try:
        Geometry(anchors_m, hanging=False)
    except KinematicsError:
        return True
    return False


def layout_geometry(anchors_m: Sequence[Sequence[float]], limits: LimitsLike) -> Geometry:
    """The `Geometry` of `anchors_m` for these limits, hanging or among the anchors as
    `effector_hangs` says.  Raises KinematicsError for unusable anchors."""
    hangs = effector_hangs(anchors_m, float(limits.floor_z_m), float(limits.top_margin_m))
    return Geometry(anchors_m, hanging=hangs)


def _why_hanging(geometry: Geometry) -> str:
    """Why a robot whose floor is not below its lowest anchor hangs all the same (its anchors
    cannot surround an effector: `effector_hangs`), as a parenthesis for the floor's message;
    empty when that is not why."""
    if not geometry.hanging:
        return ""
    try:
        Geometry(geometry.anchors_m, hanging=False)
    except KinematicsError as exc:
        return f" (the effector cannot work among these anchors: {exc})"
    return ""


@dataclass(frozen=True, slots=True)
class Violation:
    """One broken limit of a point or of its cable lengths.

    `limit`: the limit's key: ``position`` (not finite), ``xy_margin_m`` (outside the shrunk
    plan-view polygon), ``floor_z_m``, ``top_margin_m`` (above the top), ``min_cable_m`` or
    ``max_cable_m`` (a cable length, or ``cable_m`` for a non-finite one). `cable`: the
    cable's number (1-based) for a cable limit, else None. `value`: the offending value (how
    far outside the polygon, the z or the length, in m). `bound`: the limit it breaks (the
    margin, the floor, the top z, the shortest or longest cable, in m). `reason`: the message
    the checks return.
    """

    limit: str
    cable: int | None
    value: float
    bound: float
    reason: str


def _half_planes(polygon_m: Sequence[Sequence[float]], margin_m: float) -> tuple[HalfPlane, ...]:
    """The convex counter-clockwise `polygon_m` with every edge moved `margin_m` inwards."""
    planes: list[HalfPlane] = []
    n = len(polygon_m)
    for k in range(n):
        ax, ay = float(polygon_m[k][0]), float(polygon_m[k][1])
        bx, by = float(polygon_m[(k + 1) % n][0]), float(polygon_m[(k + 1) % n][1])
        ln = math.hypot(bx - ax, by - ay)
        if ln == 0.0:
            continue
        nx, ny = (by - ay) / ln, -(bx - ax) / ln  # outward normal of a CCW polygon
        planes.append((nx, ny, nx * ax + ny * ay - margin_m))
    return tuple(planes)


def _outside_by(planes: Sequence[HalfPlane], x: float, y: float) -> float:
    """How far (x, y) lies outside the half-planes (<= 0 inside); NaN for a NaN coordinate."""
    worst = -math.inf
    for nx, ny, c in planes:
        d = nx * x + ny * y - c
        if not d <= worst:  # also takes a NaN, which then stays
            worst = d
    return worst


def _inside(outside_by_m: float) -> bool:
    """The plan-view rule: inside (up to `TOL_M`) of every shrunk edge; NaN is outside."""
    return outside_by_m <= TOL_M


def _clip(polygon_m: Sequence[Vec2], planes: Sequence[HalfPlane]) -> tuple[Vec2, ...]:
    """The vertices of `polygon_m` intersected with `planes`, counter-clockwise (empty when
    nothing is left): Sutherland-Hodgman, one half-plane at a time."""
    out = [(float(x), float(y)) for x, y in polygon_m]
    for nx, ny, c in planes:
        kept: list[Vec2] = []
        for i, p in enumerate(out):
            q = out[(i + 1) % len(out)]
            dp = nx * p[0] + ny * p[1] - c
            dq = nx * q[0] + ny * q[1] - c
            if dp <= 0.0:
                kept.append(p)
            if (dp < 0.0 < dq) or (dq < 0.0 < dp):
                t = dp / (dp - dq)
                x, y = p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])
                # On an axis-parallel edge the coordinate is exact (a rectangle stays exact).
                if ny == 0.0:
                    x = c / nx
                elif nx == 0.0:
                    y = c / ny
                kept.append((x, y))
        out = kept
        if not out:
            break
    return tuple(out)


def _convex_outline(points: Sequence[Vec2]) -> tuple[Vec2, ...]:
    """The counter-clockwise convex hull of plan-view points (collinear ones dropped)."""
    return tuple(_convex_hull([(float(x), float(y)) for x, y in points]))


def _outside_faces(faces: Sequence[Face], x: float, y: float, z: float) -> tuple[float, int]:
    """How far (x, y, z) lies outside the faces (<= 0 inside) and which face (NaN: NaN)."""
    worst = -math.inf
    k = -1
    for i, (nx, ny, nz, c) in enumerate(faces):
        d = nx * x + ny * y + nz * z - c
        if not d <= worst:
            worst = d
            k = i
    return worst, k


def footprint_contains(
    polygon_m: Sequence[Sequence[float]], x_m: float, y_m: float, margin_m: float = 0.0
) -> bool:
    """True when (x, y) lies in the convex counter-clockwise `polygon_m` (e.g.
    `Geometry.footprint_m`) shrunk by `margin_m`, with the workspace's rule and tolerance.

    A point exactly `margin_m` from an edge is inside. Non-finite input gives False.
    Raises nothing.
    """
    return _inside(_outside_by(_half_planes(polygon_m, margin_m), x_m, y_m))


def shrink_polygon(polygon_m: Sequence[Sequence[float]], margin_m: float) -> tuple[Vec2, ...]:
    """The vertices of the convex counter-clockwise `polygon_m` with every edge moved
    `margin_m` inwards (counter-clockwise; empty when nothing is left). Raises nothing."""
    pts = [(float(p[0]), float(p[1])) for p in polygon_m]
    return _clip(pts, _half_planes(pts, margin_m))


class Workspace:
    """Every limit of one robot (see the module docstring).

    Raises WorkspaceError (naming the limit) for a non-finite limit, `floor_z_m` not below the
    top, `min_cable_m` not below `max_cable_m`, a ceiling not above the floor, a print radius
    not > 0, or margins and bounds that leave no workspace (a hanging robot: even the anchors'
    centroid outside the shrunk polygon).
    """

    __slots__ = (
        "_anchor_top_z_m",
        "_anchors",
        "_faces",
        "_names",
        "_planes",
        "_radius2",
        "ceiling_z_m",
        "floor_z_m",
        "footprint_m",
        "hanging",
        "max_cable_m",
        "max_cable_speed_mps",
        "min_cable_m",
        "polygon_m",
        "print_radius_m",
        "top_margin_m",
        "top_z_m",
        "xy_margin_m",
    )

    footprint_m: tuple[Vec2, ...]
    """The anchors' plan-view convex hull, counter-clockwise."""
    polygon_m: tuple[Vec2, ...]
    """The workspace's plan view, counter-clockwise: `footprint_m` shrunk by `xy_margin_m`
    (hanging), or the outline of the solid among the anchors seen from above; within a
    polygon inscribed in the print radius when there is one."""
    top_z_m: float
    """The highest allowed z: the lowest (hanging) or highest (among the anchors) anchor minus
    `top_margin_m`, or `ceiling_z_m` when that is lower."""

    def __init__(
        self,
        geometry: Geometry,
        *,
        xy_margin_m: float,
        floor_z_m: float,
        top_margin_m: float,
        min_cable_m: float,
        max_cable_m: float,
        max_cable_speed_mps: float,
        ceiling_z_m: float | None = None,
        print_radius_m: float | None = None,
    ) -> None:
        values = {
            "xy_margin_m": xy_margin_m,
            "floor_z_m": floor_z_m,
            "top_margin_m": top_margin_m,
            "min_cable_m": min_cable_m,
            "max_cable_m": max_cable_m,
            "max_cable_speed_mps": max_cable_speed_mps,
        }
        if ceiling_z_m is not None:
            values["ceiling_z_m"] = ceiling_z_m
        if print_radius_m is not None:
            values["print_radius_m"] = print_radius_m
        for name, value in values.items():
            if not math.isfinite(value):
                raise WorkspaceError(name, f"must be a finite number, got {value!r}")
        anchors = [(float(a[0]), float(a[1]), float(a[2])) for a in geometry.anchors_m.tolist()]
        self._anchors: tuple[Vec3, ...] = tuple(anchors)
        self.hanging = bool(geometry.hanging)
        self.footprint_m = tuple((float(x), float(y)) for x, y in geometry.footprint_m)
        self.xy_margin_m = float(xy_margin_m)
        self.floor_z_m = float(floor_z_m)
        self.top_margin_m = float(top_margin_m)
        heights = [a[2] for a in anchors]
        self._anchor_top_z_m = (min(heights) if self.hanging else max(heights)) - self.top_margin_m
        self.ceiling_z_m = None if ceiling_z_m is None else float(ceiling_z_m)
        self.top_z_m = min(self._anchor_top_z_m, math.inf if ceiling_z_m is None else ceiling_z_m)
        self.print_radius_m = None if print_radius_m is None else float(print_radius_m)
        self._radius2 = math.inf if print_radius_m is None else float(print_radius_m) ** 2
        self.min_cable_m = float(min_cable_m)
        self.max_cable_m = float(max_cable_m)
        self.max_cable_speed_mps = float(max_cable_speed_mps)
        if not self.floor_z_m < self._anchor_top_z_m:
            which = "lowest" if self.hanging else "highest"
            raise WorkspaceError(
                "floor_z_m",
                f"{self.floor_z_m:g} m must be below the {which} anchor minus top_margin_m "
                f"({self._anchor_top_z_m:g} m){_why_hanging(geometry)}",
            )
        if self.ceiling_z_m is not None and not self.floor_z_m < self.ceiling_z_m:
            raise WorkspaceError(
                "ceiling_z_m",
                f"{self.ceiling_z_m:g} m must be above floor_z_m ({self.floor_z_m:g} m)",
            )
        if self.print_radius_m is not None and not self.print_radius_m > 0.0:
            raise WorkspaceError("print_radius_m", f"must be > 0 m, got {self.print_radius_m:g}")
        if not self.min_cable_m < self.max_cable_m:
            raise WorkspaceError(
                "min_cable_m",
                f"{self.min_cable_m:g} m must be < max_cable_m ({self.max_cable_m:g} m)",
            )
        self._faces: tuple[Face, ...] = ()
        self._names: tuple[str, ...] = ()
        if self.hanging:
            self._planes = _half_planes(self.footprint_m, self.xy_margin_m)
            cx = sum(a[0] for a in anchors) / len(anchors)
            cy = sum(a[1] for a in anchors) / len(anchors)
            if _outside_by(self._planes, cx, cy) > 0.0:
                raise WorkspaceError(
                    "xy_margin_m",
                    f"{self.xy_margin_m:g} m leaves no workspace (even the anchors' centroid is "
                    "outside the shrunk plan-view polygon)",
                )
            self.polygon_m = _clip(self.footprint_m, self._planes)
        else:
            self._among(geometry)
        if self.print_radius_m is not None:
            disk = disk_polygon(self.print_radius_m)
            clipped = _clip(self.polygon_m, _half_planes(disk, 0.0))
            if len(clipped) < 3:
                raise WorkspaceError(
                    "print_radius_m",
                    f"{self.print_radius_m:g} m about the origin leaves no workspace (the "
                    "workspace's plan view does not reach that circle)",
                )
            self.polygon_m = clipped

    def _among(self, geometry: Geometry) -> None:
        """The solid among the anchors: shrunk faces, and its outline from above; raises
        WorkspaceError when the margins and bounds leave nothing."""
        self._faces = shrunk_faces(geometry.hull_faces, self.xy_margin_m)
        self._names = tuple(
            "cables " + ", ".join(str(k + 1) for k in f[4]) for f in geometry.hull_faces
        )
        corners = solid_vertices(self._faces, self.floor_z_m, self.top_z_m)
        outline = _convex_outline([(c[0], c[1]) for c in corners])
        if len(outline) < 3:
            raise WorkspaceError(
                "xy_margin_m",
                f"{self.xy_margin_m:g} m leaves no workspace inside the anchors' hull between "
                f"floor_z_m ({self.floor_z_m:g} m) and {self.top_z_m:g} m",
            )
        self.polygon_m = outline
        self._planes = _half_planes(outline, 0.0)

    @classmethod
    def from_limits(cls, limits: LimitsLike, geometry: Geometry) -> Workspace:
        """The workspace of `limits` (any object with the `LimitsLike` attributes, such as the
        service's `LimitsConfig`, and optionally `ceiling_z_m` and `print_radius_m`) for
        `geometry`. Raises WorkspaceError as the constructor."""
        ceiling = getattr(limits, "ceiling_z_m", None)
        radius = getattr(limits, "print_radius_m", None)
        return cls(
            geometry,
            xy_margin_m=float(limits.xy_margin_m),
            floor_z_m=float(limits.floor_z_m),
            top_margin_m=float(limits.top_margin_m),
            min_cable_m=float(limits.min_cable_m),
            max_cable_m=float(limits.max_cable_m),
            max_cable_speed_mps=float(limits.max_cable_speed_mps),
            ceiling_z_m=None if ceiling is None else float(ceiling),
            print_radius_m=None if radius is None else float(radius),
        )

    # ------------------------------------------------------------------ shape

    def box(self) -> tuple[tuple[float, float], tuple[float, float], tuple[float, float]]:
        """The workspace's bounding box ((x_lo, x_hi), (y_lo, y_hi), (z_lo, z_hi)) in m: the
        x/y extent of `polygon_m` and the z band. For a rectangular anchor layout the box is
        the workspace itself. Raises nothing."""
        xs = [p[0] for p in self.polygon_m]
        ys = [p[1] for p in self.polygon_m]
        return (min(xs), max(xs)), (min(ys), max(ys)), (self.floor_z_m, self.top_z_m)

    def boundary_m(self) -> tuple[tuple[Vec3, ...], ...]:
        """The workspace's solid as the polygons of its faces (m; each counter-clockwise seen
        from outside), for drawing: hanging, the prism of `polygon_m` between `floor_z_m` and
        `top_z_m`; among the anchors, the hull with its faces moved in, cut by the floor, the
        top and the print radius (as `polygon_m`, its inscribed polygon). Raises nothing."""
        poly = self.polygon_m
        planes = [*wall_planes(poly), *self._faces]
        planes += [(0.0, 0.0, -1.0, -self.floor_z_m), (0.0, 0.0, 1.0, self.top_z_m)]
        reach = max(math.hypot(x, y) for x, y in poly) + abs(self.floor_z_m) + abs(self.top_z_m)
        return face_polygons(planes, reach)

    def contains_xy(self, x_m: float, y_m: float) -> bool:
        """True when (x, y) is inside the workspace's plan view (`polygon_m`'s rule without
        the polygon: the shrunk footprint and the print radius; among the anchors the solid's
        outline from above) (NaN: False). Raises nothing."""
        return _inside(_outside_by(self._planes, x_m, y_m)) and (
            x_m * x_m + y_m * y_m <= self._radius2
        )

    # ------------------------------------------------------------------ points and lengths

    def point_violation(self, p: Sequence[float]) -> Violation | None:
        """The workspace limit point `p` (m) breaks, or None if it is in the workspace.

        Non-finite points break ``position``. Raises nothing.
        """
        x, y, z = p[0], p[1], p[2]
        faces = self._faces
        face = -1
        if faces:
            out, face = _outside_faces(faces, x, y, z)
        else:
            out = _outside_by(self._planes, x, y)
        # The per-tick path: one comparison chain (a NaN or an infinity fails it).
        if (
            _inside(out)
            and self.floor_z_m - TOL_M <= z <= self.top_z_m + TOL_M
            and x * x + y * y <= self._radius2
        ):
            return None
        return _violation(self, x, y, z, out, face)

    def check_point(self, p: Sequence[float]) -> str | None:
        """None if `p` (m) is in the workspace, else the reason (limit and value).

        Workspace: see the module docstring (hanging: inside the anchors' plan-view polygon
        shrunk by xy_margin_m and floor_z_m <= z <= lowest anchor z - top_margin_m). Non-finite
        points are refused. Raises nothing.
        """
        v = self.point_violation(p)
        return None if v is None else v.reason

    def lengths_at(self, p: Sequence[float]) -> tuple[float, ...]:
        """Cable lengths (m) at point `p` (straight cables to the anchors). Raises nothing."""
        x, y, z = p[0], p[1], p[2]
        return tuple(
            math.sqrt((x - ax) * (x - ax) + (y - ay) * (y - ay) + (z - az) * (z - az))
            for ax, ay, az in self._anchors
        )

    def lengths_violation(self, lengths_m: Sequence[float]) -> Violation | None:
        """The first cable whose length is outside [min_cable_m, max_cable_m] (or not
        finite), or None. Raises nothing."""
        lo = self.min_cable_m - TOL_M
        hi = self.max_cable_m + TOL_M
        for i, length in enumerate(lengths_m):
            if not lo <= length <= hi:  # also catches NaN
                if not math.isfinite(length):
                    return Violation(
                        "cable_m",
                        i + 1,
                        length,
                        math.nan,
                        f"cable {i + 1} length {length} is not finite",
                    )
                if length < lo:
                    return Violation(
                        "min_cable_m",
                        i + 1,
                        length,
                        self.min_cable_m,
                        f"cable {i + 1} length {length:.4g} m below min_cable_m "
                        f"({self.min_cable_m:g} m)",
                    )
                return Violation(
                    "max_cable_m",
                    i + 1,
                    length,
                    self.max_cable_m,
                    f"cable {i + 1} length {length:.4g} m above max_cable_m "
                    f"({self.max_cable_m:g} m)",
                )
        return None

    def check_lengths(self, lengths_m: Sequence[float]) -> str | None:
        """None if every cable length is within [min_cable_m, max_cable_m], else the reason
        naming the cable (1-based) and its length. Non-finite lengths are refused.
        Raises nothing."""
        v = self.lengths_violation(lengths_m)
        return None if v is None else v.reason

    def target_violation(self, p: Sequence[float]) -> Violation | None:
        """The limit point `p` breaks (workspace first, then its cable lengths), or None.
        Raises nothing."""
        return self.point_violation(p) or self.lengths_violation(self.lengths_at(p))

    def check_target(self, p: Sequence[float]) -> str | None:
        """None if point `p` is in the workspace and all its cable lengths are within limits
        (the check for a move target, a streamed set-point or a home pose), else the reason.
        Raises nothing."""
        return self.check_point(p) or self.check_lengths(self.lengths_at(p))

    def check_cable_speeds(
        self, prev_lengths_m: Sequence[float], lengths_m: Sequence[float], dt_s: float
    ) -> str | None:
        """None if no cable length changed faster than max_cable_speed_mps over `dt_s`, else the
        reason naming the cable (1-based) and its speed. `dt_s` <= 0 or non-finite: nothing
        can be measured, returns None. Raises nothing."""
        if not (dt_s > 0.0 and math.isfinite(dt_s)):
            return None
        max_step = self.max_cable_speed_mps * dt_s + TOL_M
        for i, (a, b) in enumerate(zip(prev_lengths_m, lengths_m, strict=False)):
            step = abs(b - a)
            if not step <= max_step:
                if not math.isfinite(step):
                    return f"cable {i + 1} speed is not finite"
                return (
                    f"cable {i + 1} speed {step / dt_s:.4g} m/s above max_cable_speed_mps "
                    f"({self.max_cable_speed_mps:g} m/s)"
                )
        return None

    # ------------------------------------------------------------------ segments and paths

    def check_segment(self, a: Sequence[float], b: Sequence[float]) -> str | None:
        """None if the straight segment a->b stays within every limit, else the reason.

        The workspace (convex) only needs the end points; a cable is longest at an end point
        but may be shortest inside the segment, so its minimum is checked at the point of the
        segment closest to the anchor. Raises nothing.
        """
        for p in (a, b):
            reason = self.check_target(p)
            if reason:
                return reason
        ax, ay, az = a[0], a[1], a[2]
        dx, dy, dz = b[0] - ax, b[1] - ay, b[2] - az
        dd = dx * dx + dy * dy + dz * dz
        if dd == 0.0:
            return None
        for i, (qx, qy, qz) in enumerate(self._anchors):
            t = ((qx - ax) * dx + (qy - ay) * dy + (qz - az) * dz) / dd
            if 0.0 < t < 1.0:
                px, py, pz = ax + t * dx, ay + t * dy, az + t * dz
                d = math.sqrt((px - qx) ** 2 + (py - qy) ** 2 + (pz - qz) ** 2)
                if d < self.min_cable_m - TOL_M:
                    return (
                        f"cable {i + 1} would shorten to {d:.4g} m on the way, below "
                        f"min_cable_m ({self.min_cable_m:g} m)"
                    )
        return None

    def inside_points(
        self, points: np.ndarray[Any, Any], lengths: bool = True
    ) -> np.ndarray[Any, Any]:
        """For an (M, 3) array of points: True where `check_target` would pass (the workspace
        and, unless `lengths` is False, every cable length, with the same tolerance),
        vectorised; False for a non-finite point. Raises ValueError if `points` is not
        (M, 3)."""
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must have shape (M, 3), got {pts.shape}")
        x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
        with np.errstate(invalid="ignore", over="ignore"):
            ok = np.isfinite(pts).all(axis=1)
            if self._faces:
                for fx, fy, fz, fc in self._faces:
                    ok &= fx * x + fy * y + fz * z - fc <= TOL_M
            else:
                for nx, ny, c in self._planes:
                    ok &= nx * x + ny * y - c <= TOL_M
            ok &= x * x + y * y <= self._radius2
            ok &= (z >= self.floor_z_m - TOL_M) & (z <= self.top_z_m + TOL_M)
            lo = self.min_cable_m - TOL_M
            hi = self.max_cable_m + TOL_M
            for q in self._anchors if lengths else ():
                rel = pts - q
                length = np.sqrt(np.einsum("ij,ij->i", rel, rel))
                ok &= (length >= lo) & (length <= hi)
        return ok

    def path_failure(
        self,
        points: Sequence[Sequence[float]],
        start_m: Sequence[float] | None = None,
        *,
        array: np.ndarray[Any, Any] | None = None,
        legs: bool = True,
    ) -> tuple[int, str] | None:
        """The first point of `points` that breaks a limit, as (0-based index, reason), or None.

        Point i fails if it is outside the workspace or a cable length limit, or (with `legs`)
        if the straight leg to it from point i - 1 (from `start_m` for point 0, if given)
        leaves them; a leg reason starts with "on the leg to it: ". Cost: a few numpy passes
        over the path, then the scalar checks on the screened candidates only (module
        docstring). `array` is `points_array(points)` if the caller has it already. Raises
        nothing.
        """
        if not legs:
            start_m = None
        n = len(points)
        if n < _VECTOR_MIN_POINTS:
            return self._scalar_failure(points, start_m, range(n), legs)
        arr = points_array(points) if array is None else array
        if arr is None:  # ragged or non-numeric: the scalar checks name the point
            return self._scalar_failure(points, start_m, range(n), legs)
        return self._scalar_failure(points, start_m, self._screen(arr, start_m, legs), legs)

    def check_path(
        self, points: Sequence[Sequence[float]], start_m: Sequence[float] | None = None
    ) -> str | None:
        """None if every point and every straight leg between them is within the limits.

        With `start_m`, the leg from the current position to the first point is checked too.
        The reason names the point (1-based, "path point 3: ..."). An empty path is refused.
        Raises nothing.
        """
        if len(points) == 0:
            return "path has no points"
        failure = self.path_failure(points, start_m)
        if failure is None:
            return None
        return f"path point {failure[0] + 1}: {failure[1]}"

    def _scalar_failure(
        self,
        points: Sequence[Sequence[float]],
        start_m: Sequence[float] | None,
        indices: Any,
        legs: bool,
    ) -> tuple[int, str] | None:
        """The scalar verdict on points `indices` (ascending), first failure first."""
        for i in indices:
            i = int(i)
            p = points[i]
            if len(p) != 3:
                return i, f"needs 3 coordinates, got {len(p)}"
            reason = self.check_target(p)
            if reason is not None:
                return i, reason
            if not legs:
                continue
            prev = points[i - 1] if i > 0 else start_m
            if prev is not None:
                reason = self.check_segment(prev, p)
                if reason is not None:
                    return i, f"on the leg to it: {reason}"
        return None

    def _screen(
        self, pts: np.ndarray[Any, Any], start_m: Sequence[float] | None, legs: bool
    ) -> Any:
        """Indices of the points (or of the legs to them) that may break a limit: a superset
        of those the scalar checks refuse (every threshold is moved in by `_SCREEN_M`)."""
        x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            bad = ~np.isfinite(pts).all(axis=1)
            if self._faces:
                for fx, fy, fz, fc in self._faces:
                    bad |= fx * x + fy * y + fz * z - fc > TOL_M - _SCREEN_M
            else:
                for nx, ny, c in self._planes:
                    bad |= nx * x + ny * y - c > TOL_M - _SCREEN_M
            if self.print_radius_m is not None:
                bad |= x * x + y * y > (self.print_radius_m - _SCREEN_M) ** 2
            bad |= z < self.floor_z_m - TOL_M + _SCREEN_M
            bad |= z > self.top_z_m + TOL_M - _SCREEN_M
            lo = self.min_cable_m - TOL_M + _SCREEN_M
            hi = self.max_cable_m + TOL_M - _SCREEN_M
            for q in self._anchors:
                rel = pts - q
                length = np.sqrt(np.einsum("ij,ij->i", rel, rel))
                bad |= ~((length >= lo) & (length <= hi))
            if legs:
                bad |= self._screen_legs(pts, start_m, lo)
        return np.flatnonzero(bad)

    def _screen_legs(
        self, pts: np.ndarray[Any, Any], start_m: Sequence[float] | None, lo: float
    ) -> np.ndarray[Any, Any]:
        """Per point: may the leg to it (from the point before, or from `start_m`) pass
        closer than `lo` to an anchor? (A superset of the scalar interior test.)"""
        if start_m is not None:
            a = np.empty_like(pts)
            a[0] = start_m
            a[1:] = pts[:-1]
        else:
            a = pts[:-1]
        b = pts if start_m is not None else pts[1:]
        d = b - a
        dd = np.einsum("ij,ij->i", d, d)
        leg_bad = np.zeros(len(b), dtype=bool)
        for q in self._anchors:
            # Closest point of each leg to the anchor (t clipped to the leg; a zero-length
            # leg gives t = 0).
            qa = np.asarray(q) - a
            t = np.where(dd > 0.0, np.einsum("ij,ij->i", qa, d) / np.where(dd > 0, dd, 1), 0)
            t = np.clip(t, 0.0, 1.0)
            c = qa - t[:, None] * d
            leg_bad |= np.sqrt(np.einsum("ij,ij->i", c, c)) < lo
        out = np.zeros(len(pts), dtype=bool)
        if start_m is not None:
            out |= leg_bad
            # The leg's own start must be within the limits too (the scalar leg check
            # includes it); one point, checked as such.
            out[0] |= self.check_target(start_m) is not None
        else:
            out[1:] |= leg_bad
        return out


def _violation(ws: Workspace, x: float, y: float, z: float, out: float, face: int) -> Violation:
    """The limit a point outside the workspace breaks, with its reason (``point_violation``'s
    slow path: `out` is how far outside the plan-view polygon or the faces it is, `face` the
    face (-1: hanging))."""
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        return Violation(
            "position", None, math.nan, math.nan, f"position ({x}, {y}, {z}) is not finite"
        )
    if not _inside(out):
        if face >= 0:
            return Violation(
                "xy_margin_m",
                None,
                out,
                ws.xy_margin_m,
                f"({x:.4g}, {y:.4g}, {z:.4g}) m is {out:.4g} m outside the anchors' hull "
                f"(the face of {ws._names[face]}) shrunk by xy_margin_m "
                f"({ws.xy_margin_m:g} m)",
            )
        return Violation(
            "xy_margin_m",
            None,
            out,
            ws.xy_margin_m,
            f"(x, y) = ({x:.4g}, {y:.4g}) m is {out:.4g} m outside the anchors' plan-view "
            f"polygon shrunk by xy_margin_m ({ws.xy_margin_m:g} m)",
        )
    r2 = x * x + y * y
    if not r2 <= ws._radius2:
        r = math.sqrt(r2)
        return Violation(
            "print_radius_m",
            None,
            r,
            float(ws.print_radius_m or 0.0),
            f"(x, y) = ({x:.4g}, {y:.4g}) m is {r:.4g} m from the origin, beyond "
            f"print_radius_m ({ws.print_radius_m:g} m)",
        )
    if z < ws.floor_z_m - TOL_M:
        return Violation(
            "floor_z_m",
            None,
            z,
            ws.floor_z_m,
            f"z={z:.4g} m below the floor (floor_z_m {ws.floor_z_m:g} m)",
        )
    if ws.ceiling_z_m is not None and ws.ceiling_z_m < ws._anchor_top_z_m:
        return Violation(
            "ceiling_z_m",
            None,
            z,
            ws.ceiling_z_m,
            f"z={z:.4g} m above the ceiling (ceiling_z_m {ws.ceiling_z_m:g} m)",
        )
    if not ws.hanging:
        return Violation(
            "top_margin_m",
            None,
            z,
            ws.top_z_m,
            f"z={z:.4g} m above the highest anchor minus top_margin_m ({ws.top_z_m:.4g} m)",
        )
    return Violation(
        "top_margin_m",
        None,
        z,
        ws.top_z_m,
        f"z={z:.4g} m above the anchor plane minus margin ({ws.top_z_m:.4g} m)",
    )


def points_array(points: Sequence[Sequence[float]]) -> np.ndarray[Any, Any] | None:
    """`points` as an (n, 3) float array, or None if ragged or not numeric. Raises nothing.

    Converted in chunks: each numpy call holds the GIL, and the control loop's thread must not
    wait long for it while a large path is converted in another thread.
    """
    n = len(points)
    out = np.empty((n, 3), dtype=np.float64)
    try:
        for i in range(0, n, _CHUNK_POINTS):
            out[i : i + _CHUNK_POINTS] = points[i : i + _CHUNK_POINTS]
    except (ValueError, TypeError):
        return None
    return out
