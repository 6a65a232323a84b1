"""Validation of heavy cables (`[[reels]] cable_mass_kg_per_m`): a cable too heavy to hang
within the tension limit anywhere in the workspace is refused with the pose
(`controller.service.config.parse` calls it with the rest of the validation).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from controller.core.catenary import least_anchor_tension
from controller.core.kinematics import Geometry
from controller.core.statics import G_MPS2
from controller.core.workspace import Workspace, WorkspaceError
from controller.service.config.schema import LimitsConfig, ReelConfig, TensionLimits

__all__ = ["cable_self_weight_problems"]


def cable_self_weight_problems(
    reels: Sequence[ReelConfig],
    limits: LimitsConfig,
    tension: TensionLimits,
    geometry: Geometry,
) -> list[tuple[int, str, str]]:
    """(reel index, key, problem) for each heavy cable that cannot hold its own weight within
    the tension limit minus its margin at a pose of the workspace: the least tension its
    anchor end can carry over the span to the farthest corner of the workspace box, at the
    floor and at the top (``catenary.least_anchor_tension``).  Raises nothing."""
    try:
        box = Workspace.from_limits(limits, geometry).box()
    except WorkspaceError:
        return []
    (x0, x1), (y0, y1), (z0, z1) = box
    corners = [(x, y, z) for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)]
    limit = tension.max_n - tension.margin_n
    out = []
    for i, r in enumerate(reels):
        m = r.cable_mass_kg_per_m
        if not m:
            continue
        ax, ay, az = r.anchor_m
        worst = (0.0, corners[0])
        for c in corners:
            try:
                t = least_anchor_tension(math.hypot(ax - c[0], ay - c[1]), az - c[2], m * G_MPS2)
            except ValueError:
                continue
            if t > worst[0]:
                worst = (t, c)
        if worst[0] > limit:
            at = "(" + ", ".join(f"{v:.3g}" for v in worst[1]) + ")"
            out.append(
                (
                    i,
                    "cable_mass_kg_per_m",
                    f"{m:g} kg/m is too heavy: to reach the workspace's corner {at} m the cable "
                    f"alone needs at least {worst[0]:.4g} N at its anchor, above {limit:.4g} N "
                    f"({tension.max_source} {tension.max_n:.4g} N - tension_margin_n "
                    f"{tension.margin_n:g} N)",
                )
            )
    return out
