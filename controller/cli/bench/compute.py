"""The controller's own compute per tick, without any transport: `Controller.tick` on a driver
that hands in readings from memory and keeps no frames, armed and flying a path at 1 kHz.

No bus, no Zenoh, no other process: the figure is the control step's own CPU time (poll and
read of in-memory readings, FPK, command intake, planner, limits, tensions, IPK, feed-forward,
the pose sample handed to a publisher that drops it), so it carries over between machines
better than the loop runs, whose ticks also pay python-can and the network stack.
"""

from __future__ import annotations

import gc
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from controller.cli.bench.settings import COMPUTE_KEYS, COMPUTE_RATE_HZ, BenchError, Plan
from controller.cli.bench.table import Row
from controller.cli.bench.timing import percentile

if TYPE_CHECKING:
    from drivers.base import AxisReading

COMPUTE_PATH_M = (
    (2.0, 0.0, 2.0),
    (2.0, 2.0, 2.5),
    (-2.0, 2.0, 3.0),
    (-2.0, -2.0, 2.5),
    (2.0, -2.0, 2.0),
    (2.0, 0.0, 2.0),
    (0.0, 0.0, 2.0),
)
"""The path flown (m): a 4 m x 4 m loop around the built-in robot's power-up pose, climbing
and descending, so that every cable's length changes and every corner is rounded."""

COMPUTE_SPEED_MPS = 1.0

COMPUTE_WARM_UP_TICKS = 200


class _Clock:
    """A monotonic clock moved by hand: the ticks come at exactly the loop's period."""

    def __init__(self) -> None:
        self.now_s = 1000.0

    def __call__(self) -> float:
        return self.now_s


class EchoDriver:
    """A `drivers.base.ReelDriver` without a bus: `poll` hands in one fresh reading per axis
    (each axis where the last command put it, as an ideal drive would, in closed loop after
    `arm`), `command` keeps only a reference to the last set-point, sends nothing. Readings are
    updated in place: no allocation per tick beyond the controller's own."""

    def __init__(self, node_ids: Sequence[int], positions_rev: Sequence[float], clock: _Clock):
        from drivers.base import AxisReading, BusStats

        self.node_ids = tuple(node_ids)
        self._clock = clock
        self._readings = [
            AxisReading(nid, position_rev=float(p), axis_state=1, state_name="IDLE")
            for nid, p in zip(self.node_ids, positions_rev, strict=True)
        ]
        self._stats = BusStats()
        self._armed = False
        self._last: Sequence[float] | None = None

    def poll(self) -> int:
        """Make every reading fresh (at the clock's time) and, when armed, put each axis where
        the last command sent it. Returns the axes handled."""
        now = self._clock.now_s
        now_ns = int(now * 1e9)
        last = self._last if self._armed else None
        for i, r in enumerate(self._readings):
            if last is not None:
                r.position_rev = last[i]
            r.stamp_s = now
            r.stamp_ns = now_ns
            r.heartbeat_stamp_s = now
            r.status_stamp_s = now
        return len(self._readings)

    def read(self) -> Sequence[AxisReading]:
        """The readings, in the order of `node_ids`."""
        return self._readings

    def command(
        self, positions_rev: Sequence[float], velocity_ff_rps: Sequence[float] | None = None
    ) -> None:
        """Keep the set-point for the next `poll`; raises ValueError for a non-finite value or
        a wrong count, as a real driver does."""
        if len(positions_rev) != len(self.node_ids):
            raise ValueError(f"{len(positions_rev)} set-points for {len(self.node_ids)} axes")
        for v in positions_rev:
            if not math.isfinite(v):
                raise ValueError(f"non-finite set-point {list(positions_rev)}")
        self._last = positions_rev

    def arm(self) -> None:
        """Every axis enters closed loop at once."""
        now = self._clock.now_s
        self._armed = True
        for r in self._readings:
            r.axis_state = 8
            r.ready = True
            r.fault = None
            r.state_name = "CLOSED_LOOP_CONTROL"
            r.command_stamp_s = now

    def disarm(self) -> None:
        """Every axis goes idle."""
        self._armed = False
        for r in self._readings:
            r.axis_state = 1
            r.ready = False
            r.state_name = "IDLE"

    def estop(self) -> None:
        """As `disarm`."""
        self.disarm()

    def request_encoders(self) -> None:
        """Nothing to ask: `poll` always has fresh readings."""

    @property
    def stats(self) -> Any:
        """The traffic counters (all zero: no bus)."""
        return self._stats


BENCH_BUILDUP_FACTOR_M = 1.0e-6
"""The spool build-up of the bench's build-up run (`[[reels]] spool_buildup_factor_m`): a
0.5 m-per-turn drum whose metres per turn change by 2.5 % over the built-in robot's cables."""


def bench_compute(
    ticks: int,
    *,
    stretch: bool = False,
    buildup: bool = False,
    sag: bool = False,
    shaper: str | None = None,
    shaper_passes: int = 1,
) -> dict[str, float]:
    """CPU time of `Controller.tick` per tick at `COMPUTE_RATE_HZ` on the built-in robot
    (rigid cables, or with `stretch` every cable at EA 2e5 N; with `buildup` every reel's spool
    builds up by `BENCH_BUILDUP_FACTOR_M` from the power-up lengths; with `sag` every cable
    3 mm steel rope: `controller.cli.sag_bench.sag_config`; with `shaper` that input shaper,
    on the model's modes at the set-point, which needs `stretch`, each mode's train applied
    `shaper_passes` times), armed and flying
    `COMPUTE_PATH_M` at 1 m/s on an `EchoDriver`, publishing every tick to a publisher that
    drops the sample; `ticks` measured after a warm-up, GC frozen as the daemon does.

    Returns ticks, p50_us, p99_us, max_us, p99_frac (p99 over the period) and moving_frac
    (the share of measured ticks in MOVING). Raises BenchError if the controller refuses the
    path or faults, ValueError if `ticks` < 1.
    """
    from controller.core import kinematics
    from controller.core.commands import Arm, Path
    from controller.core.reel import spool_buildup_from_factor
    from controller.core.states import State
    from controller.service.config import default_config
    from controller.service.loop import Controller

    if ticks < 1:
        raise ValueError("ticks must be >= 1")
    cfg = default_config()
    cfg = replace(cfg, loop=replace(cfg.loop, rate_hz=float(COMPUTE_RATE_HZ), publish_every=1))
    if stretch:
        cfg = replace(cfg, reels=tuple(replace(r, cable_ea_n=2e5) for r in cfg.reels))
    if sag:
        from controller.cli.sag_bench import sag_config

        cfg = sag_config(cfg)
    if shaper is not None:
        cfg = replace(cfg, shaper=replace(cfg.shaper, type=shaper, passes=shaper_passes))
    assert cfg.homing.power_up_position_m is not None
    lengths = kinematics.ipk_point(cfg.geometry, cfg.homing.power_up_position_m)
    if buildup:
        b = spool_buildup_from_factor(BENCH_BUILDUP_FACTOR_M)
        cfg = replace(
            cfg,
            reels=tuple(
                replace(r, reel=replace(r.reel, spool_buildup_m_per_rev2=b, reference_length_m=L))
                for r, L in zip(cfg.reels, lengths, strict=True)
            ),
        )
    turns = [r.reel.position_rev(L) for r, L in zip(cfg.reels, lengths, strict=True)]
    clock = _Clock()
    driver = EchoDriver([r.node_id for r in cfg.reels], turns, clock)
    ctl = Controller(cfg, driver, clock=clock)
    period_s = 1.0 / COMPUTE_RATE_HZ
    tick = ctl.tick

    def step(n: int) -> None:
        for _ in range(n):
            clock.now_s += period_s
            tick(clock.now_s)

    def state() -> State:
        return ctl.state  # a call, so that the type checker does not narrow it across ticks

    def fly() -> None:
        fut = ctl.submit(Path(COMPUTE_PATH_M, COMPUTE_SPEED_MPS))
        step(1)
        exc = fut.exception(timeout=0) if fut.done() else None
        if exc is not None or state() is not State.MOVING:
            raise BenchError(f"no transport: the path was not taken ({exc or state().value})")

    step(2)
    ctl.submit(Arm())
    step(1)
    deadline = 1000
    while state() is not State.HOLDING and deadline > 0:
        step(1)
        deadline -= 1
    if state() is not State.HOLDING:
        raise BenchError(f"no transport: not armed ({state().value}: {ctl.reason})")
    fly()
    step(COMPUTE_WARM_UP_TICKS)

    cpu_ns = [0] * ticks
    moving = 0
    thread_ns = time.thread_time_ns
    gc.collect()
    gc.freeze()
    try:
        for k in range(ticks):
            if state() is not State.MOVING:
                fly()
            clock.now_s += period_s
            c0 = thread_ns()
            tick(clock.now_s)
            cpu_ns[k] = thread_ns() - c0
            now_state = state()
            if now_state is State.MOVING:
                moving += 1
            elif now_state is not State.HOLDING:
                raise BenchError(f"no transport: the robot left the path ({ctl.reason})")
    finally:
        gc.unfreeze()
    us = [v / 1e3 for v in cpu_ns]
    p99 = percentile(us, 0.99)
    return {
        "ticks": ticks,
        "p50_us": percentile(us, 0.5),
        "p99_us": p99,
        "max_us": max(us),
        "p99_frac": p99 / (period_s * 1e6),
        "moving_frac": moving / ticks,
    }


def measure_compute(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """The no-transport section's JSON figures (`COMPUTE_KEYS`, rigid cables) and table rows
    (rigid, with stretch and with sag). Raises BenchError."""
    log(f"controller compute per tick without transport ({p.compute_ticks:,} ticks) ...")
    f = bench_compute(p.compute_ticks)
    fs = bench_compute(p.compute_ticks, stretch=True)
    fb = bench_compute(p.compute_ticks, buildup=True)
    fg = bench_compute(p.compute_ticks, sag=True)
    n = f"{f['ticks']:,} ticks at {COMPUTE_RATE_HZ} Hz, CPU time"
    rows = [
        Row("compute_per_tick.p50_us", f["p50_us"], "us", "", None, n),
        Row(
            "compute_per_tick.p99_us",
            f["p99_us"],
            "us",
            "",
            None,
            f"{f['p99_frac']:.3f} of the period; max {f['max_us']:.0f}; "
            f"{f['moving_frac']:.0%} moving",
        ),
        Row(
            "  with cable stretch p50",
            fs["p50_us"],
            "us",
            "",
            None,
            f"p99 {fs['p99_us']:.1f}; EA 2e5 N on every cable",
        ),
        Row(
            "  with spool build-up p50",
            fb["p50_us"],
            "us",
            "",
            None,
            f"p99 {fb['p99_us']:.1f}; spool_buildup_factor_m"
            f" {BENCH_BUILDUP_FACTOR_M:g} on every reel",
        ),
        Row(
            "  with cable sag p50",
            fg["p50_us"],
            "us",
            "",
            None,
            f"p99 {fg['p99_us']:.1f}, max {fg['max_us']:.0f}; 3 mm steel on every cable",
        ),
    ]
    return {key: f[key] for key in COMPUTE_KEYS}, rows
