"""The robot's drawable shape: anchors, footprint and workspace, from a configuration summary.

The tools that draw the robot (`cablebot view`, `cablebot plot`) get its geometry from the
configuration summary the daemon reports in its status (`status["config"]`, the dict of
`RobotConfig.summary()`), from the one stored in a recording, or from a TOML file
(`load_config(path).summary()`): the same dict in all three cases. `RobotShape.from_summary`
turns it into points to draw; the footprint and the workspace come from
`controller.core.workspace.Workspace`, so the drawn workspace is the one the daemon enforces.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

Vec3 = tuple[float, float, float]
Vec2 = tuple[float, float]


class ShapeError(ValueError):
    """The configuration summary does not describe a usable robot (missing or bad anchors)."""


@dataclass(frozen=True, slots=True)
class RobotShape:
    """What a view draws of the robot: anchors, the footprint and the workspace (metres).

    `footprint_m` is the anchors' plan-view convex hull (counter-clockwise) on the floor;
    `workspace_m` the workspace seen from above (hanging: the footprint shrunk by
    `limits.xy_margin_m`), between `floor_z_m` and `top_z_m`; `workspace_faces_m` the
    workspace's solid as the polygons of its faces (`Workspace.boundary_m`: a prism for a
    hanging robot, the shrunk hull cut by floor, top and print radius among the anchors).
    `min_cable_m` / `max_cable_m` bound the cable lengths (used for colours).
    """

    name: str
    anchors_m: tuple[Vec3, ...]
    footprint_m: tuple[Vec2, ...]
    workspace_m: tuple[Vec2, ...]
    workspace_faces_m: tuple[tuple[Vec3, ...], ...]
    floor_z_m: float
    top_z_m: float
    min_cable_m: float
    max_cable_m: float

    @property
    def size_m(self) -> float:
        """A length scale of the robot: the footprint's diagonal (for marker sizes)."""
        xs = [a[0] for a in self.anchors_m]
        ys = [a[1] for a in self.anchors_m]
        zs = [a[2] for a in self.anchors_m]
        return math.hypot(max(xs) - min(xs), max(ys) - min(ys), max(zs) - min(zs))

    @property
    def workspace_edges_m(self) -> list[tuple[Vec3, Vec3]]:
        """The edges of the workspace's faces, each once (two faces share every edge)."""
        seen: set[tuple[Vec3, Vec3]] = set()
        out: list[tuple[Vec3, Vec3]] = []
        for face in self.workspace_faces_m:
            for k, p in enumerate(face):
                q = face[(k + 1) % len(face)]
                a = (round(p[0], 9), round(p[1], 9), round(p[2], 9))
                b = (round(q[0], 9), round(q[1], 9), round(q[2], 9))
                key = (a, b) if a <= b else (b, a)
                if key not in seen:
                    seen.add(key)
                    out.append((p, q))
        return out

    @staticmethod
    def from_summary(summary: Mapping[str, Any]) -> RobotShape:
        """The shape of the robot described by a `RobotConfig.summary()` dict.

        Raises ShapeError when the anchors or limits are missing, not finite, or make no
        workspace.
        """
        from controller.core.kinematics import KinematicsError
        from controller.core.workspace import Workspace, layout_geometry
        from controller.service.config import LimitsConfig

        try:
            anchors = tuple(
                (float(a[0]), float(a[1]), float(a[2]))
                for a in (r["anchor_m"] for r in summary["reels"])
            )
            given: dict[str, Any] = {
                k: int(v) if k == "max_queued_points" else None if v is None else float(v)
                for k, v in summary["limits"].items()
            }
            limits_cfg = LimitsConfig(**given)
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise ShapeError(f"configuration summary without usable anchors/limits: {exc}") from exc
        if not all(math.isfinite(c) for a in anchors for c in a):
            raise ShapeError(f"anchors are not finite: {anchors}")
        try:
            geometry = layout_geometry(anchors, limits_cfg)
            ws = Workspace.from_limits(limits_cfg, geometry)
        except (KinematicsError, ValueError) as exc:  # WorkspaceError is a ValueError
            raise ShapeError(f"configuration summary: {exc}") from exc
        return RobotShape(
            name=str(summary.get("name", "")),
            anchors_m=anchors,
            footprint_m=ws.footprint_m,
            workspace_m=ws.polygon_m,
            workspace_faces_m=ws.boundary_m(),
            floor_z_m=ws.floor_z_m,
            top_z_m=ws.top_z_m,
            min_cable_m=ws.min_cable_m,
            max_cable_m=ws.max_cable_m,
        )


def length_colour(length_m: float, lo_m: float, hi_m: float) -> tuple[float, float, float]:
    """RGB (0..1) for a cable length: blue at `lo_m`, green half-way, red at `hi_m` (clamped)."""
    span = hi_m - lo_m
    f = 0.5 if not (span > 0 and math.isfinite(length_m)) else (length_m - lo_m) / span
    f = min(1.0, max(0.0, f))
    if f < 0.5:
        g = f / 0.5
        return (0.0, g, 1.0 - g)
    r = (f - 0.5) / 0.5
    return (r, 1.0 - r, 0.0)
