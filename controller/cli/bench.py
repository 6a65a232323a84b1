"""`cablebot bench [--quick] [--json FILE]`: where the time goes, measured on this machine.

Prints one table (figure, value, target, PASS/MISSED, how many repeats) and with `--json FILE`
writes exactly the keys of `JSON_KEYS`. The exit code is 0 even when a target is missed (this is a
measurement); it is 1 only when a figure could not be measured at all.

Method
------
* Micro-benchmarks time a loop of calls with the garbage collector off, on one thread, by the
  thread's CPU time (`time.thread_time_ns`), so that time taken by other processes on a shared
  machine does not count; the wall-clock median (`time.perf_counter_ns`) is shown next to it.
  Each figure is the median over repeats. Ratios are formed per repeat from the two sides run
  back to back (A, B, A, B, ...), then the median of those ratios is taken.
* `fpk_simplified_us` / `fpk_general_us`: `kinematics.three_spheres_equal_height` and
  `kinematics.three_spheres` (scalar, everything from the centres on every call) on the same
  three paper anchors and lengths.
* `fpk4_us`: `kinematics.fpk` on the paper robot's four cables, over a fixed set of poses in the
  workspace whose lengths carry 1 mm of Gaussian noise, so the least-squares refinement runs as
  it does on measured lengths (on exactly consistent lengths `fpk` skips it).
  `scipy_over_fpk4`: `scipy.optimize.least_squares` (default trust-region method, analytic
  Jacobian: the stronger baseline) on the same four spheres, started from the workspace centre.
  The table also shows the ratio with scipy's default finite-difference Jacobian and how far
  apart the solutions are.
* `batch_over_copy`: `kinematics.fpk_batch` on 1,000,000 such noisy rows over `np.copy` of the
  (1,000,000, 4) input. The table also shows the ratio on exactly consistent lengths (IPK of
  the poses), where only the three-spheres seed and the residual check run.
* `statics_us`: `controller.core.statics.CableStatics.solve` (the tension distribution farthest
  from the limits, the closed form for four cables) for the built-in robot's 5 kg payload, over
  a fixed set of workspace poses, per pose; `statics_batch_us`: `CableStatics.solve_batch` on
  100,000 such poses (the vectorised form `cablebot workspace` and path checks use), per pose.
  The table also shows the loop's own check (`TensionCheck.check`: the solve and the reason).
* `sim_plant_rtf`: the physical simulator's real-time factor (simulated seconds per CPU
  second) at 1 kHz: four simulated ODrive axes carrying the built-in robot's payload on elastic
  cables (`drivers.odrive.sim.step_axes` with the `ReelPlant` of `[sim] plant = "physical"`,
  plus each axis's broadcast frames, no bus), holding in position control (`position`) and
  pulling in torque control as the pre-tension does (`torque`). 1 is what keeping up takes; the
  margin above it is what a busy host may take away.
* `decode_frames_per_s`: `controller.cli.bench_rx.poll_rate`, the full receive path on one thread:
  python-can Messages on a `virtual` bus -> `cansimple.decode` -> per-axis reading update and
  stamping, 90 % encoder estimates and 10 % heartbeats for 4 axes.
* `loop`: for each rate a fresh process (`python -m controller.cli.bench loop`, daemon-like: it
  imports only what the daemon imports) starts four simulated ODrive nodes in another process (the
  registry's simulated drives built by `controller.service.simulated.sim_bank`, as `cablebot sim`
  does, at SCHED_FIFO one below the loop when permitted: they stand in for hardware, which a busy
  host does not slow down) on a udp_multicast bus of its own (random group and port), builds the
  bus, driver, `Controller` and `ZenohInterface` with the daemon's own `build_stack`, sets the same
  switch interval, GC freeze, timer slack and scheduling, and runs the controller's `Runner` (the
  daemon's loop itself) in a thread (`controller.service.runner.start_loop`). The robot is armed and
  moved back and forth (1 m/s, all four cables changing), so every tick does the full work: poll,
  FPK, planner, limits, IPK, four Set_Input_Pos frames, one pose put (`publish_every` 1). A fault
  (e.g. a simulator starved on a loaded machine) is counted and shown, then reset and re-armed so
  the run goes on. The loop's own jitter and compute rings are read every 0.1 s, so the percentiles
  cover every tick of the measured window (not only the ring's last 4096); `ticks` and `overruns`
  are the loop's counters over the window. Fractions are of the period. The simulated nodes' tick is
  0.993 ms, not 1 ms: a real ODrive's clock is independent of the host's, so its broadcasts arrive
  at any phase of the loop's tick; two 1 ms grids on the same clock would keep one fixed phase for a
  whole run and make the latency (and the tick's work) a draw of that phase. At 0.7 % the phase
  sweeps a whole 1 ms period every 0.14 s, about 70 times in a run. Each loop figure is the median
  over 3 runs per rate (1 with `--quick`), the rates interleaved (500, 1000, 500, ...). Note that
  udp_multicast delivers the daemon's own frames back to it (python-can cannot filter them), so each
  tick also receives its four Set_Input_Pos frames, which SocketCAN would not. `frames_rx_per_tick`
  / `frames_tx_per_tick` are the driver's frame counters over the measured window divided by its
  ticks: received counts every frame on the bus, the loop's own included.
* `loop.cia402.500`: the same run at 500 Hz on four simulated CiA 402 drives (`[drive] kind =
  "cia402"`, nodes 1..4; the daemon configures them by SDO before its loop runs): each tick
  writes two RPDOs per drive and one SYNC, and every drive answers with its TPDO. No end-to-end
  latency here (the encoder-frame matching is the ODrive codec's); one run (`loop_runs` of them).
* `zenoh_put_us`: the median of `ZenohInterface`'s own timing of `publish_pose` (encode +
  put) over the last 4096 ticks of a 1 kHz run, i.e. in the loop, with a subscriber attached.
* `e2e_p50_us` / `e2e_p99_us` (1 kHz runs): the simulated node's process records
  `time.time_ns()` just before `bus.send` of every encoder frame (node, float32 position); a
  Zenoh subscriber in a third process records `time.time_ns()` when each pose arrives. Every
  process is on this host, so CLOCK_REALTIME is shared. Matching is by value, not by time:
  the pose carries `cable_lengths_m`, which the loop computes as `reel.length_m(position_rev)`
  from the decoded float32, so applying the controller's homed reel models to the logged
  positions reproduces those lengths bit for bit (JSON floats round-trip). Whenever a cable's
  length changes from one received pose to the next, a new encoder frame of that node has
  reached a pose; its latency is the pose's arrival minus the send time of the latest frame of
  that node carrying exactly that value sent before the arrival. Assumption: while the robot
  moves, consecutive encoder values of a node differ (at cruise they are hundreds of float32
  steps apart), so "latest frame with that value" is the frame that produced the change; only
  at the very start and end of a move can two frames 2 ms apart repeat a value, and only if the
  second is sent before the pose arrives does it shorten that sample. Frames
  superseded before any tick used them produce no pose and no sample; a pose dropped by Zenoh
  makes the next pose count, as the subscriber saw it.
* `estop_latency_flood_ms` (`reply_p50`/`reply_p99`, `frame_p50`/`frame_p99`): e-stop while a
  hostile client floods the daemon (`bench_estop_flood`). A daemon-like process
  (`python -m controller.cli.bench daemon`: the daemon's `build_stack` and `start_loop`, the paper
  robot at its default rate with in-process simulated nodes, udp_multicast with hop limit 0)
  is armed. A flooding process keeps `ESTOP_FLOOD_THREADS` queries in flight, in turn a path,
  a move, a set-point put and a home each exactly at its verb's byte cap and malformed only at
  its last byte (so all of it is decoded before the refusal), and the original 10 MB move.
  After a second of flood this process arms the robot and sends e-stops, each to the robot
  holding, after a random 30-80 ms pause, then resets and re-arms it. It times each from just
  before the query to the reply, and to the arrival of the Estop frame of the last axis at an
  observer bus on the same channel (in this process; the kernel's receive stamp, so this
  process's scheduling does not count; a try where the observer's socket dropped a frame uses
  the last one heard and is counted). Percentiles are nearest-rank over the
  tries: of 100, p99 is the second worst; of 50 (`--quick`), the worst. The table also shows
  the flood's rate and any fault of the robot (leaving HOLDING by itself).
"""

from __future__ import annotations

import argparse
import bisect
import contextlib
import gc
import itertools
import json
import math
import os
import random
import signal
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from types import FrameType
from typing import IO, Any

# --------------------------------------------------------------------------------------------
# Settings


@dataclass(frozen=True, slots=True)
class Plan:
    """How much to measure: repeats per figure and the loop duration."""

    scalar_repeats: int
    scalar_calls: int
    fpk4_repeats: int
    fpk4_poses: int
    batch_repeats: int
    batch_poses: int
    statics_repeats: int
    statics_poses: int
    statics_batch_poses: int
    sim_seconds: float
    decode_repeats: int
    decode_frames: int
    loop_seconds: float
    loop_runs: int
    estop_tries: int


FULL = Plan(501, 400, 15, 32, 5, 1_000_000, 51, 200, 100_000, 5.0, 5, 50_000, 10.0, 3, 100)
QUICK = Plan(101, 400, 5, 16, 3, 1_000_000, 11, 100, 100_000, 1.0, 3, 20_000, 2.0, 1, 50)

LENGTH_NOISE_M = 1e-3
"""Standard deviation of the noise put on the cable lengths for `fpk4` and the batch."""
LOOP_RATES_HZ = (500, 1000)
CIA402_RATE_HZ = 500
"""The rate of the loop run on simulated CiA 402 drives (13 frames a tick fill 66 % of a
1 Mbit/s bus at 500 Hz; 1 kHz would not fit)."""
E2E_RATE_HZ = 1000
MOVE_SPEED_MPS = 1.0
MOVE_POINTS_M = ((-2.0, -1.0, 2.0), (2.0, 1.0, 3.0))
DRAIN_PERIOD_S = 0.1
SIM_TICK_S = 0.000993
"""The simulated nodes' clock runs 0.7 % fast (see the module docstring: phase sweep)."""
CHILD_START_TIMEOUT_S = 30.0
SEED = 8

TARGET_SIMPLIFIED_OVER_GENERAL = 0.6
TARGET_SIMPLIFIED_US = 2.0
TARGET_SCIPY_OVER_FPK4 = 100.0
TARGET_BATCH_OVER_COPY = 20.0
TARGET_DECODE_FRAMES_PER_S = 20_000.0
TARGET_SIM_RTF = 1.0
TARGET_JITTER_P99_FRAC = 0.10
TARGET_COMPUTE_P99_FRAC = 0.25
TARGET_OVERRUN_FRAC = 0.001
E2E_MARGIN_US = 300.0
TARGET_ESTOP_FLOOD_P99_MS = 50.0
ESTOP_FLOOD_THREADS = 4
"""Queries the flooding client keeps in flight."""

LOOP_KEYS = (
    "ticks",
    "overruns",
    "jitter_p50_frac",
    "jitter_p99_frac",
    "compute_p50_frac",
    "compute_p99_frac",
)
JSON_KEYS = (
    "fpk_simplified_us",
    "fpk_general_us",
    "fpk_simplified_over_general",
    "fpk4_us",
    "scipy_over_fpk4",
    "batch_over_copy",
    "statics_us",
    "statics_batch_us",
    "sim_plant_rtf",
    "decode_frames_per_s",
    "zenoh_put_us",
    "loop",
    "e2e_p50_us",
    "e2e_p99_us",
    "estop_latency_flood_ms",
)
ESTOP_KEYS = ("reply_p50", "reply_p99", "frame_p50", "frame_p99")


class BenchError(RuntimeError):
    """A figure could not be measured (a helper process failed, no samples, ...)."""


# --------------------------------------------------------------------------------------------
# Small helpers


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


# --------------------------------------------------------------------------------------------
# Kinematics figures


def bench_three_spheres(repeats: int, calls: int) -> dict[str, float]:
    """Scalar simplified vs general three-spheres call; microseconds per call and their ratio."""
    from controller.core import kinematics as kin

    anchors = kin.paper_anchors()
    c1, c2, c3 = (tuple(float(v) for v in anchors[i]) for i in range(3))
    geom = kin.Geometry(anchors)
    lengths = kin.ipk(geom, (3.0, -4.0, 2.5))
    r1, r2, r3 = (float(lengths[i]) for i in range(3))
    simplified = kin.three_spheres_equal_height
    general = kin.three_spheres
    a = simplified(c1, c2, c3, r1, r2, r3)
    b = general(c1, c2, c3, r1, r2, r3)
    if math.dist(a, b) > 1e-9:
        raise BenchError(f"simplified {a} and general {b} three-spheres disagree")

    def run_simplified() -> None:
        f = simplified
        for _ in itertools.repeat(None, calls):
            f(c1, c2, c3, r1, r2, r3)

    def run_general() -> None:
        f = general
        for _ in itertools.repeat(None, calls):
            f(c1, c2, c3, r1, r2, r3)

    t = interleaved([run_simplified, run_general], repeats)
    return {
        "fpk_simplified_us": t.cpu(0, calls) / 1e3,
        "fpk_general_us": t.cpu(1, calls) / 1e3,
        "fpk_simplified_over_general": t.ratio(0, 1),
        "fpk_simplified_wall_us": t.wall(0, calls) / 1e3,
        "fpk_general_wall_us": t.wall(1, calls) / 1e3,
    }


def _workspace_poses(cfg: Any, n: int, seed: int) -> Any:
    """`n` random points in the workspace's box (`Workspace.box`), which for the rectangular
    paper robot is the workspace itself.

    Raises BenchError if the box is not inside the workspace (a non-rectangular layout).
    """
    import numpy as np

    from controller.core.workspace import Workspace

    rng = np.random.default_rng(seed)
    ws = Workspace.from_limits(cfg.limits, cfg.geometry)
    (x_lo, x_hi), (y_lo, y_hi), (z_lo, z_hi) = ws.box()
    for x in (x_lo, x_hi):
        for y in (y_lo, y_hi):
            if not ws.contains_xy(x, y):
                raise BenchError("the workspace is not its bounding box (not a rectangle)")
    return np.column_stack(
        [rng.uniform(x_lo, x_hi, n), rng.uniform(y_lo, y_hi, n), rng.uniform(z_lo, z_hi, n)]
    )


def _workspace_centre(cfg: Any) -> tuple[float, float, float]:
    """The anchors' plan-view centroid, half-way up the workspace."""
    from controller.core.workspace import Workspace

    a = cfg.geometry.anchors_m
    _, _, (z_lo, z_hi) = Workspace.from_limits(cfg.limits, cfg.geometry).box()
    return (float(a[:, 0].mean()), float(a[:, 1].mean()), 0.5 * (z_lo + z_hi))


def bench_fpk4(repeats: int, n_poses: int) -> dict[str, float]:
    """`kinematics.fpk` (4 cables, noisy lengths) vs scipy least_squares on the same spheres.

    Returns fpk4_us, scipy_over_fpk4, scipy_us and the largest distance between the two
    solutions (metres). Raises BenchError if scipy did not converge.
    """
    import numpy as np
    from scipy.optimize import least_squares

    from controller.core import kinematics as kin
    from controller.service.config import default_config

    cfg = default_config()
    geom = cfg.geometry
    anchors = np.asarray(geom.anchors_m, dtype=np.float64)
    poses = _workspace_poses(cfg, n_poses, SEED)
    rng = np.random.default_rng(SEED + 1)
    lens = kin.ipk(geom, poses) + rng.normal(0.0, LENGTH_NOISE_M, (n_poses, geom.n_cables))
    rows = [[float(v) for v in row] for row in lens]
    x0 = np.array(_workspace_centre(cfg))

    def residuals(p: Any, lengths: Any) -> Any:
        return np.sqrt(((p - anchors) ** 2).sum(axis=1)) - lengths

    def jacobian(p: Any, lengths: Any) -> Any:
        d = p - anchors
        return d / np.sqrt((d * d).sum(axis=1))[:, None]

    fpk = kin.fpk
    worst = 0.0
    for row, ln in zip(rows, lens, strict=True):
        r = least_squares(residuals, x0, jac=jacobian, args=(ln,))
        if not r.success:
            raise BenchError(f"scipy least_squares did not converge: {r.message}")
        worst = max(worst, math.dist(fpk(geom, row).position_m, tuple(r.x)))

    def run_fpk() -> None:
        for row in rows:
            fpk(geom, row)

    def run_scipy() -> None:
        for ln in lens:
            least_squares(residuals, x0, jac=jacobian, args=(ln,))

    def run_scipy_default() -> None:
        for ln in lens:
            least_squares(residuals, x0, args=(ln,))

    t = interleaved([run_fpk, run_scipy, run_scipy_default], repeats)
    return {
        "scipy_default_over_fpk4": t.ratio(2, 0),
        "fpk4_us": t.cpu(0, n_poses) / 1e3,
        "scipy_us": t.cpu(1, n_poses) / 1e3,
        "scipy_over_fpk4": t.ratio(1, 0),
        "fpk4_wall_us": t.wall(0, n_poses) / 1e3,
        "scipy_wall_us": t.wall(1, n_poses) / 1e3,
        "fpk4_vs_scipy_m": worst,
    }


def bench_batch(repeats: int, n_poses: int) -> dict[str, float]:
    """`kinematics.fpk_batch` over `np.copy` of its input: noisy and consistent lengths."""
    import numpy as np

    from controller.core import kinematics as kin
    from controller.service.config import default_config

    cfg = default_config()
    geom = cfg.geometry
    poses = _workspace_poses(cfg, n_poses, SEED + 2)
    exact = kin.ipk(geom, poses)
    rng = np.random.default_rng(SEED + 3)
    noisy = exact + rng.normal(0.0, LENGTH_NOISE_M, exact.shape)
    out: dict[str, float] = {}
    for name, lens in (("batch_over_copy", noisy), ("batch_over_copy_consistent", exact)):
        res = kin.fpk_batch(geom, lens)
        if not bool(res.valid.all()):
            raise BenchError(f"fpk_batch marked {int((~res.valid).sum())} workspace rows invalid")
        del res  # that run was the batch's warm-up
        np.copy(lens)

        def run_copy(lens: Any = lens) -> None:
            np.copy(lens)

        def run_batch(lens: Any = lens) -> None:
            kin.fpk_batch(geom, lens)

        t = interleaved([run_copy, run_batch], repeats, warm_up=False)
        out[name] = t.ratio(1, 0)
        out[name + "_s"] = t.cpu(1) / 1e9
        out[name + "_copy_s"] = t.cpu(0) / 1e9
        out[name + "_wall_s"] = t.wall(1) / 1e9
    return out


def bench_statics(repeats: int, n_poses: int, batch_poses: int) -> dict[str, float]:
    """Cable tensions for the built-in robot's payload: one pose (solve, and the loop's check)
    and a batch, in microseconds per pose."""
    from controller.core.statics import CableStatics, TensionCheck
    from controller.service.config import default_config

    cfg = default_config()
    assert cfg.payload is not None and cfg.tension is not None
    mass = cfg.payload.mass_kg
    ten = cfg.tension
    statics = CableStatics(cfg.anchors_m, ten.min_n, ten.max_n)
    check = TensionCheck(cfg.anchors_m, mass, ten.min_n, ten.max_n, ten.margin_n)
    poses = [tuple(p) for p in _workspace_poses(cfg, n_poses, SEED + 5).tolist()]
    batch = _workspace_poses(cfg, batch_poses, SEED + 6)
    solve = statics.solve
    checked = check.check

    def run_solve() -> None:
        for p in poses:
            solve(p, mass)

    def run_check() -> None:
        for p in poses:
            checked(p)

    def run_batch() -> None:
        statics.solve_batch(batch, mass)

    t = interleaved([run_solve, run_check], repeats)
    b = interleaved([run_batch], max(3, repeats // 5))
    return {
        "statics_us": t.cpu(0, n_poses) / 1e3,
        "statics_wall_us": t.wall(0, n_poses) / 1e3,
        "statics_check_us": t.cpu(1, n_poses) / 1e3,
        "statics_batch_us": b.cpu(0, batch_poses) / 1e3,
        "statics_batch_wall_us": b.wall(0, batch_poses) / 1e3,
    }


def bench_sim_plant(seconds: float) -> dict[str, float]:
    """Real-time factor of four simulated ODrives carrying the built-in robot's payload at
    1 kHz (module docstring), holding in position control and pulling in torque control."""
    from controller.service.config import default_config, tension_check
    from controller.service.simulated import initial_turns, sim_plant
    from drivers.odrive import cansimple as cs
    from drivers.odrive.sim import SimODriveAxis, step_axes

    cfg = replace(default_config(), sim=replace(default_config().sim, plant="physical"))
    assert cfg.payload is not None and cfg.tension is not None
    assert cfg.homing.power_up_position_m is not None
    turns = initial_turns(cfg)
    pose = tuple(float(v) for v in cfg.homing.power_up_position_m)
    tensions = tension_check(cfg.payload, cfg.tension, cfg.geometry).solve(pose).tensions_n
    dt = 0.001
    ticks = max(1, round(seconds / dt))
    out: dict[str, float] = {}
    for mode in ("position", "torque"):
        plant = sim_plant(cfg, turns)
        axes = [
            SimODriveAxis(n, initial_position_rev=t)
            for n, t in zip(cfg.node_ids, turns, strict=True)
        ]
        for a, r, t, n in zip(axes, cfg.reels, turns, tensions, strict=True):
            a.coupled = True
            if mode == "torque":
                a.handle(cs.SetInputTorque(a.node_id, r.reel.torque_nm(t, n)))
                a.handle(cs.SetControllerMode(a.node_id, cs.ControlMode.TORQUE_CONTROL, 1))
            a.handle(cs.SetAxisState(a.node_id, cs.AxisState.CLOSED_LOOP_CONTROL))

        def run(axes: list[SimODriveAxis] = axes, plant: Any = plant) -> None:
            for _ in range(ticks):
                step_axes(axes, plant, dt)
                for a in axes:
                    a.broadcasts(dt)

        timed = interleaved([run], 1, warm_up=False)
        out[mode] = ticks * dt / (timed.cpu(0) / 1e9)
        out[f"{mode}_tick_us"] = timed.cpu(0, ticks) / 1e3
    return out


def bench_decode(repeats: int, frames: int) -> dict[str, float]:
    """Frames per second through the driver's full receive path (`controller.cli.bench_rx`)."""
    from controller.cli.bench_rx import poll_rate

    poll_rate(min(frames, 5000))  # warm-up
    rates = [poll_rate(frames) for _ in range(repeats)]
    return {"decode_frames_per_s": _median(rates)}


# --------------------------------------------------------------------------------------------
# Loop benchmark: helper processes


class _Child:
    """A helper process whose stdout/stderr lines are collected by reader threads."""

    def __init__(self, args: Sequence[str], name: str) -> None:
        env = dict(os.environ)
        env["PYTHONUNBUFFERED"] = "1"
        env.pop("NOTIFY_SOCKET", None)
        self.name = name
        self.proc = subprocess.Popen(
            list(args), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self.out: list[str] = []
        self.err: list[str] = []
        for stream, sink in ((self.proc.stdout, self.out), (self.proc.stderr, self.err)):
            threading.Thread(target=self._read, args=(stream, sink), daemon=True).start()

    @staticmethod
    def _read(stream: IO[str] | None, sink: list[str]) -> None:
        if stream is None:
            return
        for line in stream:
            sink.append(line.rstrip("\n"))

    def wait_line(self, needle: str, timeout_s: float) -> None:
        """Wait for a stdout line containing `needle`; BenchError on timeout or exit."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if any(needle in line for line in list(self.out)):
                return
            if self.proc.poll() is not None:
                break
            time.sleep(0.02)
        raise BenchError(f"{self.name}: no {needle!r} line\n{self.tail()}")

    def tail(self) -> str:
        """The last lines of output, for error messages."""
        return f"--- {self.name} rc={self.proc.poll()}\n" + "\n".join(
            self.out[-10:] + self.err[-30:]
        )

    def stop(self, timeout_s: float = 10.0) -> int | None:
        """SIGTERM, wait (bounded), SIGKILL if needed; returns the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        return self.proc.returncode


def _helper(role: str, *args: str) -> list[str]:
    return [sys.executable, "-m", "controller.cli.bench", role, *args]


def _on_term(stop: threading.Event) -> None:
    def handler(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)


def _load_cfg(path: str) -> Any:
    from controller.service.config import parse_config

    with open(path, encoding="utf-8") as f:
        return parse_config(json.load(f), path)


class _RecordingBus:
    """Wraps a python-can bus; stamps `time.time_ns()` just before sending each ODrive encoder
    frame (with `record`)."""

    def __init__(self, bus: Any, *, record: bool = True) -> None:
        from drivers.odrive import cansimple as cs

        self.bus = bus
        self._encoder_cmd = cs.GET_ENCODER_ESTIMATES if record else -1
        self.sent: list[tuple[int, int, bytes]] = []

    def recv(self, timeout: float | None = None) -> Any:
        return self.bus.recv(timeout=timeout)

    def send(self, msg: Any, timeout: float | None = None) -> None:
        if (msg.arbitration_id & 0x1F) == self._encoder_cmd and not msg.is_remote_frame:
            t_ns = time.time_ns()
            self.bus.send(msg, timeout=timeout)
            self.sent.append((t_ns, msg.arbitration_id, bytes(msg.data)))
        else:
            self.bus.send(msg, timeout=timeout)


def role_sim(config: str, log: str, tick_s: float) -> int:
    """Helper process: the config's simulated drives (as `cablebot sim`), logging encoder sends
    (ODrive frames; none for other families)."""
    import dataclasses

    from controller.service.runner import RT_PRIORITY, set_realtime
    from controller.service.simulated import sim_settings
    from drivers import registry
    from drivers.bus import open_bus

    cfg = _load_cfg(config)
    stop = threading.Event()
    _on_term(stop)
    b = cfg.bus
    bus = open_bus(b.interface, b.channel, b.bitrate, **dict(b.options))
    rec = _RecordingBus(bus, record=cfg.drive.kind == "odrive")
    try:
        settings = dataclasses.replace(sim_settings(cfg), tick_s=tick_s)
        fam = registry.family(cfg.drive.kind)
        bank = fam.sim_bank(rec, cfg.node_ids, cfg.drive.options, settings)  # type: ignore[arg-type]
        bank.start()
        # The drives stand in for hardware, which a busy host does not slow down: like the
        # daemon's in-process simulator, run one priority below the loop when permitted.
        sched = "SCHED_OTHER"
        thread = bank.thread
        if thread is not None and thread.native_id is not None:
            prio = max(1, int(getattr(cfg.loop, "rt_priority", RT_PRIORITY)) - 1)
            sched = set_realtime(prio, thread.native_id)
        try:
            print(f"READY {sched}", flush=True)
            stop.wait()
        finally:
            bank.stop()
    finally:
        bus.shutdown()
        with open(log, "w", encoding="utf-8") as f:
            json.dump([[t, a, d.hex()] for t, a, d in rec.sent], f)
    return 0


def role_sub(endpoint: str, key: str, out: str) -> int:
    """Helper process: a Zenoh client subscriber stamping each sample's arrival."""
    import zenoh

    from controller.service.zenoh_io import client_config

    stop = threading.Event()
    _on_term(stop)
    deadline = time.monotonic() + CHILD_START_TIMEOUT_S
    while True:
        try:
            session = zenoh.open(client_config([endpoint]))
            break
        except Exception:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)
    got: list[tuple[int, bytes]] = []
    first = threading.Event()

    def on_sample(sample: Any) -> None:
        got.append((time.time_ns(), sample.payload.to_bytes()))
        if not first.is_set():
            first.set()
            print("FIRST", flush=True)

    sub = session.declare_subscriber(key, on_sample)
    print("READY", flush=True)
    stop.wait()
    with contextlib.suppress(Exception):
        sub.undeclare()  # type: ignore[no-untyped-call]
    with contextlib.suppress(Exception):
        session.close()  # type: ignore[no-untyped-call]
    with open(out, "w", encoding="utf-8") as f:
        json.dump([[t, p.decode()] for t, p in list(got)], f)
    return 0


# --------------------------------------------------------------------------------------------
# Loop benchmark: the daemon-like process


CIA402_COUNTS_PER_REV = 131072.0
"""The simulated CiA 402 drives' scaling in the loop bench (a 17-bit encoder)."""


def loop_config_data(rate_hz: float, zenoh_port: int, kind: str = "odrive") -> dict[str, Any]:
    """The paper robot on its own udp_multicast bus and Zenoh port, loop at `rate_hz`, on
    drives of family `kind` ("odrive", node ids 0..3, or "cia402", node ids 1..4)."""
    from controller.service.config import paper_robot_data

    name = f"bench-{os.getpid()}-{random.randrange(1 << 16):04x}"
    data = paper_robot_data(name)
    if kind == "cia402":
        data["drive"] = {"kind": "cia402", "counts_per_rev": CIA402_COUNTS_PER_REV}
        for i, reel in enumerate(data["reels"]):
            reel["node_id"] = i + 1
    data["bus"] = {
        "interface": "udp_multicast",
        "channel": f"239.74.{random.randint(1, 254)}.{random.randint(1, 254)}",
        "options": {"port": random.randint(20000, 60000)},
    }
    data["loop"] = {
        "rate_hz": float(rate_hz),
        "realtime": True,
        "gc_freeze": True,
        "publish_every": 1,
        "encoder_rtr": False,
    }
    data["sim"] = {"enabled": False}
    data["zenoh"] = {
        "prefix": f"cablebot/{name}",
        "mode": "peer",
        "listen": [f"tcp/127.0.0.1:{zenoh_port}"],
        "multicast_scouting": False,
    }
    return data


class _RingReader:
    """Copies new values out of a loop statistics ring (`controller.service.runner.LoopStats`)."""

    def __init__(self, ring: Any) -> None:
        self.ring = ring
        self.last = int(ring.count)
        self.values: list[float] = []
        self.lost = 0

    def drain(self, keep: bool = True) -> None:
        count = int(self.ring.count)
        size = int(self.ring.size)
        start = max(self.last, count - size + 1)  # index count-size may be being overwritten
        if keep:
            self.lost += start - self.last
            buf = self.ring.buf
            self.values.extend(buf[i % size] for i in range(start, count))
        self.last = count


def loop_once(
    rate_hz: float, seconds: float, workdir: Path, kind: str = "odrive"
) -> dict[str, Any]:
    """Run the daemon's loop at `rate_hz` for `seconds` against simulated drives of family
    `kind`; its figures (the end-to-end ones None for other families than "odrive").

    Raises BenchError when a helper fails, the robot cannot be armed or faults, or (ODrive)
    no end-to-end sample was matched.
    """
    from controller.core.commands import Arm, Move, Reset
    from controller.core.states import State
    from controller.service.daemon import Stack, build_stack
    from controller.service.runner import start_loop
    from controller.service.zenoh_io import free_tcp_port  # Zenoh only when used

    zport = free_tcp_port()
    data = loop_config_data(rate_hz, zport, kind)
    cfg_path = workdir / f"loop-{int(rate_hz)}.json"
    cfg_path.write_text(json.dumps(data))
    cfg = _load_cfg(str(cfg_path))
    sim_log = workdir / f"sim-{int(rate_hz)}.json"
    sub_log = workdir / f"sub-{int(rate_hz)}.json"
    period_s = 1.0 / float(rate_hz)
    children: list[_Child] = []
    stack: Stack | None = None
    stop_loop = threading.Event()
    thread: threading.Thread | None = None
    try:
        sim = _Child(
            _helper(
                "sim", "--config", str(cfg_path), "--log", str(sim_log), "--tick-s", str(SIM_TICK_S)
            ),
            "sim",
        )
        children.append(sim)
        sim.wait_line("READY", CHILD_START_TIMEOUT_S)
        sim_sched = next((ln[6:] for ln in sim.out if ln.startswith("READY ")), "")

        # The daemon's own builder and loop thread (bus, driver, Controller, Zenoh; SCHED_FIFO,
        # timer slack, switch interval, gc freeze).
        stack = build_stack(cfg)
        controller, driver, iface = stack.controller, stack.driver, stack.zenoh
        assert iface is not None  # build_stack(zenoh=True) raises rather than give None
        thread, rt_report = start_loop(controller.runner(), cfg.loop, stop_loop)

        endpoint = f"tcp/127.0.0.1:{zport}"
        sub = _Child(
            _helper(
                "sub", "--connect", endpoint, "--key", f"{iface.prefix}/pose", "--out", str(sub_log)
            ),
            "subscriber",
        )
        children.append(sub)
        sub.wait_line("FIRST", CHILD_START_TIMEOUT_S)

        _arm_and_hold(controller, float(cfg.faults.arm_timeout_s) + 3.0)

        loop_stats = controller.loop_stats
        jitter = _RingReader(loop_stats.jitter)
        compute = _RingReader(loop_stats.compute)
        moves = 0
        faults: list[str] = []
        controller.submit(Move(MOVE_POINTS_M[0], MOVE_SPEED_MPS))
        moves += 1
        t0_ns = time.time_ns()
        ticks0, overruns0, skipped0 = controller.ticks, loop_stats.overruns, loop_stats.skipped
        bus0 = driver.stats.snapshot()
        jitter.drain(keep=False)
        compute.drain(keep=False)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            time.sleep(DRAIN_PERIOD_S)
            jitter.drain()
            compute.drain()
            state = _state_of(controller)
            if state is State.FAULT:
                # Counted and reported; reset and re-arm so the run goes on.
                faults.append(str(controller.reason))
                controller.submit(Reset())
            elif state is State.DISARMED:
                controller.submit(Arm())
            elif state is State.HOLDING:
                controller.submit(Move(MOVE_POINTS_M[moves % 2], MOVE_SPEED_MPS))
                moves += 1
        ticks = controller.ticks - ticks0
        overruns = loop_stats.overruns - overruns0
        skipped = loop_stats.skipped - skipped0
        bus1 = driver.stats.snapshot()
        jitter.drain()
        compute.drain()
        t1_ns = time.time_ns()
        zstats = iface.stats()
        bus_stats = driver.stats.snapshot()
        reels = list(controller.reels)
        node_ids = controller.node_ids

        sub.stop()
        stop_loop.set()
        thread.join(2.0)
    finally:
        stop_loop.set()
        for c in reversed(children):
            c.stop()
        if stack is not None:
            stack.close()

    if not jitter.values or not compute.values:
        raise BenchError("no loop statistics were collected")
    sent = json.loads(sim_log.read_text())
    poses = json.loads(sub_log.read_text())
    e2e = match_e2e(sent, poses, reels, node_ids, t0_ns, t1_ns)
    if kind == "odrive" and not e2e["total_us"]:
        raise BenchError(f"no end-to-end sample matched ({e2e['unmatched']} unmatched changes)")

    pct = _percentile_or_none
    put = zstats["pose_publish_tick"]
    return {
        "rate_hz": float(rate_hz),
        "seconds": (t1_ns - t0_ns) / 1e9,
        "ticks": ticks,
        "overruns": overruns,
        "overrun_frac": overruns / max(ticks, 1),
        "skipped": skipped,
        "jitter_p50_frac": percentile(jitter.values, 0.50) / period_s,
        "jitter_p99_frac": percentile(jitter.values, 0.99) / period_s,
        "compute_p50_frac": percentile(compute.values, 0.50) / period_s,
        "compute_p99_frac": percentile(compute.values, 0.99) / period_s,
        "stat_samples": len(compute.values),
        "stat_lost": jitter.lost + compute.lost,
        "zenoh_put_us": put["p50_us"],
        "zenoh_put_p99_us": put["p99_us"],
        "zenoh_put_n": min(int(zstats["poses_published"]), 4096),
        "e2e_p50_us": pct(e2e["total_us"], 0.50),
        "e2e_p99_us": pct(e2e["total_us"], 0.99),
        "e2e_n": len(e2e["total_us"]),
        "e2e_unmatched": e2e["unmatched"],
        "send_to_publish_p50_us": pct(e2e["to_publish_us"], 0.50),
        "send_to_publish_p99_us": pct(e2e["to_publish_us"], 0.99),
        "publish_to_arrival_p50_us": pct(e2e["after_publish_us"], 0.50),
        "publish_to_arrival_p99_us": pct(e2e["after_publish_us"], 0.99),
        "moves": moves,
        "faults": len(faults),
        "fault_reasons": sorted(set(faults))[:5],
        "frames_rx": bus_stats.frames_rx,
        "frames_rx_per_tick": (bus1.frames_rx - bus0.frames_rx) / max(ticks, 1),
        "frames_tx_per_tick": (bus1.frames_tx - bus0.frames_tx) / max(ticks, 1),
        "kind": kind,
        "scheduling": "; ".join(rt_report),
        "sim_scheduling": sim_sched,
    }


def _arm_and_hold(controller: Any, timeout_s: float) -> None:
    """Arm the robot and wait until it holds. Raises BenchError if it faults or `timeout_s`
    passes first."""
    from controller.core.commands import Arm
    from controller.core.states import State

    controller.submit(Arm())
    deadline = time.monotonic() + timeout_s
    while controller.state is not State.HOLDING:
        if time.monotonic() > deadline or controller.state is State.FAULT:
            raise BenchError(f"arming failed: {controller.state.value} {controller.reason}")
        time.sleep(0.01)


def _percentile_or_none(values: Sequence[float], q: float) -> float | None:
    return percentile(values, q) if values else None


def _state_of(controller: Any) -> Any:
    """The controller's state, read afresh (another thread changes it)."""
    return controller.state


def match_e2e(
    sent: Sequence[Sequence[Any]],
    poses: Sequence[Sequence[Any]],
    reels: Sequence[Any],
    node_ids: Sequence[int],
    t0_ns: int,
    t1_ns: int,
) -> dict[str, Any]:
    """Relate pose arrivals to encoder-frame sends by value (see the module docstring).

    `sent`: (send_ns, arbitration id, data hex) per encoder frame; `poses`: (arrival_ns, JSON)
    in arrival order; `reels`: the controller's homed reel models in cable order. Only frames
    sent within [t0_ns, t1_ns] count. Returns lists of microseconds (`total_us`, `to_publish_us`
    = frame send to the daemon's publish stamp, `after_publish_us`) and the `unmatched` count.
    """
    cable_of = {n: i for i, n in enumerate(node_ids)}
    sends: list[dict[float, list[int]]] = [{} for _ in node_ids]
    for t_ns, arb, data_hex in sent:
        i = cable_of.get(int(arb) >> 5)
        if i is None:
            continue
        (pos,) = struct.unpack_from("<f", bytes.fromhex(data_hex))
        sends[i].setdefault(reels[i].length_m(pos), []).append(int(t_ns))
    for table in sends:
        for times in table.values():
            times.sort()
    total: list[float] = []
    to_pub: list[float] = []
    after_pub: list[float] = []
    unmatched = 0
    prev: list[float | None] = [None] * len(node_ids)
    for t_arr, payload in poses:
        d = json.loads(payload)
        lengths = d.get("cable_lengths_m") or []
        for i, v in enumerate(lengths[: len(node_ids)]):
            if v is None:
                prev[i] = None
                continue
            changed = prev[i] is not None and v != prev[i]
            prev[i] = v
            if not changed:
                continue
            times = sends[i].get(float(v), [])
            k = bisect.bisect_right(times, int(t_arr)) - 1
            if k < 0:
                unmatched += 1
                continue
            t_send = times[k]
            if not t0_ns <= t_send <= t1_ns:
                continue
            total.append((int(t_arr) - t_send) / 1e3)
            to_pub.append((int(d["stamp_ns"]) - t_send) / 1e3)
            after_pub.append((int(t_arr) - int(d["stamp_ns"])) / 1e3)
    return {
        "total_us": total,
        "to_publish_us": to_pub,
        "after_publish_us": after_pub,
        "unmatched": unmatched,
    }


_SUMMED = ("faults", "e2e_n", "e2e_unmatched", "stat_samples", "stat_lost", "moves", "frames_rx")


def merge_runs(runs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """One figure set from several `loop_once` results: the median of each number (counts in
    `_SUMMED` are summed, fault reasons joined); `runs` says how many. Raises ValueError on
    no runs."""
    if not runs:
        raise ValueError("no loop runs to merge")
    out: dict[str, Any] = {"runs": len(runs)}
    for key, first in runs[0].items():
        values = [r[key] for r in runs]
        if key in _SUMMED:
            out[key] = sum(values)
        elif key == "fault_reasons":
            out[key] = sorted({x for v in values for x in v})[:5]
        elif isinstance(first, bool) or not isinstance(first, int | float):
            out[key] = first
        elif isinstance(first, int):
            out[key] = int(statistics.median_low(values))
        else:
            out[key] = _median(values)
    return out


def role_loop(rate_hz: float, seconds: float, out: str, kind: str = "odrive") -> int:
    """Helper process: `loop_once` in a fresh, daemon-like process; writes its figures as JSON."""
    with tempfile.TemporaryDirectory(prefix="cablebot-bench-") as tmp:
        try:
            result: dict[str, Any] = loop_once(rate_hz, seconds, Path(tmp), kind)
        except BenchError as exc:
            result = {"error": str(exc)}
    Path(out).write_text(json.dumps(result))
    return 0


def bench_loop(rate_hz: int, seconds: float, kind: str = "odrive") -> dict[str, Any]:
    """Run `loop_once` in its own process (`python -m controller.cli.bench loop`) on drives of
    family `kind`; its figures.

    Raises BenchError when that process fails or reports an error.
    """
    with tempfile.TemporaryDirectory(prefix="cablebot-bench-") as tmp:
        out = Path(tmp) / "loop.json"
        args = _helper(
            "loop",
            "--rate-hz",
            str(rate_hz),
            "--seconds",
            str(seconds),
            "--out",
            str(out),
            "--drive",
            kind,
        )
        try:
            proc = subprocess.run(
                args, capture_output=True, text=True, timeout=seconds + 90.0, check=False
            )
        except subprocess.TimeoutExpired as exc:
            raise BenchError(f"loop bench at {rate_hz} Hz timed out") from exc
        if proc.returncode != 0 or not out.exists():
            raise BenchError(
                f"loop bench at {rate_hz} Hz failed (rc {proc.returncode}):\n{proc.stderr[-3000:]}"
            )
        result: dict[str, Any] = json.loads(out.read_text())
    if "error" in result:
        raise BenchError(f"loop bench at {rate_hz} Hz: {result['error']}")
    return result


# --------------------------------------------------------------------------------------------
# E-stop under a flood of hostile commands


def flood_payloads() -> list[tuple[str, bytes]]:
    """What the flooding client sends, in turn: `(verb, payload)`, "setpoint" meaning a put.

    Each payload but the last is exactly its verb's byte cap (`commands.MAX_PAYLOAD_BYTES`),
    passes the size and nesting checks, and is malformed only at its very end, so the daemon
    decodes every byte before refusing it: the most GIL a single accepted message can take.
    The last is the original attack, 10 MB (2.6 million numbers), refused by its size unread.
    """
    from controller.core.commands import MAX_PAYLOAD_BYTES

    def at_cap(verb: str, head: bytes, item: bytes) -> bytes:
        cap = MAX_PAYLOAD_BYTES[verb]
        body = head + item * ((cap - len(head)) // len(item))
        return body + b" " * (cap - len(body))  # unclosed: malformed at the last byte

    return [
        ("path", at_cap("path", b'{"points_m": [', b"[1.25, -2.5, 3.75], ")),
        ("move", at_cap("move", b'{"position_m": [', b"1.2345678, ")),
        ("path", at_cap("path", b'{"points_m": [', b"[], ")),
        ("setpoint", at_cap("setpoint", b'{"position_m": [', b"1.2345678, ")),
        ("home", at_cap("home", b'{"position_m": [', b"7, ")),
        ("move", b'{"position_m": [' + b"1.0, " * 2_600_000 + b"1.0]}"),
    ]


def role_flood(endpoint: str, prefix: str, threads: int) -> int:
    """Helper process: `threads` clients sending `flood_payloads()` back to back (each waits for
    its reply, so `threads` queries are in flight), until SIGTERM; prints how many it sent."""
    import zenoh

    from controller.service.zenoh_io import client_config

    stop = threading.Event()
    _on_term(stop)
    deadline = time.monotonic() + CHILD_START_TIMEOUT_S
    while True:
        try:
            session = zenoh.open(client_config([endpoint]))
            break
        except Exception:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)
    payloads = flood_payloads()
    sent = [0] * threads
    started = threading.Event()

    def worker(k: int) -> None:
        i = k
        while not stop.is_set():
            verb, data = payloads[i % len(payloads)]
            i += 1
            if verb == "setpoint":
                session.put(f"{prefix}/setpoint", data)
            else:
                for _ in session.get(f"{prefix}/cmd/{verb}", payload=data, timeout=10.0):
                    pass
            sent[k] += 1
            started.set()

    workers = [threading.Thread(target=worker, args=(k,), daemon=True) for k in range(threads)]
    for w in workers:
        w.start()
    if started.wait(CHILD_START_TIMEOUT_S):
        print("FLOODING", flush=True)
    stop.wait()
    for w in workers:
        w.join(15.0)
    print(f"SENT {sum(sent)}", flush=True)
    with contextlib.suppress(Exception):
        session.close()  # type: ignore[no-untyped-call]
    return 0


def role_daemon(config: str) -> int:
    """Helper process: the daemon's own stack (`build_stack`, `start_loop`: bus, in-process
    simulated nodes, Controller, Zenoh) on `config`, armed as the daemon arms, until SIGTERM."""
    from controller.core.commands import Arm
    from controller.core.states import State
    from controller.service.daemon import build_stack
    from controller.service.runner import start_loop

    cfg = _load_cfg(config)
    stop = threading.Event()
    _on_term(stop)
    stack = build_stack(cfg)
    stop_loop = threading.Event()
    thread: threading.Thread | None = None
    try:
        thread, report = start_loop(stack.controller.runner(), cfg.loop, stop_loop)
        controller = stack.controller
        controller.submit(Arm())
        deadline = time.monotonic() + float(cfg.faults.arm_timeout_s) + 3.0
        while _state_of(controller) is not State.HOLDING:
            if time.monotonic() > deadline:
                print(f"ARM FAILED {controller.state.value} {controller.reason}", flush=True)
                return 1
            time.sleep(0.01)
        print(f"READY {'; '.join(report)}", flush=True)
        stop.wait()
    finally:
        stop_loop.set()
        if thread is not None:
            thread.join(2.0)
        stack.close()
    return 0


def estop_config_data(zenoh_port: int) -> dict[str, Any]:
    """The paper robot as `cablebot run` would run it with `[sim] enabled` (in-process simulated
    nodes, loop at its default rate), on its own udp_multicast bus (random group and port,
    hop limit 0: nothing leaves the host) and Zenoh port."""
    from controller.service.config import paper_robot_data

    name = f"estop-{os.getpid()}-{random.randrange(1 << 16):04x}"
    data = paper_robot_data(name)
    data["bus"] = {
        "interface": "udp_multicast",
        "channel": f"239.74.{random.randint(1, 254)}.{random.randint(1, 254)}",
        "options": {"port": random.randint(20000, 60000), "hop_limit": 0},
    }
    data["sim"] = {"enabled": True}
    data["zenoh"] = {
        "prefix": f"cablebot/{name}",
        "mode": "peer",
        "listen": [f"tcp/127.0.0.1:{zenoh_port}"],
        "multicast_scouting": False,
    }
    return data


class _EstopWatch:
    """An observer on the robot's bus: the kernel's arrival stamp (wall clock, SO_TIMESTAMPNS,
    so this process's own scheduling does not count) of every Estop frame it hears."""

    RCVBUF_BYTES = 4 << 20
    """The observer's socket buffer: a busy bus must not overflow it while this process waits
    for a CPU (the kernel caps it at net.core.rmem_max)."""

    def __init__(self, bus_cfg: dict[str, Any]) -> None:
        from drivers.bus import open_bus
        from drivers.odrive import cansimple as cs

        self._estop = cs.ESTOP
        self.bus = open_bus(bus_cfg)
        with contextlib.suppress(AttributeError, OSError):  # python-can's own socket
            sock = self.bus._multicast._socket  # type: ignore[attr-defined]
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.RCVBUF_BYTES)
        self.frames: list[tuple[float, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="estop-watch", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(timeout=0.05)
            if msg is not None and (msg.arbitration_id & 0x1F) == self._estop:
                self.frames.append((float(msg.timestamp), msg.arbitration_id >> 5))

    def heard(self, start: int, t0: float, nodes: set[int], timeout_s: float) -> tuple[float, int]:
        """Wait until every node in `nodes` has an Estop frame stamped after `t0` (wall clock;
        frames from index `start` on), at most `timeout_s`. Returns the stamp of the last of
        them (of the last heard, if not all were) and how many nodes were heard."""
        deadline = time.monotonic() + timeout_s
        while True:
            seen: dict[int, float] = {}
            for t, node in self.frames[start:]:
                if t >= t0 and node in nodes:
                    seen.setdefault(node, t)
            if len(seen) == len(nodes) or time.monotonic() > deadline:
                return (max(seen.values()) if seen else math.nan), len(seen)
            time.sleep(0.002)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1.0)
        self.bus.shutdown()


def bench_estop_flood(tries: int, flood_threads: int = ESTOP_FLOOD_THREADS) -> dict[str, Any]:
    """E-stop latency while another process floods the daemon with hostile commands.

    A daemon-like process (`role_daemon`: the daemon's own stack with in-process simulated
    nodes) is armed; a second process (`role_flood`) keeps `flood_threads` queries of
    `flood_payloads()` in flight; this process, after a second of flood, sends `tries` e-stops
    to the robot holding (`_hold` resets and re-arms it after each), each after a random
    30-80 ms pause, and measures for each the time to the e-stop's reply and the time until an
    observer on the same bus has heard an Estop frame for every axis (`_EstopWatch`; tries
    where it heard only some count in `frames_missed`). Returns milliseconds
    (`reply_p50`/`reply_p99`, `frame_p50`/`frame_p99`, nearest-rank; `reply_max`, `frame_max`;
    every try's in `reply_ms` and `frame_ms`),
    `tries`, the flood's query count and rate, the faults the robot showed and the loop
    thread's scheduling.
    Raises BenchError when a helper fails, an e-stop gets no reply, or the observer heard no
    Estop frame at all in more than a tenth of the tries.
    """
    import zenoh

    from controller.service.zenoh_io import client_config

    rng = random.Random(SEED)
    with tempfile.TemporaryDirectory(prefix="cablebot-bench-") as tmp:
        from controller.service.zenoh_io import free_tcp_port  # Zenoh only when used

        zport = free_tcp_port()
        data = estop_config_data(zport)
        cfg_path = Path(tmp) / "estop.json"
        cfg_path.write_text(json.dumps(data))
        cfg = _load_cfg(str(cfg_path))
        prefix = str(cfg.zenoh.prefix)
        endpoint = f"tcp/127.0.0.1:{zport}"
        nodes = {int(r.node_id) for r in cfg.reels}
        children: list[_Child] = []
        watch: _EstopWatch | None = None
        session: Any = None
        reply_ms: list[float] = []
        frame_ms: list[float] = []
        faults: list[str] = []
        missed = 0
        try:
            watch = _EstopWatch(cfg.bus.as_mapping())
            daemon = _Child(_helper("daemon", "--config", str(cfg_path)), "daemon")
            children.append(daemon)
            daemon.wait_line("READY", CHILD_START_TIMEOUT_S)
            sched = next((ln[6:] for ln in daemon.out if ln.startswith("READY ")), "")
            session = zenoh.open(client_config([endpoint]))
            flood = _Child(
                _helper(
                    "flood", "--connect", endpoint, "--prefix", prefix,
                    "--threads", str(flood_threads),
                ),
                "flood",
            )  # fmt: skip
            children.append(flood)
            flood.wait_line("FLOODING", CHILD_START_TIMEOUT_S)
            time.sleep(1.0)
            t_flood0 = time.monotonic()
            _hold(session, prefix, faults)
            for _ in range(tries):
                time.sleep(rng.uniform(0.03, 0.08))
                st = _query_json(session, f"{prefix}/status")
                if st.get("state") != "HOLDING":  # it left HOLDING by itself: a fault
                    faults.append(f"{st.get('state')}: {st.get('reason')}")
                start = len(watch.frames)
                t0_wall = time.time()
                t0 = time.monotonic()
                replies = list(session.get(f"{prefix}/cmd/estop", timeout=5.0))
                t1 = time.monotonic()
                if len(replies) != 1 or replies[0].ok is None:
                    raise BenchError(f"e-stop got no reply ({len(replies)})\n{daemon.tail()}")
                reply_ms.append((t1 - t0) * 1e3)
                t_frames, n_heard = watch.heard(start, t0_wall, nodes, 2.0)
                if n_heard < len(nodes):
                    missed += 1  # the observer's socket dropped some: not the daemon's doing
                if n_heard:
                    frame_ms.append((t_frames - t0_wall) * 1e3)
                _hold(session, prefix, faults)
            flood_s = time.monotonic() - t_flood0
            if len(frame_ms) < 0.9 * tries:
                raise BenchError(
                    f"the observer heard no Estop frame in {tries - len(frame_ms)} tries"
                )
            flood.stop()
            sent_line = next((ln for ln in flood.out if ln.startswith("SENT ")), "SENT 0")
            flood_n = int(sent_line.split()[1])
        finally:
            for c in reversed(children):
                c.stop()
            if session is not None:
                with contextlib.suppress(Exception):
                    session.close()
            if watch is not None:
                watch.close()
    return {
        "reply_p50": percentile(reply_ms, 0.50),
        "reply_p99": percentile(reply_ms, 0.99),
        "frame_p50": percentile(frame_ms, 0.50),
        "frame_p99": percentile(frame_ms, 0.99),
        "reply_max": max(reply_ms),
        "frame_max": max(frame_ms),
        "reply_ms": reply_ms,
        "frame_ms": frame_ms,
        "tries": len(reply_ms),
        "frames_missed": missed,
        "flood_queries": flood_n,
        "flood_per_s": flood_n / max(flood_s, 1e-9),
        "faults": len(faults),
        "fault_reasons": sorted(set(faults))[:5],
        "scheduling": sched,
    }


def _hold(session: Any, prefix: str, faults: list[str], timeout_s: float = 15.0) -> None:
    """Reset and arm the robot over Zenoh until it holds; faults met on the way are appended
    to `faults`. Raises BenchError if it does not hold within `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    last_fault = None
    while True:
        st = _query_json(session, f"{prefix}/status")
        state = st.get("state")
        if state == "HOLDING":
            return
        if state == "FAULT" and st.get("state_stamp_ns", st.get("reason")) != last_fault:
            last_fault = st.get("state_stamp_ns", st.get("reason"))  # each fault once
            faults.append(f"FAULT: {st.get('reason')}")
        if state in ("ESTOPPED", "FAULT"):
            _query_json(session, f"{prefix}/cmd/reset")
        elif state == "DISARMED":
            _query_json(session, f"{prefix}/cmd/arm")
        if time.monotonic() > deadline:
            raise BenchError(f"the robot does not hold: {state} {st.get('reason')}")
        time.sleep(0.02)


def _query_json(session: Any, key: str) -> dict[str, Any]:
    """One query; the reply's JSON object, or {} if none came."""
    for reply in session.get(key, timeout=5.0):
        if reply.ok is not None:
            out: dict[str, Any] = json.loads(reply.ok.payload.to_bytes())
            return out
    return {}


# --------------------------------------------------------------------------------------------
# The command


@dataclass(frozen=True, slots=True)
class Row:
    """One line of the table."""

    name: str
    value: float | int
    unit: str
    target: str
    ok: bool | None
    repeats: str


def _fmt_value(v: float | int, unit: str) -> str:
    if isinstance(v, int):
        return f"{v:,}"
    if unit == "frac":
        return f"{v:.4f}"
    if abs(v) >= 1e4:
        return f"{v:,.0f}"
    if abs(v) >= 100:
        return f"{v:.1f}"
    if abs(v) >= 1:
        return f"{v:.3f}"
    return f"{v:.3g}"


def format_table(rows: Sequence[Row]) -> str:
    """The results as an aligned text table; MISSED rows are marked with '<--'."""
    head = ("figure", "value", "unit", "target", "result", "repeats")
    body = [
        (
            r.name,
            _fmt_value(r.value, r.unit),
            r.unit,
            r.target,
            "" if r.ok is None else ("PASS" if r.ok else "MISSED"),
            r.repeats,
        )
        for r in rows
    ]
    widths = [max(len(x[k]) for x in [head, *body]) for k in range(len(head))]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    for r, cells in zip(rows, body, strict=True):
        line = "  ".join(c.ljust(w) for c, w in zip(cells, widths, strict=True)).rstrip()
        lines.append(line + ("   <--" if r.ok is False else ""))
    return "\n".join(lines)


def _measure_kinematics(
    p: Plan, log: Callable[[str], None]
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any], list[Row]]:
    """Measure the scalar three-spheres FPK, `fpk` against scipy and the batch FPK.

    Returns their figures and table rows. Raises BenchError.
    """
    rows: list[Row] = []
    log("three-spheres (scalar) ...")
    ts = bench_three_spheres(p.scalar_repeats, p.scalar_calls)
    rep = f"median of {p.scalar_repeats} x {p.scalar_calls} calls"
    rows += [
        Row(
            "fpk_simplified_us",
            ts["fpk_simplified_us"],
            "us",
            f"< {TARGET_SIMPLIFIED_US:g}",
            ts["fpk_simplified_us"] < TARGET_SIMPLIFIED_US,
            f"{rep}; wall {ts['fpk_simplified_wall_us']:.3g}",
        ),
        Row(
            "fpk_general_us",
            ts["fpk_general_us"],
            "us",
            "",
            None,
            f"{rep}; wall {ts['fpk_general_wall_us']:.3g}",
        ),
        Row(
            "fpk_simplified_over_general",
            ts["fpk_simplified_over_general"],
            "ratio",
            f"<= {TARGET_SIMPLIFIED_OVER_GENERAL:g}",
            ts["fpk_simplified_over_general"] <= TARGET_SIMPLIFIED_OVER_GENERAL,
            f"median of {p.scalar_repeats} interleaved pairs",
        ),
    ]

    log("fpk (4 cables) vs scipy least_squares ...")
    f4 = bench_fpk4(p.fpk4_repeats, p.fpk4_poses)
    rep = f"median of {p.fpk4_repeats} x {p.fpk4_poses} poses"
    rows += [
        Row("fpk4_us", f4["fpk4_us"], "us", "", None, f"{rep}; wall {f4['fpk4_wall_us']:.3g}"),
        Row(
            "  scipy least_squares",
            f4["scipy_us"],
            "us",
            "",
            None,
            f"{rep}; wall {f4['scipy_wall_us']:.4g}",
        ),
        Row(
            "scipy_over_fpk4",
            f4["scipy_over_fpk4"],
            "ratio",
            f">= {TARGET_SCIPY_OVER_FPK4:g}",
            f4["scipy_over_fpk4"] >= TARGET_SCIPY_OVER_FPK4,
            f"median of {p.fpk4_repeats} interleaved pairs",
        ),
        Row(
            "  scipy_over_fpk4 (2-point jac)",
            f4["scipy_default_over_fpk4"],
            "ratio",
            "",
            None,
            "scipy's default Jacobian",
        ),
        Row("  |fpk - scipy| max", f4["fpk4_vs_scipy_m"], "m", "", None, f"{p.fpk4_poses} poses"),
    ]

    log(f"batch fpk on {p.batch_poses:,} poses ...")
    bt = bench_batch(p.batch_repeats, p.batch_poses)
    rep = f"median of {p.batch_repeats} interleaved pairs"
    rows += [
        Row(
            "batch_over_copy",
            bt["batch_over_copy"],
            "ratio",
            f"<= {TARGET_BATCH_OVER_COPY:g}",
            bt["batch_over_copy"] <= TARGET_BATCH_OVER_COPY,
            rep,
        ),
        Row(
            "  batch fpk (noisy)",
            bt["batch_over_copy_s"],
            "s",
            "",
            None,
            f"{rep}; wall {bt['batch_over_copy_wall_s']:.3g}",
        ),
        Row("  np.copy", bt["batch_over_copy_copy_s"], "s", "", None, rep),
        Row(
            "  batch_over_copy (consistent)",
            bt["batch_over_copy_consistent"],
            "ratio",
            "",
            None,
            rep,
        ),
    ]
    return ts, f4, bt, rows


def _measure_statics(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """Measure statics per pose, single and batched: figures and rows. Raises BenchError."""
    rows: list[Row] = []
    log("statics (tensions for the payload) ...")
    sx = bench_statics(p.statics_repeats, p.statics_poses, p.statics_batch_poses)
    rep = f"median of {p.statics_repeats} x {p.statics_poses} poses"
    rows += [
        Row(
            "statics_us",
            sx["statics_us"],
            "us",
            "",
            None,
            f"{rep}; wall {sx['statics_wall_us']:.3g}",
        ),
        Row("  tension check (loop)", sx["statics_check_us"], "us", "", None, rep),
        Row(
            "statics_batch_us",
            sx["statics_batch_us"],
            "us",
            "",
            None,
            f"{p.statics_batch_poses:,} poses per batch; wall {sx['statics_batch_wall_us']:.3g}",
        ),
    ]
    return sx, rows


def _measure_sim(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """Measure the physical simulator's real-time factor: figures and rows."""
    log("physical simulator ...")
    sp = bench_sim_plant(p.sim_seconds)
    rows = [
        Row(
            f"sim_plant_rtf.{mode}",
            sp[mode],
            "x",
            f">= {TARGET_SIM_RTF:g}",
            sp[mode] >= TARGET_SIM_RTF,
            f"{p.sim_seconds:g} simulated s at 1 kHz, 4 axes; "
            f"{sp[mode + '_tick_us']:.3g} us a tick",
        )
        for mode in ("position", "torque")
    ]
    return sp, rows


def _measure_decode(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """Measure the receive path: its figures and table rows. Raises BenchError."""
    rows: list[Row] = []
    log("receive path ...")
    dc = bench_decode(p.decode_repeats, p.decode_frames)
    rows.append(
        Row(
            "decode_frames_per_s",
            dc["decode_frames_per_s"],
            "1/s",
            f">= {TARGET_DECODE_FRAMES_PER_S:,.0f}",
            dc["decode_frames_per_s"] >= TARGET_DECODE_FRAMES_PER_S,
            f"median of {p.decode_repeats} x {p.decode_frames:,} frames",
        ),
    )
    return dc, rows


def _measure_loops(
    p: Plan, log: Callable[[str], None]
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any], list[Row]]:
    """Measure the daemon's loop at each rate on simulated ODrives, at 500 Hz on simulated
    CiA 402 drives, and the end-to-end latency.

    Returns the merged runs per rate, the CiA 402 runs, the end-to-end rate's runs and the table
    rows. Raises BenchError.
    """
    rows: list[Row] = []
    runs: dict[str, list[dict[str, Any]]] = {str(rate): [] for rate in LOOP_RATES_HZ}
    for k in range(p.loop_runs):
        for rate in LOOP_RATES_HZ:  # rates interleaved, so load drifts hit both alike
            log(f"loop at {rate} Hz for {p.loop_seconds:g} s (run {k + 1}/{p.loop_runs}) ...")
            lp = bench_loop(rate, p.loop_seconds)
            runs[str(rate)].append(lp)
            for reason in lp["fault_reasons"]:
                log(f"  fault at {rate} Hz: {reason}")
    loops = {rate: merge_runs(rs) for rate, rs in runs.items()}
    for rate in LOOP_RATES_HZ:
        lp = loops[str(rate)]
        at_1k = rate == 1000
        n = f"median of {lp['runs']} runs of {lp['seconds']:.1f} s"
        over_frac = lp["overrun_frac"]
        rows += [
            Row(
                f"loop.{rate}.faults",
                lp["faults"],
                "",
                "0",
                lp["faults"] == 0,
                "; ".join(lp["fault_reasons"])[:60],
            ),
            Row(f"loop.{rate}.ticks", lp["ticks"], "", "", None, n),
            Row(
                f"loop.{rate}.overruns",
                lp["overruns"],
                "",
                f"< {TARGET_OVERRUN_FRAC:.1%} of ticks" if at_1k else "",
                over_frac < TARGET_OVERRUN_FRAC if at_1k else None,
                f"{over_frac:.3%} of ticks",
            ),
            Row(f"loop.{rate}.jitter_p50_frac", lp["jitter_p50_frac"], "frac", "", None, n),
            Row(
                f"loop.{rate}.jitter_p99_frac",
                lp["jitter_p99_frac"],
                "frac",
                f"<= {TARGET_JITTER_P99_FRAC:g}" if at_1k else "",
                lp["jitter_p99_frac"] <= TARGET_JITTER_P99_FRAC if at_1k else None,
                n,
            ),
            Row(f"loop.{rate}.compute_p50_frac", lp["compute_p50_frac"], "frac", "", None, n),
            Row(
                f"loop.{rate}.compute_p99_frac",
                lp["compute_p99_frac"],
                "frac",
                f"<= {TARGET_COMPUTE_P99_FRAC:g}" if at_1k else "",
                lp["compute_p99_frac"] <= TARGET_COMPUTE_P99_FRAC if at_1k else None,
                n,
            ),
            _frames_row(f"loop.{rate}.frames_rx_per_tick", lp),
        ]

    cia_runs = []
    for k in range(p.loop_runs):
        log(
            f"loop at {CIA402_RATE_HZ} Hz on simulated CiA 402 drives for {p.loop_seconds:g} s "
            f"(run {k + 1}/{p.loop_runs}) ..."
        )
        lp = bench_loop(CIA402_RATE_HZ, p.loop_seconds, "cia402")
        cia_runs.append(lp)
        for reason in lp["fault_reasons"]:
            log(f"  fault on CiA 402 drives: {reason}")
    ci = merge_runs(cia_runs)
    name = f"loop.cia402.{CIA402_RATE_HZ}"
    n = f"median of {ci['runs']} runs of {ci['seconds']:.1f} s"
    rows += [
        Row(
            f"{name}.faults",
            ci["faults"],
            "",
            "0",
            ci["faults"] == 0,
            "; ".join(ci["fault_reasons"])[:60],
        ),
        Row(f"{name}.ticks", ci["ticks"], "", "", None, n),
        Row(f"{name}.overruns", ci["overruns"], "", "", None, f"{ci['overrun_frac']:.3%} of ticks"),
        Row(f"{name}.jitter_p99_frac", ci["jitter_p99_frac"], "frac", "", None, n),
        Row(f"{name}.compute_p50_frac", ci["compute_p50_frac"], "frac", "", None, n),
        Row(f"{name}.compute_p99_frac", ci["compute_p99_frac"], "frac", "", None, n),
        _frames_row(f"{name}.frames_rx_per_tick", ci),
    ]

    k5 = loops["500"]
    rows.append(
        Row(
            "  e2e_p50_us at 500 Hz",
            k5["e2e_p50_us"],
            "us",
            "",
            None,
            f"median of {k5['runs']} runs; p99 {k5['e2e_p99_us']:.0f}",
        )
    )
    k1 = loops[str(E2E_RATE_HZ)]
    e2e_target = 1e6 / E2E_RATE_HZ + E2E_MARGIN_US
    e2e_n = f"median of {k1['runs']} runs, {k1['e2e_n']} frames"
    rows += [
        Row(
            "zenoh_put_us",
            k1["zenoh_put_us"],
            "us",
            "",
            None,
            f"median of {k1['runs']} runs of {min(k1['zenoh_put_n'], 4096)} loop puts",
        ),
        Row(
            "e2e_p50_us",
            k1["e2e_p50_us"],
            "us",
            f"<= {e2e_target:g}",
            k1["e2e_p50_us"] <= e2e_target,
            e2e_n,
        ),
        Row("e2e_p99_us", k1["e2e_p99_us"], "us", "", None, e2e_n),
        Row(
            "  e2e send -> daemon publish p50",
            k1["send_to_publish_p50_us"],
            "us",
            "",
            None,
            f"p99 {k1['send_to_publish_p99_us']:.0f}",
        ),
        Row(
            "  e2e publish -> subscriber p50",
            k1["publish_to_arrival_p50_us"],
            "us",
            "",
            None,
            f"p99 {k1['publish_to_arrival_p99_us']:.0f}",
        ),
    ]
    return loops, ci, k1, rows


def _measure_estop(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """Measure e-stop latency under a flood of commands: figures and rows. Raises BenchError."""
    rows: list[Row] = []
    log(f"e-stop under a flood of hostile commands ({p.estop_tries} tries) ...")
    es = bench_estop_flood(p.estop_tries)
    flood = (
        f"{es['tries']} tries; flood {es['flood_per_s']:.0f} queries/s, "
        f"{ESTOP_FLOOD_THREADS} in flight"
    )
    rows += [
        Row(
            "estop_latency_flood_ms.reply_p99",
            es["reply_p99"],
            "ms",
            f"< {TARGET_ESTOP_FLOOD_P99_MS:g}",
            es["reply_p99"] < TARGET_ESTOP_FLOOD_P99_MS,
            f"p50 {es['reply_p50']:.1f}, max {es['reply_max']:.1f}; {flood}",
        ),
        Row(
            "estop_latency_flood_ms.frame_p99",
            es["frame_p99"],
            "ms",
            f"< {TARGET_ESTOP_FLOOD_P99_MS:g}",
            es["frame_p99"] < TARGET_ESTOP_FLOOD_P99_MS,
            f"p50 {es['frame_p50']:.1f}, max {es['frame_max']:.1f}; all axes' Estop frames",
        ),
        Row(
            "  robot faults during the flood",
            es["faults"],
            "",
            "0",
            es["faults"] == 0,
            "; ".join(es["fault_reasons"])[:60],
        ),
    ]
    return es, rows


def measure(
    plan: Plan, log: Callable[[str], None]
) -> tuple[dict[str, Any], list[Row], dict[str, Any]]:
    """Run every benchmark of `plan`; returns the JSON mapping of figures, the table rows and the
    loop runs' full results (`{"loops": {rate: {...}}}`).

    Raises BenchError when a figure cannot be measured.
    """
    rows: list[Row] = []
    p = plan
    ts, f4, bt, part = _measure_kinematics(p, log)
    rows += part
    sx, part = _measure_statics(p, log)
    rows += part
    sp, part = _measure_sim(p, log)
    rows += part
    dc, part = _measure_decode(p, log)
    rows += part
    loops, ci, k1, part = _measure_loops(p, log)
    rows += part
    es, part = _measure_estop(p, log)
    rows += part

    result: dict[str, Any] = {
        "fpk_simplified_us": ts["fpk_simplified_us"],
        "fpk_general_us": ts["fpk_general_us"],
        "fpk_simplified_over_general": ts["fpk_simplified_over_general"],
        "fpk4_us": f4["fpk4_us"],
        "scipy_over_fpk4": f4["scipy_over_fpk4"],
        "batch_over_copy": bt["batch_over_copy"],
        "statics_us": sx["statics_us"],
        "statics_batch_us": sx["statics_batch_us"],
        "sim_plant_rtf": {"position": sp["position"], "torque": sp["torque"]},
        "decode_frames_per_s": dc["decode_frames_per_s"],
        "zenoh_put_us": float(k1["zenoh_put_us"]),
        "loop": {
            str(rate): {key: loops[str(rate)][key] for key in LOOP_KEYS} for rate in LOOP_RATES_HZ
        },
        "e2e_p50_us": k1["e2e_p50_us"],
        "e2e_p99_us": k1["e2e_p99_us"],
        "estop_latency_flood_ms": {key: es[key] for key in ESTOP_KEYS},
    }
    return result, rows, {"loops": loops, "cia402": ci, "estop": es}


def _frames_row(name: str, lp: dict[str, Any]) -> Row:
    """The frames a loop run's driver received per tick (every frame on the bus: udp_multicast
    echoes the loop's own) and, in the detail, those it sent."""
    return Row(
        name,
        lp["frames_rx_per_tick"],
        "",
        "",
        None,
        f"sent {lp['frames_tx_per_tick']:.2f}/tick; received counts the loop's own",
    )


def machine_line() -> str:
    """CPU model, core count, load and Python version, for the table's header."""
    model = "unknown CPU"
    with contextlib.suppress(OSError), open("/proc/cpuinfo", encoding="utf-8") as f:
        for line in f:
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    load = ""
    with contextlib.suppress(OSError):
        load = " load {:.2f} {:.2f} {:.2f},".format(*os.getloadavg())
    return f"{model}, {os.cpu_count()} cores,{load} Python {sys.version.split()[0]}"


def cmd_bench(args: argparse.Namespace) -> int:
    """Entry point of `cablebot bench`."""
    base = QUICK if args.quick else FULL
    plan = replace(
        base,
        batch_poses=args.batch_poses if args.batch_poses is not None else base.batch_poses,
        loop_seconds=args.loop_seconds if args.loop_seconds is not None else base.loop_seconds,
    )

    t_start = time.monotonic()

    def log(msg: str) -> None:
        print(f"[{time.monotonic() - t_start:6.1f} s] {msg}", file=sys.stderr, flush=True)

    log(f"cablebot bench ({'quick' if args.quick else 'full'}) on {machine_line()}")
    try:
        result, rows, extra = measure(plan, log)
    except BenchError as exc:
        print(f"bench failed: {exc}", file=sys.stderr)
        return 1
    print(f"cablebot bench on {machine_line()}")
    print(format_table(rows))
    for rate, lp in extra["loops"].items():
        sim = lp["sim_scheduling"]
        print(f"loop {rate} Hz: loop thread {lp['scheduling']}; simulated nodes {sim}")
    ci = extra["cia402"]
    print(
        f"loop {CIA402_RATE_HZ} Hz on CiA 402 drives: loop thread {ci['scheduling']}; "
        f"simulated drives {ci['sim_scheduling']}"
    )
    print(f"e-stop under flood: loop thread {extra['estop']['scheduling']}")
    missed = [r.name for r in rows if r.ok is False]
    print("MISSED: " + ", ".join(missed) if missed else "all targets met")
    if args.json is not None:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    return 0


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `cablebot bench`."""
    p = sub.add_parser(
        "bench",
        help="measure FPK, receive path, loop timing and latency on this machine",
        description="Measure where the time goes on this machine and compare with the targets.",
    )
    p.add_argument("--quick", action="store_true", help="fewer repeats, 2 s loop runs")
    p.add_argument("--json", type=Path, default=None, metavar="FILE", help="write the figures")
    # For the test: smaller batch and shorter loop runs.
    p.add_argument("--batch-poses", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--loop-seconds", type=float, default=None, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_bench)


def _helper_main(argv: Sequence[str]) -> int:
    """`python -m controller.cli.bench ROLE ...`: the bench's helper processes (sim, sub, loop,
    daemon, flood)."""
    p = argparse.ArgumentParser(prog="python -m controller.cli.bench")
    roles = p.add_subparsers(dest="role", required=True)
    s = roles.add_parser("sim")
    s.add_argument("--config", required=True)
    s.add_argument("--log", required=True)
    s.add_argument("--tick-s", type=float, default=0.001)
    z = roles.add_parser("sub")
    z.add_argument("--connect", required=True)
    z.add_argument("--key", required=True)
    z.add_argument("--out", required=True)
    lp = roles.add_parser("loop")
    lp.add_argument("--rate-hz", type=float, required=True)
    lp.add_argument("--seconds", type=float, required=True)
    lp.add_argument("--out", required=True)
    lp.add_argument("--drive", default="odrive", help="drive family (drivers.registry)")
    d = roles.add_parser("daemon")
    d.add_argument("--config", required=True)
    f = roles.add_parser("flood")
    f.add_argument("--connect", required=True)
    f.add_argument("--prefix", required=True)
    f.add_argument("--threads", type=int, default=ESTOP_FLOOD_THREADS)
    a = p.parse_args(argv)
    if a.role == "sim":
        return role_sim(a.config, a.log, a.tick_s)
    if a.role == "sub":
        return role_sub(a.connect, a.key, a.out)
    if a.role == "daemon":
        return role_daemon(a.config)
    if a.role == "flood":
        return role_flood(a.connect, a.prefix, a.threads)
    return role_loop(a.rate_hz, a.seconds, a.out, a.drive)


if __name__ == "__main__":
    sys.exit(_helper_main(sys.argv[1:]))
