"""Values that cannot be meant: a speed or a job whose size is off by a unit's factor for the
robot it is given to (a speed in mm/s where m/s is asked for, a G-code file written in metres
where millimetres are read, a job's M203 read in the other dialect's unit). Pure: numbers in,
a reason out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

MIN_CROSSING_S = 0.05
"""A top speed that crosses the workspace's longest side in less than this cannot be meant."""
TINY_JOB_M = 0.005
"""A job whose motions span less than this (its bounding box's longest side), or less than a
`UNIT_FACTOR`th of the workspace's longest side, ..."""
SLOW_LIMIT_RATIO = 10.0
"""A job's M203 that lowers the speed this many times below the job's own feeds is taken for
the other dialect's unit (mm/s and mm/min are 60 apart)."""
TINY_JOB_RATIO = 100.0
"""... on a robot whose workspace is at least this many times `TINY_JOB_M` long is taken for
a unit mistake."""
UNIT_FACTOR = 1000.0
"""A G-code file written in metres and read as millimetres is this many times too small: the
whole job then fits in this fraction of the workspace (76 mm on the 76 m paper robot, where a
fixed 5 mm would miss a 3 m circle written in metres)."""


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


def tiny_job_problem(extent_m: float, workspace_box: Sequence[tuple[float, float]]) -> str | None:
    """Why a job whose motions span `extent_m` is likely written in other units than read (it
    spans less than `TINY_JOB_M`, or less than the workspace's longest side / `UNIT_FACTOR`,
    on a workspace at least `TINY_JOB_RATIO` times `TINY_JOB_M` long), or None. A job with no
    motion (extent 0) is not tiny. Raises nothing."""
    side = longest_side_m(workspace_box)
    if side < TINY_JOB_RATIO * TINY_JOB_M:
        return None
    if not 0.0 < extent_m < max(TINY_JOB_M, side / UNIT_FACTOR):
        return None
    return (
        f"the job's motions span only {extent_m * 1e3:.3g} mm on a robot whose workspace is"
        f" {side:.3g} m long: is the file written in metres? G-code lengths are millimetres"
        " (G21) or inches (G20), and [gcode] units sets the unit a job starts in"
    )


def speed_limit_problem(
    line_no: int, limit_mps: float, fastest_feed_mps: float, per_minute: bool
) -> str | None:
    """Why a job's `M203` at `line_no`, which limits it to `limit_mps`, is likely read in the
    wrong unit: the job's own feeds ask for `SLOW_LIMIT_RATIO` times that or more (Marlin
    writes M203 in mm/s, RepRapFirmware in mm/min: `per_minute` says which was read), or None.
    Raises nothing."""
    if not (limit_mps > 0.0 and fastest_feed_mps >= SLOW_LIMIT_RATIO * limit_mps):
        return None
    read, other, other_dialect = (
        ("mm/min", "mm/s", "marlin") if per_minute else ("mm/s", "mm/min", "reprapfirmware")
    )
    return (
        f"line {line_no}: M203 limits the job to {limit_mps * 1e3:.4g} mm/s (read in {read}),"
        f" {fastest_feed_mps / limit_mps:.0f} times below the feeds it asks for (up to"
        f" {fastest_feed_mps * 1e3:.4g} mm/s): was it written in {other}? ([gcode] dialect ="
        f' "{other_dialect}" reads it so)'
    )
