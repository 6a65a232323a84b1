"""Limits: workspace, cable-length and cable-speed checks, with human-readable reasons.

`Limits(cfg, geometry)` precomputes the anchors' plan-view convex hull as half-planes shrunk by
`xy_margin_m`, the z band [floor_z_m, lowest anchor - top_margin_m] and the cable bounds, so
every per-tick check is a few float operations in pure Python. Each check returns None when the
value is fine and otherwise a reason string that names the limit and the value, used verbatim
in a `CommandRefused` or a fault.

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
from typing import Any

import numpy as np

from controller.core.kinematics import Geometry
from controller.service.config import LimitsConfig

Vec3 = tuple[float, float, float]

TOL_M = 1e-9

_SCREEN_M = 1e-12
"""The vectorised path screen flags anything within this of a limit (a margin far above the
rounding differences between numpy and the scalar checks); the scalar check then decides."""
_VECTOR_MIN_POINTS = 16
"""Shorter paths are checked point by point (numpy's fixed cost is larger there)."""
_CHUNK_POINTS = 1024
"""Points converted to an array per numpy call: each call holds the GIL, keep it short."""


class Limits:
    """All limits of one robot (see the module docstring). Raises ValueError if the shrunk
    polygon would be empty or the z band inverted (config validation prevents both)."""

    __slots__ = (
        "_anchors",
        "_edges",
        "cfg",
        "floor_z_m",
        "max_cable_m",
        "max_cable_speed_mps",
        "min_cable_m",
        "polygon_m",
        "top_z_m",
        "xy_margin_m",
    )

    def __init__(self, cfg: LimitsConfig, geometry: Geometry) -> None:
        self.cfg = cfg
        anchors = [(float(a[0]), float(a[1]), float(a[2])) for a in geometry.anchors_m.tolist()]
        self._anchors: tuple[Vec3, ...] = tuple(anchors)
        hull = geometry.footprint_m
        self.polygon_m: tuple[tuple[float, float], ...] = tuple(hull)
        edges: list[tuple[float, float, float]] = []
        for k in range(len(hull)):
            (ax, ay), (bx, by) = hull[k], hull[(k + 1) % len(hull)]
            ln = math.hypot(bx - ax, by - ay)
            nx, ny = (by - ay) / ln, -(bx - ax) / ln  # outward normal of a CCW polygon
            # inside the shrunk polygon: nx*x + ny*y <= c
            edges.append((nx, ny, nx * ax + ny * ay - cfg.xy_margin_m))
        self._edges: tuple[tuple[float, float, float], ...] = tuple(edges)
        self.xy_margin_m = cfg.xy_margin_m
        self.floor_z_m = cfg.floor_z_m
        self.top_z_m = min(a[2] for a in anchors) - cfg.top_margin_m
        self.min_cable_m = cfg.min_cable_m
        self.max_cable_m = cfg.max_cable_m
        self.max_cable_speed_mps = cfg.max_cable_speed_mps
        if not self.floor_z_m < self.top_z_m:
            raise ValueError(
                f"floor_z_m ({self.floor_z_m:g} m) must be below the top limit ({self.top_z_m:g} m)"
            )
        cx = sum(a[0] for a in anchors) / len(anchors)
        cy = sum(a[1] for a in anchors) / len(anchors)
        if self._outside_by(cx, cy) > 0.0:
            raise ValueError(f"xy_margin_m ({cfg.xy_margin_m:g} m) leaves no workspace")

    def _outside_by(self, x: float, y: float) -> float:
        worst = -math.inf
        for nx, ny, c in self._edges:
            d = nx * x + ny * y - c
            if d > worst:
                worst = d
        return worst

    def check_point(self, p: Sequence[float]) -> str | None:
        """None if `p` (m) is in the workspace, else the reason (limit and value).

        Workspace: inside the anchors' plan-view polygon shrunk by xy_margin_m and
        floor_z_m <= z <= lowest anchor z - top_margin_m. Non-finite points are refused.
        Raises nothing.
        """
        x, y, z = p[0], p[1], p[2]
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            return f"position ({x}, {y}, {z}) is not finite"
        for nx, ny, c in self._edges:
            if nx * x + ny * y - c > TOL_M:
                out = self._outside_by(x, y)
                return (
                    f"(x, y) = ({x:.4g}, {y:.4g}) m is {out:.4g} m outside the anchors' plan-view "
                    f"polygon shrunk by xy_margin_m ({self.xy_margin_m:g} m)"
                )
        if z < self.floor_z_m - TOL_M:
            return f"z={z:.4g} m below the floor (floor_z_m {self.floor_z_m:g} m)"
        if z > self.top_z_m + TOL_M:
            return f"z={z:.4g} m above the anchor plane minus margin ({self.top_z_m:.4g} m)"
        return None

    def lengths_at(self, p: Sequence[float]) -> tuple[float, ...]:
        """Cable lengths (m) at point `p` (straight cables to the anchors). Raises nothing."""
        x, y, z = p[0], p[1], p[2]
        return tuple(
            math.sqrt((x - ax) * (x - ax) + (y - ay) * (y - ay) + (z - az) * (z - az))
            for ax, ay, az in self._anchors
        )

    def check_lengths(self, lengths_m: Sequence[float]) -> str | None:
        """None if every cable length is within [min_cable_m, max_cable_m], else the reason
        naming the cable (1-based) and its length. Non-finite lengths are refused.
        Raises nothing."""
        lo = self.min_cable_m - TOL_M
        hi = self.max_cable_m + TOL_M
        for i, length in enumerate(lengths_m):
            if not lo <= length <= hi:  # also catches NaN
                if not math.isfinite(length):
                    return f"cable {i + 1} length {length} is not finite"
                if length < lo:
                    return (
                        f"cable {i + 1} length {length:.4g} m below min_cable_m "
                        f"({self.min_cable_m:g} m)"
                    )
                return (
                    f"cable {i + 1} length {length:.4g} m above max_cable_m "
                    f"({self.max_cable_m:g} m)"
                )
        return None

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

    def check_segment(self, a: Sequence[float], b: Sequence[float]) -> str | None:
        """None if the straight segment a->b stays within every limit, else the reason.

        The workspace (convex) only needs the end points; a cable is longest at an end point
        but may be shortest inside the segment, so its minimum is checked at the point of the
        segment closest to the anchor. Raises nothing.
        """
        for p in (a, b):
            reason = self.check_point(p) or self.check_lengths(self.lengths_at(p))
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

    def check_target(self, p: Sequence[float]) -> str | None:
        """None if point `p` is in the workspace and all its cable lengths are within limits
        (the check for a move target or a streamed set-point), else the reason. Raises nothing."""
        return self.check_point(p) or self.check_lengths(self.lengths_at(p))

    def inside_points(self, points: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
        """For an (M, 3) array of points: True where `check_target` would pass (the workspace
        and every cable length, with the same tolerance), vectorised; False for a non-finite
        point. Raises ValueError if `points` is not (M, 3)."""
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must have shape (M, 3), got {pts.shape}")
        x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
        with np.errstate(invalid="ignore", over="ignore"):
            ok = np.isfinite(pts).all(axis=1)
            for nx, ny, c in self._edges:
                ok &= nx * x + ny * y - c <= TOL_M
            ok &= (z >= self.floor_z_m - TOL_M) & (z <= self.top_z_m + TOL_M)
            lo = self.min_cable_m - TOL_M
            hi = self.max_cable_m + TOL_M
            for q in self._anchors:
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
    ) -> tuple[int, str] | None:
        """The first point of `points` that breaks a limit, as (0-based index, reason), or None.

        Point i fails if it is outside the workspace or a cable length limit, or if the straight
        leg to it from point i - 1 (from `start_m` for point 0, if given) leaves them; a leg
        reason starts with "on the leg to it: ". Cost: a few numpy passes over the path, then
        the scalar checks on the screened candidates only (module docstring). `array` is
        `points_array(points)` if the caller has it already. Raises nothing.
        """
        n = len(points)
        if n < _VECTOR_MIN_POINTS:
            return self._scalar_failure(points, start_m, range(n))
        arr = points_array(points) if array is None else array
        if arr is None:  # ragged or non-numeric: the scalar checks name the point
            return self._scalar_failure(points, start_m, range(n))
        return self._scalar_failure(points, start_m, self._screen(arr, start_m))

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
            prev = points[i - 1] if i > 0 else start_m
            if prev is not None:
                reason = self.check_segment(prev, p)
                if reason is not None:
                    return i, f"on the leg to it: {reason}"
        return None

    def _screen(self, pts: np.ndarray[Any, Any], start_m: Sequence[float] | None) -> Any:
        """Indices of the points (or of the legs to them) that may break a limit: a superset
        of those the scalar checks refuse (every threshold is moved in by `_SCREEN_M`)."""
        x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            bad = ~np.isfinite(pts).all(axis=1)
            for nx, ny, c in self._edges:
                bad |= nx * x + ny * y - c > TOL_M - _SCREEN_M
            bad |= z < self.floor_z_m - TOL_M + _SCREEN_M
            bad |= z > self.top_z_m + TOL_M - _SCREEN_M
            if start_m is not None:
                a = np.empty_like(pts)
                a[0] = start_m
                a[1:] = pts[:-1]
            else:
                a = pts[:-1]
            b = pts if start_m is not None else pts[1:]
            d = b - a
            dd = np.einsum("ij,ij->i", d, d)
            lo = self.min_cable_m - TOL_M + _SCREEN_M
            hi = self.max_cable_m + TOL_M - _SCREEN_M
            leg_bad = np.zeros(len(b), dtype=bool)
            for q in self._anchors:
                rel = pts - q
                length = np.sqrt(np.einsum("ij,ij->i", rel, rel))
                bad |= ~((length >= lo) & (length <= hi))
                # Closest point of each leg to the anchor (t clipped to the leg: a superset of
                # the scalar interior test; a zero-length leg gives t = 0).
                qa = np.asarray(q) - a
                t = np.where(dd > 0.0, np.einsum("ij,ij->i", qa, d) / np.where(dd > 0, dd, 1), 0)
                t = np.clip(t, 0.0, 1.0)
                c = qa - t[:, None] * d
                leg_bad |= np.sqrt(np.einsum("ij,ij->i", c, c)) < lo
            if start_m is not None:
                bad |= leg_bad
                # The leg's own start must be within the limits too (the scalar leg check
                # includes it); one point, checked as such.
                bad[0] |= self.check_target(start_m) is not None
            else:
                bad[1:] |= leg_bad
        return np.flatnonzero(bad)


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
