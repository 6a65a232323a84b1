"""Figures of the path planner for the benchmark: planning cost per point and the tick's cost
(`MotionPlanner.advance`) with few and many points queued.

Measures with the clock it is given (`time.perf_counter` by default) and returns plain numbers;
it prints nothing and judges nothing (the benchmark compares them with its targets).
"""

from __future__ import annotations

import itertools
import math
import statistics
import time
from collections.abc import Callable

from controller.core.motion import MotionPlanner, Vec3, circle_path


def _spiral(n: int, step_m: float = 0.001) -> tuple[Vec3, ...]:
    """`n` points `step_m` apart on a slowly widening horizontal spiral (every corner turns)."""
    pts: list[Vec3] = []
    ang = 0.0
    for _ in range(n):
        r = 0.2 + 1e-6 * len(pts)
        ang += step_m / r
        pts.append((r * math.cos(ang), r * math.sin(ang), 1.0))
    return tuple(pts)


def _tick_cost_us(pl: MotionPlanner, ticks: int, dt_s: float, clock: Callable[[], float]) -> float:
    t0 = clock()
    for _ in range(ticks):
        pl.advance(dt_s)
    return (clock() - t0) / ticks * 1e6


def bench_planning(
    points: int = 20_000,
    repeats: int = 3,
    ticks: int = 2_000,
    queued: int = 100_000,
    clock: Callable[[], float] = time.perf_counter,
) -> dict[str, float]:
    """Plan `points` points and time `advance`; medians of `repeats` runs.

    Returns `plan_us_per_point` (a path of `points` 1 mm segments, every one a rounded corner,
    planned at once), `append_us_per_point` (the same points appended in chunks of 1,000 and
    planned), `advance_us_10` and `advance_us_100k` (one `advance(2 ms)` with 10 and 100,000
    points queued and planned, 5 cm apart, so that both ticks cross the same corners),
    `advance_us_100k_staged` (100,000 queued, planned as the set-point advances) and
    `circle_s` / `circle_ideal_s` (the 1,000-point circle of radius 0.2 m at 0.1 m/s and
    1 m/s^2: the time it takes and length / speed). `queued` replaces the 100,000 (the "100k"
    figures keep their names). Raises ValueError for `points`, `repeats` or `ticks` below 1.
    """
    if points < 1 or repeats < 1 or ticks < 1:
        raise ValueError("points, repeats and ticks must be >= 1")
    dt = 0.002
    pts = _spiral(points)
    # the tick's cost with 10 and 100,000 points queued: the same corners (5 cm segments on a
    # circle of 0.2 m, flown at 0.1 m/s), only the queue's length differs
    big = _spiral(max(queued, 10), 0.05)
    few = big[:10]
    plan_us: list[float] = []
    append_us: list[float] = []
    adv10: list[float] = []
    adv100k: list[float] = []
    adv_staged: list[float] = []
    for _ in range(repeats):
        pl = MotionPlanner(1.0, 1.0, max_queued_points=200_000)
        pl.hold((0.2, 0.0, 1.0))
        t0 = clock()
        pl.follow_points(pts, 0.1)
        pl.plan(points)
        plan_us.append((clock() - t0) / points * 1e6)

        pl = MotionPlanner(1.0, 1.0, max_queued_points=200_000)
        pl.hold((0.2, 0.0, 1.0))
        t0 = clock()
        pl.follow_points(pts[:1000], 0.1)
        for i in range(1000, points, 1000):
            pl.append_prepared(pts[i : i + 1000], 0.1)
        pl.plan(points)
        append_us.append((clock() - t0) / points * 1e6)

        pl = MotionPlanner(1.0, 1.0)
        pl.hold((0.2, 0.0, 1.0))
        pl.follow_points(few, 0.1)
        pl.plan(len(few))
        adv10.append(_tick_cost_us(pl, ticks, dt, clock))

        pl = MotionPlanner(1.0, 1.0, max_queued_points=max(200_000, len(big)))
        pl.hold((0.2, 0.0, 1.0))
        pl.follow_points(big, 0.1)
        adv_staged.append(_tick_cost_us(pl, ticks, dt, clock))
        pl.plan(len(big))
        adv100k.append(_tick_cost_us(pl, ticks, dt, clock))

    circle = circle_path(0.2, (0.0, 0.0), 1.0, steps=1000)
    pl = MotionPlanner(1.0, 1.0)
    pl.hold(circle[0])
    pl.follow_path(circle, 0.1)
    n = 0
    while pl.moving and n < 1_000_000:
        pl.advance(dt)
        n += 1
    length = sum(math.dist(a, b) for a, b in itertools.pairwise(circle))
    return {
        "plan_us_per_point": statistics.median(plan_us),
        "append_us_per_point": statistics.median(append_us),
        "advance_us_10": statistics.median(adv10),
        "advance_us_100k": statistics.median(adv100k),
        "advance_us_100k_staged": statistics.median(adv_staged),
        "circle_s": n * dt,
        "circle_ideal_s": length / 0.1,
    }
