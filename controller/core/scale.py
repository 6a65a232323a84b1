"""Values that cannot be meant: a speed or a job whose size is off by a unit's factor for the
robot it is given to (a speed in mm/s where m/s is asked for, a G-code file written in metres
where millimetres are read). Pure: numbers in, a reason out.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

MIN_CROSSING_S = 0.05
"""A top speed that crosses the workspace's longest side in less than this cannot be meant."""
TINY_JOB_M = 0.005
"""A job whose motions span less than this (its bounding box's longest side) ..."""
TINY_JOB_RATIO = 100.0
"""... on a robot whose workspace is at least this many times longer is taken for a unit
mistake (a G-code file in metres read as millimetres is 1000 times too small)."""


def longest_side_m(box: Sequence[tuple[float, float]]) -> float:
    """The longest side of a box given as (lo, hi) per axis. Raises nothing."""
    return max((hi - lo for lo, hi in box), default=0.0)


def speed_scale_problem(
    max_speed_mps: float, workspace_box: Sequence[tuple[float, float]]
) -> str | None:
    """Why `max_speed_mps` cannot be meant for a workspace with this bounding box (it crosses
    the longest side in less than `MIN_CROSSING_S`: likely a value in mm/s), or None. Raises
    nothing."""
    side = longest_side_m(workspace_box)
    if not (math.isfinite(max_speed_mps) and max_speed_mps > 0.0 and side > 0.0):
        return None
    crossing_s = side / max_speed_mps
    if crossing_s >= MIN_CROSSING_S:
        return None
    return (
        f"{max_speed_mps:g} m/s crosses the workspace's {side:.3g} m in {crossing_s * 1e3:.3g} ms:"
        f" a speed this robot cannot mean (the unit is metres per second; a value in mm/s?)"
    )


def job_extent_m(points: Iterable[Sequence[float]]) -> float:
    """The longest side of the bounding box of `points` (0 for none). Raises nothing."""
    lo = [math.inf] * 3
    hi = [-math.inf] * 3
    for p in points:
        for i in range(3):
            lo[i] = min(lo[i], p[i])
            hi[i] = max(hi[i], p[i])
    if lo[0] == math.inf:
        return 0.0
    return max(h - low for low, h in zip(lo, hi, strict=True))


def tiny_job_problem(extent_m: float, workspace_box: Sequence[tuple[float, float]]) -> str | None:
    """Why a job whose motions span `extent_m` is likely written in other units than read (it
    spans less than `TINY_JOB_M` on a workspace at least `TINY_JOB_RATIO` times longer), or
    None. A job with no motion (extent 0) is not tiny. Raises nothing."""
    side = longest_side_m(workspace_box)
    if not (0.0 < extent_m < TINY_JOB_M and side >= TINY_JOB_RATIO * TINY_JOB_M):
        return None
    return (
        f"the job's motions span only {extent_m * 1e3:.3g} mm on a robot whose workspace is"
        f" {side:.3g} m long: is the file written in metres? G-code lengths are millimetres"
        " (G21) or inches (G20), and [gcode] units sets the unit a job starts in"
    )
