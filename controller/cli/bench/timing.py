"""Timing helpers of the benchmark: percentiles, interleaved CPU/wall timing of sides."""

from __future__ import annotations

import gc
import math
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass


def percentile(values: Sequence[float], q: float) -> float:
    """Nearest-rank percentile (`q` in 0..1) of `values`, as the loop's rings compute it.

    Raises ValueError on an empty sequence.
    """
    if not values:
        raise ValueError("percentile of no values")
    s = sorted(values)
    return s[max(0, min(len(s) - 1, math.ceil(q * len(s)) - 1))]


def _median(values: Sequence[float]) -> float:
    return float(statistics.median(values))


@dataclass(frozen=True, slots=True)
class Timed:
    """Per side, per repeat: the thread's CPU time and the wall-clock time, in nanoseconds."""

    cpu_ns: list[list[int]]
    wall_ns: list[list[int]]

    def cpu(self, side: int, per: int = 1) -> float:
        """Median CPU time of one side divided by `per`, in nanoseconds."""
        return _median(self.cpu_ns[side]) / per

    def wall(self, side: int, per: int = 1) -> float:
        """Median wall-clock time of one side divided by `per`, in nanoseconds."""
        return _median(self.wall_ns[side]) / per

    def ratio(self, num: int, den: int) -> float:
        """Median over repeats of the CPU-time ratio side `num` / side `den`."""
        pairs = zip(self.cpu_ns[num], self.cpu_ns[den], strict=True)
        return _median([a / b for a, b in pairs])


def interleaved(
    sides: Sequence[Callable[[], object]], repeats: int, *, warm_up: bool = True
) -> Timed:
    """Run each side once per repeat, in turn (A, B, A, B, ...), GC off, and time each run.

    Both the calling thread's CPU time (`time.thread_time_ns`: time other processes take on a
    shared machine does not count) and the wall clock are recorded. With `warm_up` a first
    round runs and is not counted.
    """
    cpu: list[list[int]] = [[] for _ in sides]
    wall: list[list[int]] = [[] for _ in sides]
    thread_ns = time.thread_time_ns
    perf_ns = time.perf_counter_ns
    was_enabled = gc.isenabled()
    gc.collect()
    gc.disable()
    try:
        if warm_up:
            for fn in sides:
                fn()
        for _ in range(repeats):
            for k, fn in enumerate(sides):
                w0 = perf_ns()
                c0 = thread_ns()
                fn()
                c1 = thread_ns()
                w1 = perf_ns()
                cpu[k].append(c1 - c0)
                wall[k].append(w1 - w0)
    finally:
        if was_enabled:
            gc.enable()
    return Timed(cpu, wall)
