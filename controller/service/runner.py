"""The fixed-rate runner: calls a control step against absolute deadlines, and its loop thread.

`Runner(step, period_s).run(stop)` calls `step(now_s)` once per period on the monotonic clock
until `stop` is set. Deadlines are absolute (`next += period`): a step that ends past the next
deadline counts an overrun, and the deadlines already passed are skipped (counted): the loop
resumes on the grid and never bunches steps to catch up. It sleeps until `SPIN_S` before the
deadline and spins the rest, so a step starts within microseconds of it.

Its figures (`LoopStats`: overruns, skipped, the start jitter and compute time of the last
`STATS_WINDOW` steps) are written only by the loop thread and read by anyone;
`controller.service.loop.Controller` owns the `LoopStats` its runner writes and reports them in
`status()["loop"]`.

`start_loop` runs a runner in its own thread as the daemon does: SCHED_FIFO and a 1 us timer
slack for that thread (with `loop.realtime`), a short GIL switch interval, and the garbage
collector frozen after start-up (`loop.gc_freeze`).
"""

from __future__ import annotations

import ctypes
import gc
import logging
import math
import os
import sys
import threading
import time
from array import array
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from controller.service.config import LoopConfig

log = logging.getLogger("cablebot.loop")

STATS_WINDOW = 4096
"""Steps kept in the jitter / compute-time ring buffers."""
SPIN_S = 0.0002
"""The runner sleeps until this long before a deadline, then spins to it."""
PR_SET_TIMERSLACK = 29
RT_PRIORITY = 50
"""Default SCHED_FIFO priority of the loop thread (`loop.rt_priority` overrides it)."""
TIMER_SLACK_NS = 1_000
SWITCH_INTERVAL_S = 0.0005


# --------------------------------------------------------------------------------------------
# Statistics


class _Ring:
    """Preallocated ring buffer of floats; written by index in the loop, read by `summary`."""

    __slots__ = ("buf", "count", "size")

    def __init__(self, size: int) -> None:
        self.buf = array("d", bytes(8 * size))
        self.size = size
        self.count = 0

    def add(self, value: float) -> None:
        self.buf[self.count % self.size] = value
        self.count += 1

    def summary(self) -> dict[str, float | None]:
        """p50, p99 and max over the window (None when empty)."""
        n = min(self.count, self.size)
        if n == 0:
            return {"p50": None, "p99": None, "max": None}
        # numpy: ~50x faster than sorted() on the array, so a status request holds the GIL
        # (and so delays the loop thread) for tens of microseconds, not milliseconds.
        vals = np.sort(np.frombuffer(self.buf, dtype=np.float64, count=n))
        return {
            "p50": float(vals[(n - 1) // 2]),
            "p99": float(vals[min(n - 1, math.ceil(0.99 * n) - 1)]),
            "max": float(vals[-1]),
        }


class LoopStats:
    """A runner's figures: overruns, skipped deadlines, and rings of the last `STATS_WINDOW`
    steps' start jitter (start - deadline, s) and compute time (s).

    Written by the loop thread only; `figures` may be called from any thread.
    """

    __slots__ = ("compute", "jitter", "overruns", "skipped")

    def __init__(self) -> None:
        self.overruns = 0
        """Steps that ended past the next deadline."""
        self.skipped = 0
        """Deadlines passed over after overruns (the loop resumes on the grid)."""
        self.jitter = _Ring(STATS_WINDOW)
        self.compute = _Ring(STATS_WINDOW)

    def figures(self) -> dict[str, int | float | None]:
        """overruns, skipped, jitter and compute p50/p99/max (s; None before the first step),
        under their `status()["loop"]` keys."""
        j = self.jitter.summary()
        c = self.compute.summary()
        return {
            "overruns": self.overruns,
            "skipped": self.skipped,
            "jitter_p50_s": j["p50"],
            "jitter_p99_s": j["p99"],
            "jitter_max_s": j["max"],
            "compute_p50_s": c["p50"],
            "compute_p99_s": c["p99"],
            "compute_max_s": c["max"],
        }


# --------------------------------------------------------------------------------------------
# The runner


class Runner:
    """Calls `step(now_s)` every `period_s` seconds of `clock` (see the module docstring).

    `sleep` waits (time.sleep, or a fake clock's); `spin_s` is how early before a deadline the
    sleep ends; the figures go to `stats` (a new `LoopStats` if None). Raises ValueError for a
    period that is not a positive finite number.
    """

    def __init__(
        self,
        step: Callable[[float], None],
        period_s: float,
        *,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        spin_s: float = SPIN_S,
        stats: LoopStats | None = None,
    ) -> None:
        if not (math.isfinite(period_s) and period_s > 0.0):
            raise ValueError(f"period_s must be a positive finite number, got {period_s!r}")
        self.step = step
        self.period_s = float(period_s)
        self.clock = clock
        self.sleep = sleep
        self.spin_s = float(spin_s)
        self.stats = stats if stats is not None else LoopStats()

    def run(
        self,
        stop: threading.Event,
        *,
        on_watchdog: Callable[[], None] | None = None,
        watchdog_period_s: float = 0.0,
    ) -> None:
        """Call the step at the period until `stop` is set.

        `on_watchdog` is called from this thread every `watchdog_period_s` (systemd
        WATCHDOG=1), after the step; never when the period is not positive (no watchdog was
        asked for). Raises whatever the step raises.
        """
        clock = self.clock
        period = self.period_s
        sleep = self.sleep
        spin = self.spin_s
        step = self.step
        stats = self.stats
        jitter = stats.jitter
        compute = stats.compute
        next_s = clock() + period
        next_wd = clock() + watchdog_period_s
        if not watchdog_period_s > 0.0:  # 0 or NaN: no watchdog asked for
            on_watchdog = None
        while not stop.is_set():
            remaining = next_s - clock()
            if remaining > spin:
                sleep(remaining - spin)
            while clock() < next_s:
                pass
            start = clock()
            step(start)
            end = clock()
            jitter.add(start - next_s)
            compute.add(end - start)
            next_s += period
            if end > next_s:
                # Missed deadline(s): resume on the first deadline still ahead, on the grid.
                stats.overruns += 1
                behind = int((end - next_s) / period) + 1
                stats.skipped += behind
                next_s += behind * period
            if on_watchdog is not None and end >= next_wd:
                next_wd = end + watchdog_period_s
                on_watchdog()


# --------------------------------------------------------------------------------------------
# The loop thread and its scheduling


def set_realtime(priority: int, tid: int = 0) -> str:
    """Try SCHED_FIFO at `priority` for thread `tid` (0: the calling thread); return what
    happened, for the log. Raises nothing."""
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as exc:
        return f"SCHED_FIFO {priority} not available ({exc}); running SCHED_OTHER"
    return f"SCHED_FIFO priority {priority}"


def set_timer_slack(slack_ns: int) -> str:
    """Try prctl(PR_SET_TIMERSLACK) for the calling thread; return what happened, for the log."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        rc = libc.prctl(PR_SET_TIMERSLACK, ctypes.c_ulong(slack_ns), 0, 0, 0)
    except (OSError, AttributeError) as exc:
        return f"timer slack unchanged ({exc})"
    if rc != 0:
        return f"timer slack unchanged (errno {ctypes.get_errno()})"
    return f"timer slack {slack_ns} ns"


def start_loop(
    runner: Runner,
    loop_cfg: LoopConfig,
    stop: threading.Event,
    *,
    on_watchdog: Callable[[], None] | None = None,
    watchdog_period_s: float = 0.0,
    on_crash: Callable[[BaseException], None] | None = None,
) -> tuple[threading.Thread, list[str]]:
    """Run `runner.run(stop)` in a loop thread, as the daemon does: SCHED_FIFO at
    `loop_cfg.rt_priority` and a 1 us timer slack for that thread (with `loop_cfg.realtime`), a
    short GIL switch interval, and the garbage collector frozen after start-up
    (`loop_cfg.gc_freeze`).

    Returns the thread and a list that the thread fills with the scheduling it obtained.
    If the loop raises, it is logged and `on_crash` is called from the loop thread; nothing
    is raised.
    """
    report: list[str] = []

    def loop_main() -> None:
        if loop_cfg.realtime:
            report.append(set_realtime(int(loop_cfg.rt_priority)))
        else:
            report.append("SCHED_OTHER (loop.realtime = false)")
        report.append(set_timer_slack(TIMER_SLACK_NS))
        try:
            runner.run(stop, on_watchdog=on_watchdog, watchdog_period_s=watchdog_period_s)
        except BaseException as exc:
            log.exception("control loop crashed")
            if on_crash is not None:
                on_crash(exc)

    # A woken loop thread waits for the GIL up to the switch interval (5 ms by default):
    # shorten it so other Python threads (Zenoh callbacks, an in-process sim) yield sooner.
    sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
    if loop_cfg.gc_freeze:
        gc.collect()
        gc.freeze()
    thread = threading.Thread(target=loop_main, name="cablebot-loop", daemon=True)
    thread.start()
    return thread, report
