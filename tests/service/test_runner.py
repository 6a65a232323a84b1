"""The fixed-rate runner on its own: deadlines, watchdog, figures, and its loop thread."""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Iterator

import pytest

from controller.service.config import LoopConfig
from controller.service.runner import STATS_WINDOW, LoopStats, Runner, start_loop


class StepClock:
    """A clock that only sleeping and the step move; a sleep ends a microsecond late."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s

    def sleep(self, dt_s: float) -> None:
        self.now_s += max(dt_s, 0.0) + 1e-6


@pytest.fixture
def switch_interval() -> Iterator[None]:
    """`start_loop` shortens the process's GIL switch interval: put it back."""
    old = sys.getswitchinterval()
    yield
    sys.setswitchinterval(old)


@pytest.mark.parametrize("period_s", [0.0, -1e-3, math.nan, math.inf])
def test_a_period_that_is_not_positive_and_finite_is_refused(period_s: float) -> None:
    with pytest.raises(ValueError, match="period_s must be a positive finite number"):
        Runner(lambda now_s: None, period_s)


def test_the_step_runs_on_the_grid_and_the_watchdog_at_its_own_period() -> None:
    clk = StepClock()
    stop = threading.Event()
    starts: list[float] = []
    beats: list[float] = []

    def step(now_s: float) -> None:
        starts.append(now_s)
        clk.now_s += 0.0003  # compute time
        if len(starts) >= 50:
            stop.set()

    runner = Runner(step, 0.002, clock=clk, sleep=clk.sleep, spin_s=0.0)
    runner.run(stop, on_watchdog=lambda: beats.append(clk()), watchdog_period_s=0.009)
    assert len(starts) == 50
    # On the absolute grid (the late sleep is not carried over from one step to the next).
    assert starts == pytest.approx([0.002 * (i + 1) + 1e-6 for i in range(50)], abs=1e-12)
    # The watchdog after the step, no sooner than 9 ms after the last one: every fifth step.
    assert beats == pytest.approx([starts[i] + 0.0003 for i in range(4, 50, 5)], abs=1e-12)
    f = runner.stats.figures()
    assert f["overruns"] == 0 and f["skipped"] == 0
    assert f["compute_p50_s"] == pytest.approx(0.0003) and f["compute_max_s"] == pytest.approx(
        0.0003
    )
    assert f["jitter_max_s"] == pytest.approx(1e-6, abs=1e-12)


def test_figures_are_none_before_the_first_step_and_the_rings_keep_a_window() -> None:
    stats = LoopStats()
    assert stats.figures() == {
        "overruns": 0,
        "skipped": 0,
        "jitter_p50_s": None,
        "jitter_p99_s": None,
        "jitter_max_s": None,
        "compute_p50_s": None,
        "compute_p99_s": None,
        "compute_max_s": None,
    }
    for i in range(STATS_WINDOW + 100):
        stats.compute.add(1.0 if i < 100 else 0.5)
    # The 100 oldest values (1.0) have left the window.
    assert stats.figures()["compute_max_s"] == 0.5


def test_a_step_that_raises_ends_the_run_with_its_exception() -> None:
    clk = StepClock()

    def step(now_s: float) -> None:
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        Runner(step, 0.001, clock=clk, sleep=clk.sleep, spin_s=0.0).run(threading.Event())


def test_start_loop_reports_its_scheduling_and_hands_a_crash_to_on_crash(
    switch_interval: None,
) -> None:
    crashed: list[BaseException] = []
    steps: list[float] = []

    def step(now_s: float) -> None:
        steps.append(now_s)
        if len(steps) == 3:
            raise RuntimeError("step failed")

    cfg = LoopConfig(rate_hz=500.0, realtime=False, gc_freeze=False)
    stop = threading.Event()
    thread, report = start_loop(Runner(step, 0.002), cfg, stop, on_crash=crashed.append)
    assert thread.name == "cablebot-loop" and thread.daemon
    thread.join(5.0)
    assert not thread.is_alive()
    assert len(steps) == 3
    assert len(crashed) == 1 and str(crashed[0]) == "step failed"
    assert report[0] == "SCHED_OTHER (loop.realtime = false)"
    assert report[1].startswith("timer slack")
    assert sys.getswitchinterval() <= 0.0005


def test_start_loop_runs_until_stopped(switch_interval: None) -> None:
    steps: list[float] = []
    runner = Runner(steps.append, 0.001)
    stop = threading.Event()
    thread, _ = start_loop(runner, LoopConfig(realtime=False, gc_freeze=False), stop)
    deadline = time.monotonic() + 5.0
    while len(steps) < 20 and time.monotonic() < deadline:
        time.sleep(0.005)
    stop.set()
    thread.join(5.0)
    assert not thread.is_alive()
    assert len(steps) >= 20
    assert runner.stats.compute.count == len(steps)
