"""The tick's added cost of input shaping: `compute.bench_compute` with cable stretch, with the
default shaper (on the model's three modes, following the set-point), with it at two passes
(`[shaper] passes = 2`) and without, interleaved in one run (off, on, two passes, off, ...),
each figure the median over the rounds."""

from __future__ import annotations

import statistics
from collections.abc import Callable
from typing import Any

from controller.cli.bench.compute import bench_compute
from controller.cli.bench.settings import SHAPING_KEYS, TARGET_SHAPING_ADDED_US, Plan
from controller.cli.bench.table import Row

PAIRS = 5
"""Off/on pairs of compute runs."""


def bench_shaping(ticks: int, pairs: int = PAIRS) -> dict[str, float]:
    """The `SHAPING_KEYS` figures: p50 and p99 of the tick's CPU time (us) without and with
    the default shaper, the p99 added (the median of the per-pair differences) and the p99
    ratio on over off (the median of the per-pair ratios); the same p99 and p99 added with
    two passes. Raises BenchError as `bench_compute` does."""
    from controller.core.motion.shaper import DEFAULT_SHAPER_TYPE

    off: list[dict[str, float]] = []
    on: list[dict[str, float]] = []
    two: list[dict[str, float]] = []
    for _ in range(pairs):
        off.append(bench_compute(ticks, stretch=True))
        on.append(bench_compute(ticks, stretch=True, shaper=DEFAULT_SHAPER_TYPE))
        two.append(bench_compute(ticks, stretch=True, shaper=DEFAULT_SHAPER_TYPE, shaper_passes=2))
    med = statistics.median
    return {
        "p50_us_off": med(r["p50_us"] for r in off),
        "p99_us_off": med(r["p99_us"] for r in off),
        "p50_us_on": med(r["p50_us"] for r in on),
        "p99_us_on": med(r["p99_us"] for r in on),
        "added_p99_us": med(b["p99_us"] - a["p99_us"] for a, b in zip(off, on, strict=True)),
        "on_over_off": med(b["p99_us"] / a["p99_us"] for a, b in zip(off, on, strict=True)),
        "p99_us_two_passes": med(r["p99_us"] for r in two),
        "added_p99_us_two_passes": med(
            b["p99_us"] - a["p99_us"] for a, b in zip(off, two, strict=True)
        ),
    }


def measure_shaping(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """The shaping section's JSON figures (`SHAPING_KEYS`) and table rows. Raises BenchError."""
    log(f"the tick with and without input shaping ({PAIRS} x 3 x {p.compute_ticks:,} ticks) ...")
    f = bench_shaping(p.compute_ticks)
    added = f["added_p99_us"]
    rows = [
        Row(
            "shaping_per_tick.added_p99_us",
            added,
            "us",
            f"<= {TARGET_SHAPING_ADDED_US:g}",
            added <= TARGET_SHAPING_ADDED_US,
            f"p99 {f['p99_us_off']:.1f} -> {f['p99_us_on']:.1f} us (x{f['on_over_off']:.2f}), "
            f"p50 {f['p50_us_off']:.1f} -> {f['p50_us_on']:.1f} us; stretch on both",
        ),
        Row(
            "shaping_per_tick.added_p99_us_two_passes",
            f["added_p99_us_two_passes"],
            "us",
            "",
            None,
            f"[shaper] passes = 2: p99 {f['p99_us_off']:.1f} -> {f['p99_us_two_passes']:.1f} us",
        ),
    ]
    return {key: f[key] for key in SHAPING_KEYS}, rows
