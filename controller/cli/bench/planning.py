"""The motion planner's section: planning cost per point, the tick's `advance` with few and many
points queued, and the circle's time against its ideal (`controller.core.motion_bench`).
"""

from __future__ import annotations

import gc
import statistics
import time
from collections.abc import Callable
from typing import Any

from controller.cli.bench.settings import (
    PLANNING_KEYS,
    TARGET_ADVANCE_100K_OVER_10,
    BenchError,
    Plan,
)
from controller.cli.bench.table import Row


def bench_planning_figures(repeats: int) -> dict[str, float]:
    """`motion_bench.bench_planning` run `repeats` times (one repeat each, GC off, timed by this
    thread's CPU time); the median of each figure and of the per-run ratio
    `advance_100k_over_10` (both ticks of a ratio come from the same run, back to back).

    Raises BenchError if a figure is not finite and positive, ValueError if `repeats` < 1.
    """
    from controller.core.motion_bench import bench_planning

    if repeats < 1:
        raise ValueError("repeats must be >= 1")
    runs: list[dict[str, float]] = []
    was_enabled = gc.isenabled()
    gc.collect()
    gc.disable()
    try:
        for _ in range(repeats):
            runs.append(bench_planning(repeats=1, clock=time.thread_time))
            gc.collect()  # the 100,000 queued points' garbage, outside the timed parts
    finally:
        if was_enabled:
            gc.enable()
    out = {key: float(statistics.median(r[key] for r in runs)) for key in runs[0]}
    out["advance_100k_over_10"] = float(
        statistics.median(r["advance_us_100k"] / r["advance_us_10"] for r in runs)
    )
    for key, v in out.items():
        if not (v > 0.0 and v < float("inf")):
            raise BenchError(f"motion planning: {key} is {v!r}")
    return out


def measure_planning(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """The planning section's JSON figures (`PLANNING_KEYS`) and table rows. Raises BenchError."""
    log(f"motion planning ({p.planning_repeats} runs) ...")
    f = bench_planning_figures(p.planning_repeats)
    rep = f"median of {p.planning_repeats} runs"
    ratio = f["advance_100k_over_10"]
    rows = [
        Row("planning.plan_us_per_point", f["plan_us_per_point"], "us", "", None, rep),
        Row("planning.append_us_per_point", f["append_us_per_point"], "us", "", None, rep),
        Row("planning.advance_us_10", f["advance_us_10"], "us", "", None, f"{rep}; 2,000 ticks"),
        Row(
            "planning.advance_us_100k",
            f["advance_us_100k"],
            "us",
            "",
            None,
            f"{rep}; staged as it advances {f['advance_us_100k_staged']:.3g}",
        ),
        Row(
            "planning.advance_100k_over_10",
            ratio,
            "ratio",
            f"<= {TARGET_ADVANCE_100K_OVER_10:g}",
            ratio <= TARGET_ADVANCE_100K_OVER_10,
            f"median of {p.planning_repeats} per-run ratios",
        ),
        Row(
            "planning.circle_s",
            f["circle_s"],
            "s",
            "",
            None,
            f"ideal {f['circle_ideal_s']:.3f} s (length / speed); "
            f"{f['circle_s'] / f['circle_ideal_s']:.3f}x",
        ),
    ]
    return {key: f[key] for key in PLANNING_KEYS}, rows
