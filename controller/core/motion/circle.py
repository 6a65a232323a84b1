"""The paper's example (c): a horizontal circle as straight legs."""

from __future__ import annotations

import math
from collections.abc import Sequence

from .speeds import Vec3, _positive


def circle_path(
    radius_m: float = 20.0,
    centre_m: Sequence[float] = (0.0, 0.0),
    z_m: float = 2.0,
    steps: int = 72,
) -> list[Vec3]:
    """The paper's example (c): a horizontal circle as `steps` straight legs.

    Returns `steps + 1` points at angles 0, 360/steps, ... 360 degrees, counter-clockwise from
    +x; the last point repeats the first exactly, so following the path closes the circle
    (72 legs of 5 degrees each for the defaults, radius 20 m about (0, 0) at z = 2 m).
    Raises ValueError on a non-positive/non-finite radius, non-finite centre or z, or steps < 3.
    """
    r = _positive(radius_m, "radius_m")
    if len(centre_m) != 2:
        raise ValueError(f"centre_m must have 2 components, got {len(centre_m)}")
    cx, cy = float(centre_m[0]), float(centre_m[1])
    z = float(z_m)
    if not (math.isfinite(cx) and math.isfinite(cy) and math.isfinite(z)):
        raise ValueError("centre_m and z_m must be finite")
    if int(steps) != steps or steps < 3:
        raise ValueError(f"steps must be an integer >= 3, got {steps!r}")
    pts: list[Vec3] = []
    for i in range(int(steps)):
        ang = 2.0 * math.pi * i / steps
        pts.append((cx + r * math.cos(ang), cy + r * math.sin(ang), z))
    pts.append(pts[0])
    return pts
