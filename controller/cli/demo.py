"""`cablebot demo circle`: the paper's example (c) run on the real stack, with pictures.

One process runs everything the daemon runs: simulated ODrive nodes (`SimODriveBank`) on a
python-can `virtual` bus, the CANSimple driver (`ODriveReels`), the `Controller` in its
fixed-rate loop thread, and the Zenoh publisher (`ZenohInterface`, on a free local port; the
demo goes on without it if Zenoh cannot open). It homes at the circle's start, arms, and visits
the circle's points one step at a time (each step a one-point `Path` command, i.e. the
planner's `follow_path`, then a short hold so the reels settle), like the paper's 72 steps:
radius 20 m, centre (0, 0), height 2 m, on the paper robot (80.9 m x 50 m x 7.62 m).

A `Recorder` wraps the publisher and stores, every tick, what the loop saw: time, commanded
set-point, FPK position, FPK residual, encoder cable lengths and state (preallocated flat
`array('d')`, a few hundred nanoseconds per tick). At the end the demo prints the settled FPK
error against the commanded points, the cable-length ranges and how closely the encoder lengths
match pure IPK (against the float32 resolution of the reel model), and with `--plot DIR` draws
four PNG figures (matplotlib, the optional `plot` extra).

Whatever the configuration's bus and `[sim]` say, the demo always uses an in-process `virtual`
bus with simulated nodes, never homes from or writes a state file, and publishes every tick.
"""

from __future__ import annotations

import argparse
import gc
import importlib.util
import itertools
import logging
import math
import socket
import sys
import threading
import time
import uuid
from array import array
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

log = logging.getLogger("cablebot.demo")

FloatArray = npt.NDArray[np.float64]
Vec3 = tuple[float, float, float]

PLOT_FILES: tuple[str, ...] = (
    "circle-3d.png",
    "circle-cable-lengths.png",
    "circle-fpk-xyz.png",
    "circle-errors.png",
)
"""The figures `plot_circle` writes, in the README's order."""

SUMMARY_LINE_PREFIX = "max settled FPK error:"
"""The last line of the demo's output starts with this (tests parse it)."""

_STATE_NAMES: tuple[str, ...] = (
    "DISARMED",
    "ARMING",
    "HOLDING",
    "MOVING",
    "FAULT",
    "ESTOPPED",
)
_STATE_CODE = {name: float(i) for i, name in enumerate(_STATE_NAMES)}
_FIXED_COLUMNS = 10  # t, setpoint xyz, fpk xyz, residual, valid, state


class DemoError(RuntimeError):
    """The demo could not run to the end (refused command, fault, timeout); says why."""


# --------------------------------------------------------------------------------------------
# Recording


class Recorder:
    """A `Publisher` that records every published tick, then forwards to `inner`.

    Rows (all floats, NaN where a value is absent): time (monotonic s), set-point x/y/z,
    FPK x/y/z, residual, valid (0/1), state code, then one cable length per reel. The buffer
    is preallocated for `capacity` rows; later rows are counted in `dropped`, not stored.
    Called on the loop thread only; `count` may be read from any thread (rows below it are
    complete).
    """

    def __init__(
        self,
        controller: Any,
        n_cables: int,
        capacity: int,
        inner: Any,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.controller = controller
        self.inner = inner
        self.n_cables = n_cables
        self.stride = _FIXED_COLUMNS + n_cables
        self.capacity = max(1, int(capacity))
        self._buf = array("d", bytes(8 * self.stride * self.capacity))
        self._clock = clock
        self.count = 0
        self.dropped = 0
        self.inner_errors = 0

    def publish_pose(self, sample: Any) -> None:
        """Record the tick (set-point read from the controller), then publish it onwards."""
        i = self.count
        if i < self.capacity:
            buf = self._buf
            b = i * self.stride
            nan = math.nan
            buf[b] = self._clock()
            sp = self.controller.setpoint_m
            if sp is None:
                buf[b + 1] = buf[b + 2] = buf[b + 3] = nan
            else:
                buf[b + 1], buf[b + 2], buf[b + 3] = sp
            pos = sample.position_m
            if pos is None or not sample.valid:
                buf[b + 4] = buf[b + 5] = buf[b + 6] = nan
                buf[b + 8] = 0.0
            else:
                buf[b + 4], buf[b + 5], buf[b + 6] = pos
                buf[b + 8] = 1.0
            res = sample.residual_m
            buf[b + 7] = nan if res is None else res
            buf[b + 9] = _STATE_CODE.get(sample.state, -1.0)
            j = b + _FIXED_COLUMNS
            for length in sample.cable_lengths_m:
                buf[j] = length
                j += 1
            self.count = i + 1
        else:
            self.dropped += 1
        try:
            self.inner.publish_pose(sample)
        except Exception:
            self.inner_errors += 1

    def publish_state(self, state: str, reason: str | None, stamp_ns: int) -> None:
        """Forward a state change to `inner`."""
        try:
            self.inner.publish_state(state, reason, stamp_ns)
        except Exception:
            self.inner_errors += 1

    def last_time_s(self) -> float:
        """Time of the last complete row (-inf before the first)."""
        n = self.count
        return self._buf[(n - 1) * self.stride] if n > 0 else -math.inf

    def rows(self, start: int = 0) -> FloatArray:
        """A copy of the complete rows from `start` on, shape (count - start, stride)."""
        n = self.count
        start = min(max(0, start), n)
        data = np.frombuffer(
            self._buf,
            dtype=np.float64,
            count=(n - start) * self.stride,
            offset=8 * start * self.stride,
        )
        return data.reshape(n - start, self.stride).copy()


# --------------------------------------------------------------------------------------------
# The run


@dataclass(frozen=True, slots=True)
class CircleSpec:
    """What to run: the circle (paper's example (c) by default), speed and settle hold."""

    radius_m: float = 20.0
    centre_m: tuple[float, float] = (0.0, 0.0)
    z_m: float = 2.0
    steps: int = 72
    speed_mps: float | None = None
    """None = the configuration's default_speed_mps."""
    settle_s: float = 0.1
    """Hold at each point before taking the settled sample."""


@dataclass(slots=True)
class CircleRun:
    """What the loop saw during a circle run, plus what the demo knows about the robot."""

    robot: str
    spec: CircleSpec
    speed_mps: float
    rate_hz: float
    anchors_m: FloatArray
    """(n, 3) anchor points."""
    points_m: FloatArray
    """(steps + 1, 3) commanded circle points; row 0 is the start, the last row repeats it."""
    t_s: FloatArray
    """(N,) tick times, seconds from the first settled sample (at the start point)."""
    setpoint_m: FloatArray
    fpk_m: FloatArray
    residual_m: FloatArray
    valid: npt.NDArray[np.bool_]
    state: list[str]
    lengths_m: FloatArray
    """(N, n) cable lengths from the encoders through the homed reel models."""
    settled_index: npt.NDArray[np.int64]
    """(steps + 1,) row of the settled sample at each point (0 = the start, after arming)."""
    turns_max_abs_rev: FloatArray
    """(n,) the largest |motor turns| each reel reached (for the float32 resolution)."""
    reel_slope_m_per_rev: FloatArray
    """(n,) cable metres per motor turn of each reel (|dL/dturn| at that position)."""
    zenoh: str
    """How the pose was published ("tcp/127.0.0.1:PORT, prefix ..." or why not)."""
    wall_s: float
    overruns: int
    ticks: int
    dropped_rows: int
    notes: list[str] = field(default_factory=list)


SETTLE_WINDOW_S = 0.1
SETTLE_TOL_M = 1e-6
"""Settled: after the hold, the FPK position moved less than this over the last window. The
reels' position loops settle exponentially (time constant 1 / pos_gain = 50 ms), so this is in
effect "the float32 encoder readings stopped changing for two time constants", i.e. the reels
sit on their set-points to within a float32 step."""


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (never 7447)."""
    for _ in range(20):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.bind(("127.0.0.1", 0))
            port = int(s.getsockname()[1])
        if port != 7447:
            return port
    raise OSError("no free TCP port on 127.0.0.1")


DEMO_FAULT_FLOORS: dict[str, float] = {
    "stale_timeout_s": 1.0,
    "heartbeat_timeout_s": 2.0,
    "tracking_max_m": 1.0,
    "residual_max_m": 0.2,
}
"""The demo's lowest fault thresholds (unless `strict_faults`). The simulated nodes share this
process (and its GIL) with the loop, and often a busy CPU with other programs: a stall of a few
hundred milliseconds then looks like stale encoders, and after it the set-point has moved on
(tracking error) while the four encoder frames straddle the stall (FPK residual). None of this
touches the settled figures the demo measures; the run's worst tracking error and residual are
printed."""


def demo_config(
    cfg: Any, *, channel: str, zenoh_listen: str | None, strict_faults: bool = False
) -> Any:
    """The demo's copy of `cfg`: in-process virtual bus with simulated nodes, no state file,
    no power-up pose (the demo homes explicitly), publish every tick, Zenoh listening only on
    `zenoh_listen` (no connect, no scouting, no config file); unless `strict_faults`, the fault
    thresholds are raised to at least `DEMO_FAULT_FLOORS`. Raises nothing.
    """
    from controller.service.config import BusConfig, HomingConfig

    faults = cfg.faults
    if not strict_faults:
        faults = replace(
            faults,
            **{k: max(float(getattr(faults, k)), v) for k, v in DEMO_FAULT_FLOORS.items()},
        )

    zen = replace(
        cfg.zenoh,
        listen=(zenoh_listen,) if zenoh_listen else (),
        connect=(),
        multicast_scouting=False,
        config_file=None,
    )
    return replace(
        cfg,
        bus=BusConfig("virtual", channel),
        homing=HomingConfig(None, None),
        loop=replace(cfg.loop, publish_every=1, realtime=False),
        sim=replace(cfg.sim, enabled=True),
        faults=faults,
        zenoh=zen,
    )


def estimate_duration_s(points: Sequence[Vec3], speed_mps: float, accel_mps2: float) -> float:
    """Motion time of visiting `points` in order, rest to rest (the planner's trapezoids)."""
    from controller.core.motion import TrapezoidMove

    return sum(
        TrapezoidMove(a, b, speed_mps, accel_mps2).duration_s for a, b in itertools.pairwise(points)
    )


def _wait(
    cond: Callable[[], bool], timeout_s: float, what: str, fail: Callable[[], str | None]
) -> None:
    """Poll `cond` every 10 ms until true; DemoError on timeout or when `fail()` says why."""
    deadline = time.monotonic() + timeout_s
    while True:
        if cond():
            return
        why = fail()
        if why is not None:
            raise DemoError(f"{what}: {why}")
        if time.monotonic() > deadline:
            raise DemoError(f"{what}: timed out after {timeout_s:g} s")
        time.sleep(0.01)


def _result(fut: Any, timeout_s: float, what: str) -> dict[str, Any]:
    from controller.core.commands import CommandRefused

    try:
        reply: dict[str, Any] = fut.result(timeout=timeout_s)
    except CommandRefused as exc:
        raise DemoError(f"{what} refused: {exc}") from None
    except TimeoutError:
        raise DemoError(f"{what}: no reply within {timeout_s:g} s (loop stalled?)") from None
    return reply


def run_circle(
    cfg: Any,
    spec: CircleSpec,
    *,
    zenoh_listen: str | None = "auto",
    strict_faults: bool = False,
    progress: Callable[[str], None] | None = None,
) -> CircleRun:
    """Run the circle on the real stack in this process and return what the loop saw.

    `cfg` is a `RobotConfig` (its geometry, reels, limits, loop rate and faults are used; see
    `demo_config` for what the demo overrides). `zenoh_listen`: an endpoint, "auto" (a free
    port on 127.0.0.1) or None (no Zenoh). Raises DemoError if a command is refused, the robot
    faults or a wait times out (everything started is stopped and closed first), ValueError
    for an unusable spec.
    """
    from controller.core.commands import Arm, Disarm, Home
    from controller.core.commands import Path as PathCmd
    from controller.core.motion import circle_path
    from controller.core.states import State
    from controller.core.workspace import Workspace
    from controller.service.daemon import Stack, build_stack
    from controller.service.pose import NullPublisher
    from controller.service.runner import start_loop

    say = progress if progress is not None else (lambda s: None)
    points = circle_path(spec.radius_m, spec.centre_m, spec.z_m, spec.steps)
    start = points[0]
    lim = cfg.limits
    speed = float(lim.default_speed_mps if spec.speed_mps is None else spec.speed_mps)
    if not (math.isfinite(speed) and 0.0 < speed <= float(lim.max_speed_mps)):
        raise ValueError(
            f"speed {speed:g} m/s must be > 0 and <= the config's max_speed_mps "
            f"({float(lim.max_speed_mps):g} m/s)"
        )
    if not (math.isfinite(spec.settle_s) and spec.settle_s >= 0.0):
        raise ValueError(f"settle time must be >= 0, got {spec.settle_s!r}")
    reason = Workspace.from_limits(lim, cfg.geometry).check_path(points)
    if reason is not None:
        raise ValueError(f"the circle leaves the robot's limits: {reason}")
    motion_s = estimate_duration_s(points, speed, float(lim.max_accel_mps2))
    rate_hz = float(cfg.loop.rate_hz)
    expect_s = motion_s + spec.steps * (spec.settle_s + 0.05) + 5.0
    capacity = int(rate_hz * (2.0 * expect_s + 60.0))

    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}" if zenoh_listen == "auto" else zenoh_listen
    channel = f"cablebot-demo-{uuid.uuid4().hex[:12]}"
    dcfg = demo_config(cfg, channel=channel, zenoh_listen=endpoint, strict_faults=strict_faults)
    say(
        f"robot {cfg.name!r} ({len(cfg.reels)} reels) from {cfg.source}; simulated ODrive nodes "
        f"{list(dcfg.node_ids)} on python-can virtual bus {channel!r}; loop {rate_hz:g} Hz"
    )
    say(
        f"circle: radius {spec.radius_m:g} m about ({spec.centre_m[0]:g}, {spec.centre_m[1]:g}) "
        f"at z = {spec.z_m:g} m, {spec.steps} steps at {speed:g} m/s "
        f"(accel {float(lim.max_accel_mps2):g} m/s^2), {spec.settle_s:g} s settle: "
        f"about {motion_s + spec.steps * spec.settle_s:.0f} s"
    )
    changed = [
        f"{k} {getattr(dcfg.faults, k):g} (config {getattr(cfg.faults, k):g})"
        for k in DEMO_FAULT_FLOORS
        if getattr(dcfg.faults, k) != getattr(cfg.faults, k)
    ]
    if changed:
        say(
            "fault thresholds raised for a simulation sharing this process and CPU: "
            + ", ".join(changed)
            + " (--strict-faults keeps the config's)"
        )

    stack: Stack | None = None
    notes: list[str] = []
    stop_loop = threading.Event()
    crashed: list[BaseException] = []
    thread: threading.Thread | None = None
    old_switch = sys.getswitchinterval()
    try:
        # The simulated reels power up with the effector at the circle's start.
        sim_cfg = replace(dcfg, homing=replace(dcfg.homing, power_up_position_m=start))
        # The daemon's own builder; Zenoh is optional here (opened below, or not at all).
        stack = build_stack(dcfg, zenoh=False, sim_cfg=sim_cfg)
        controller = stack.controller

        inner: Any = NullPublisher()
        zenoh_text = "off (--no-zenoh)"
        if endpoint is not None:
            try:
                from controller.service.zenoh_io import ZenohInterface

                iface = ZenohInterface(dcfg.zenoh, controller)
                iface.open()
            except Exception as exc:
                zenoh_text = f"unavailable ({type(exc).__name__}: {exc}); publishing nothing"
                notes.append(f"Zenoh {zenoh_text}")
            else:
                inner = iface
                stack.closers.append(("zenoh", iface.close))
                zenoh_text = f"{endpoint}, key {dcfg.zenoh.prefix}/pose"
        say(f"Zenoh: {zenoh_text}")
        if not isinstance(inner, NullPublisher):
            say(f"  watch it: cablebot pose --connect {endpoint} --prefix {dcfg.zenoh.prefix}")
        recorder = Recorder(controller, len(dcfg.reels), capacity, inner)
        controller.publisher = recorder

        # As the daemon runs it (its loop thread, switch interval and gc freeze).
        thread, _sched = start_loop(
            controller.runner(), dcfg.loop, stop_loop, on_crash=crashed.append
        )

        def fault() -> str | None:
            if crashed:
                return f"control loop crashed: {crashed[0]!r}"
            st = controller.state
            if st is State.FAULT or st is State.ESTOPPED:
                return f"{st.value}: {controller.reason}"
            return None

        # Home at the circle's start (retry while the first encoder frames arrive), then arm.
        deadline = time.monotonic() + 5.0
        while True:
            try:
                _result(controller.submit(Home(start)), 3.0, "home")
                break
            except DemoError as exc:
                if "stale_encoder" not in str(exc) or time.monotonic() > deadline:
                    raise
                time.sleep(0.02)
        _result(controller.submit(Arm()), 3.0, "arm")
        _wait(
            lambda: controller.state is State.HOLDING,
            float(cfg.faults.arm_timeout_s) + 3.0,
            "arming",
            fault,
        )
        say(f"homed at ({start[0]:g}, {start[1]:g}, {start[2]:g}) m and armed: HOLDING")

        t_wall0 = time.monotonic()
        settled: list[int] = []

        def settle() -> int:
            """Hold `settle_s`, then until the FPK position over the last `SETTLE_WINDOW_S`
            moved less than `SETTLE_TOL_M` (bounded); return the settled row."""
            t_arrive = time.monotonic()
            first = recorder.count

            def converged() -> bool:
                if recorder.last_time_s() < t_arrive + spec.settle_s:
                    return False
                w = recorder.rows(first)
                w = w[w[:, 0] >= w[-1, 0] - SETTLE_WINDOW_S, 4:7]
                if len(w) < 3 or not np.all(np.isfinite(w)):
                    return False
                return bool(np.max(np.ptp(w, axis=0)) <= SETTLE_TOL_M)

            _wait(converged, spec.settle_s + 5.0, "settling", fault)
            if controller.state is not State.HOLDING:
                raise DemoError(f"left HOLDING while settling: {controller.state.value}")
            return recorder.count - 1

        settled.append(settle())
        every = max(1, spec.steps // 6)
        accel = float(lim.max_accel_mps2)
        for k in range(1, spec.steps + 1):
            p = points[k]
            _result(controller.submit(PathCmd((p,), speed)), 3.0, f"step {k}")
            leg_s = estimate_duration_s([points[k - 1], p], speed, accel)
            _wait(
                lambda p=p: (  # type: ignore[misc]
                    controller.state is State.HOLDING and controller.setpoint_m == p
                ),
                3.0 * leg_s + 5.0,
                f"step {k}",
                fault,
            )
            settled.append(settle())
            if k % every == 0 or k == spec.steps:
                row = recorder.rows(settled[-1])[0]
                err_mm = float(np.linalg.norm(row[4:7] - np.asarray(p))) * 1e3
                say(
                    f"  step {k:3d}/{spec.steps}: at ({p[0]:7.3f}, {p[1]:7.3f}, {p[2]:.3f}) m, "
                    f"settled FPK error {err_mm:.4f} mm, {time.monotonic() - t_wall0:5.1f} s"
                )
        wall_s = time.monotonic() - t_wall0
        _result(controller.submit(Disarm()), 3.0, "disarm")

        data = recorder.rows()
        reels = list(controller.reels)
        overruns = int(controller.loop_stats.overruns)
        ticks = int(controller.ticks)
        dropped = recorder.dropped
    finally:
        stop_loop.set()
        if thread is not None:
            thread.join(2.0)
        sys.setswitchinterval(old_switch)
        gc.unfreeze()
        if stack is not None:
            stack.close()

    n = len(cfg.reels)
    i0 = settled[0]
    t = data[:, 0] - data[i0, 0]
    lengths = data[:, _FIXED_COLUMNS : _FIXED_COLUMNS + n]
    turns = np.array(
        [
            [reels[c].position_rev(float(v)) if math.isfinite(v) else math.nan for v in col]
            for c, col in enumerate(lengths[i0:].T)
        ]
    )
    turns_max = np.nanmax(np.abs(turns), axis=1)
    slopes = np.array(
        [abs(m.length_rate_mps(float(tm), 1.0)) for m, tm in zip(reels, turns_max, strict=True)]
    )
    codes = data[:, 9].astype(int)
    return CircleRun(
        robot=str(cfg.name),
        spec=spec,
        speed_mps=speed,
        rate_hz=rate_hz,
        anchors_m=np.asarray(cfg.geometry.anchors_m, dtype=np.float64),
        points_m=np.asarray(points, dtype=np.float64),
        t_s=t,
        setpoint_m=data[:, 1:4].copy(),
        fpk_m=data[:, 4:7].copy(),
        residual_m=data[:, 7].copy(),
        valid=data[:, 8] > 0.5,
        state=[_STATE_NAMES[c] if 0 <= c < len(_STATE_NAMES) else "?" for c in codes],
        lengths_m=lengths.copy(),
        settled_index=np.asarray(settled, dtype=np.int64),
        turns_max_abs_rev=turns_max,
        reel_slope_m_per_rev=slopes,
        zenoh=zenoh_text,
        wall_s=wall_s,
        overruns=overruns,
        ticks=ticks,
        dropped_rows=dropped,
        notes=notes,
    )


# --------------------------------------------------------------------------------------------
# Numbers


@dataclass(frozen=True, slots=True)
class CircleSummary:
    """The demo's figures of merit (metres unless the name says otherwise)."""

    points: int
    max_settled_error_m: float
    rms_settled_error_m: float
    length_min_m: tuple[float, ...]
    length_max_m: tuple[float, ...]
    ipk_cmd_max_diff_m: float
    """max |encoder length - IPK(commanded point)| over the settled samples."""
    ipk_fpk_max_diff_m: float
    """max |encoder length - IPK(FPK point)| over the settled samples."""
    resolution_m: float
    """One float32 step of motor turns, in cable metres, at the largest |turns| reached."""
    max_tracking_m: float
    """max |FPK - set-point| over every armed tick (includes the lag while moving)."""
    max_residual_m: float


def float32_step_rev(turns_rev: float) -> float:
    """The spacing of float32 numbers (one ULP) at `turns_rev`, in turns."""
    return float(np.spacing(np.float32(abs(turns_rev))))


def summarize(run: CircleRun) -> CircleSummary:
    """The figures of merit of a run (settled samples at points 1..steps, i.e. one lap)."""
    from controller.core import kinematics
    from controller.core.kinematics import Geometry

    geom = Geometry(run.anchors_m)
    idx = run.settled_index[1:]
    cmd = run.points_m[1:]
    fpk = run.fpk_m[idx]
    err = np.linalg.norm(fpk - cmd, axis=1)
    enc = run.lengths_m[idx]
    ipk_cmd = np.asarray(kinematics.ipk(geom, cmd))
    ipk_fpk = np.asarray(kinematics.ipk(geom, fpk))
    armed = np.array([s in ("HOLDING", "MOVING") for s in run.state]) & run.valid
    armed &= np.all(np.isfinite(run.setpoint_m), axis=1)
    track = np.linalg.norm(run.fpk_m[armed] - run.setpoint_m[armed], axis=1)
    lengths = run.lengths_m[run.settled_index[0] :]
    res_step = max(
        float32_step_rev(float(tm)) * float(sl)
        for tm, sl in zip(run.turns_max_abs_rev, run.reel_slope_m_per_rev, strict=True)
    )
    return CircleSummary(
        points=len(idx),
        max_settled_error_m=float(np.max(err)),
        rms_settled_error_m=float(np.sqrt(np.mean(err**2))),
        length_min_m=tuple(float(v) for v in np.nanmin(lengths, axis=0)),
        length_max_m=tuple(float(v) for v in np.nanmax(lengths, axis=0)),
        ipk_cmd_max_diff_m=float(np.max(np.abs(enc - ipk_cmd))),
        ipk_fpk_max_diff_m=float(np.max(np.abs(enc - ipk_fpk))),
        resolution_m=res_step,
        max_tracking_m=float(np.max(track)) if track.size else math.nan,
        max_residual_m=float(np.nanmax(run.residual_m[armed])) if armed.any() else math.nan,
    )


def format_summary(run: CircleRun, s: CircleSummary, tolerance_m: float) -> list[str]:
    """The demo's closing lines; the last one starts with `SUMMARY_LINE_PREFIX`."""
    lines = [
        f"run: {run.wall_s:.1f} s, {run.ticks} ticks at {run.rate_hz:g} Hz, "
        f"{run.overruns} overruns; Zenoh: {run.zenoh}",
        "cable lengths from the encoders (min .. max over the lap):",
    ]
    for i, (lo, hi) in enumerate(zip(s.length_min_m, s.length_max_m, strict=True), start=1):
        lines.append(f"  cable {i}: {lo:8.4f} .. {hi:8.4f} m")
    ok_ipk = s.ipk_cmd_max_diff_m <= s.resolution_m
    lines += [
        f"reel resolution: one float32 step of motor turns = {s.resolution_m * 1e3:.4f} mm of "
        f"cable (at {float(np.max(run.turns_max_abs_rev)):.0f} turns)",
        f"encoder lengths vs pure IPK of the commanded points: max "
        f"{s.ipk_cmd_max_diff_m * 1e3:.4f} mm "
        f"({'within' if ok_ipk else 'OUTSIDE'} the reel resolution)",
        f"encoder lengths vs IPK of the FPK points: max {s.ipk_fpk_max_diff_m * 1e3:.4f} mm",
        f"while moving: max |FPK - set-point| {s.max_tracking_m * 1e3:.2f} mm (loop lag), "
        f"max FPK residual {s.max_residual_m * 1e3:.4f} mm",
        f"RMS settled FPK error: {s.rms_settled_error_m * 1e3:.4f} mm",
    ]
    verdict = "agrees" if s.max_settled_error_m <= tolerance_m else "DISAGREES"
    lines.append(
        f"{SUMMARY_LINE_PREFIX} {s.max_settled_error_m * 1e3:.4f} mm ({s.points} points; "
        f"{verdict} with the commanded circle within {tolerance_m * 1e3:g} mm)"
    )
    return lines


# --------------------------------------------------------------------------------------------
# Pictures

_CABLE_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b")


def _step_axis(run: CircleRun) -> FloatArray:
    """Each tick's position along the steps: settled sample k at k, time-interpolated between."""
    ts = run.t_s[run.settled_index]
    return np.interp(run.t_s, ts, np.arange(len(ts), dtype=np.float64))


ZOOM_BELOW = 0.25
"""Zoom the 3-D figure to the path when it spans less than this fraction of the robot."""


def zoom_box_3d(anchors_m: FloatArray, path_m: FloatArray) -> tuple[FloatArray, FloatArray] | None:
    """The (low, high) corners of a cube around `path_m` for the 3-D figure, or None.

    None when the path spans at least `ZOOM_BELOW` of the anchors' plan-view extent (draw the
    whole robot). Otherwise the cube is centred on the path with 30 % room, all three sides
    equal so that the figure keeps the path's true shape.
    """
    robot_span = float(max(np.ptp(anchors_m[:, 0]), np.ptp(anchors_m[:, 1])))
    lo = np.min(path_m, axis=0)
    hi = np.max(path_m, axis=0)
    span = float(np.max(hi - lo))
    if robot_span <= 0.0 or span >= ZOOM_BELOW * robot_span:
        return None
    half = max(span, 1e-3) * 0.65
    centre = (lo + hi) / 2.0
    centre[2] = max(float(centre[2]), half)  # keep the cube above the floor (z = 0)
    return centre - half, centre + half


def plot_circle(run: CircleRun, out_dir: Path, summary: CircleSummary | None = None) -> list[Path]:
    """Write the four PNG figures (`PLOT_FILES`) into `out_dir` and return their paths.

    Raises ImportError without matplotlib (the `plot` extra), OSError if a file cannot be
    written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    s = summary if summary is not None else summarize(run)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / name for name in PLOT_FILES]
    i0 = int(run.settled_index[0])
    sl = slice(i0, None)
    t = run.t_s[sl]
    step = _step_axis(run)[sl]
    idx = run.settled_index
    n = run.anchors_m.shape[0]
    spec = run.spec
    title_circle = (
        f"radius {spec.radius_m:g} m, centre ({spec.centre_m[0]:g}, {spec.centre_m[1]:g}), "
        f"z = {spec.z_m:g} m, {spec.steps} steps"
    )
    colours = [_CABLE_COLOURS[i % len(_CABLE_COLOURS)] for i in range(n)]
    plt.rcParams.update({"font.size": 11, "axes.titlesize": 12, "figure.titlesize": 14})

    deg = 360.0 / spec.steps
    note_kw: dict[str, Any] = {"ha": "center", "fontsize": 9, "color": "0.3"}

    # 1. The robot and the path in 3D (the paper's Figure 3). A path small beside the robot
    # gets axes zoomed to it (equal aspect) and the anchors in a plan-view inset.
    fig = plt.figure(figsize=(11, 5.8))
    ax: Any = fig.add_axes((-0.04, 0.0, 0.84, 0.96), projection="3d")
    A = run.anchors_m  # noqa: N806
    pts = run.points_m
    f = run.fpk_m[sl]
    p_end = run.fpk_m[idx[-1]]
    box = zoom_box_3d(A, np.vstack([pts, f]))
    if box is None:
        for i in range(n):
            ax.plot([A[i, 0]] * 2, [A[i, 1]] * 2, [0.0, A[i, 2]], color="0.45", lw=2.5)
        ring = np.vstack([A, A[:1]])
        ax.plot(ring[:, 0], ring[:, 1], np.zeros(len(ring)), color="0.6", lw=1, ls=":")
        ax.scatter(A[:, 0], A[:, 1], A[:, 2], color="k", marker="v", s=50, label="anchors B1..B4")
        for i in range(n):
            ax.text(A[i, 0], A[i, 1], A[i, 2] + 1.0, f"B{i + 1}", ha="center", fontsize=11)
        cable_ends = A
    else:
        # Cables drawn toward their anchors only as far as the zoomed box reaches.
        u = (A - p_end) / np.linalg.norm(A - p_end, axis=1)[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            to_wall = np.where(u > 0, (box[1] - p_end) / u, (box[0] - p_end) / u)
        reach = np.nanmin(np.where(np.abs(u) > 1e-12, to_wall, np.inf), axis=1)
        cable_ends = p_end + u * reach[:, None]
    for i in range(n):
        ax.plot(
            [cable_ends[i, 0], p_end[0]],
            [cable_ends[i, 1], p_end[1]],
            [cable_ends[i, 2], p_end[2]],
            color=colours[i],
            lw=1.8,
            label=f"cable {i + 1}" + ("" if box is None else f" (toward B{i + 1})"),
        )
    ax.plot(
        pts[:, 0],
        pts[:, 1],
        pts[:, 2],
        ls="none",
        marker="o",
        ms=4.5,
        mfc="none",
        mec="k",
        mew=0.8,
        label=f"commanded ({spec.steps} points)",
    )
    ax.plot(f[:, 0], f[:, 1], f[:, 2], color="#1f77b4", lw=1.8, label="FPK measured")
    ax.scatter(*p_end, color="#d62728", s=45, depthshade=False, label="P, final = initial")
    if box is None:
        lx, ly = np.ptp(A[:, 0]), np.ptp(A[:, 1])
        zmax = float(np.max(A[:, 2]))
        z_scale = 3.0
        ax.set_box_aspect((lx, ly, zmax * z_scale), zoom=1.0)
        ax.set_zlim(0.0, zmax * 1.1)
        scale_note = f"Vertical scale x{z_scale:g}."
    else:
        ax.set_xlim(box[0][0], box[1][0])
        ax.set_ylim(box[0][1], box[1][1])
        ax.set_zlim(box[0][2], box[1][2])
        ax.set_box_aspect((1.0, 1.0, 1.0), zoom=0.85)
        scale_note = "Equal scales."
        fig.text(0.89, 0.57, "the 3-D view: red box", ha="center", fontsize=8, color="0.3")
        ins = fig.add_axes((0.80, 0.64, 0.18, 0.28))
        ring = np.vstack([A, A[:1]])
        ins.plot(ring[:, 0], ring[:, 1], color="0.6", lw=1, ls=":")
        ins.plot(A[:, 0], A[:, 1], "kv", ms=5)
        for i in range(n):
            ins.annotate(
                f"B{i + 1}",
                (A[i, 0], A[i, 1]),
                fontsize=8,
                ha="center",
                xytext=(0, 5),
                textcoords="offset points",
            )
        ins.plot(pts[:, 0], pts[:, 1], color="#1f77b4", lw=1.5)
        ins.add_patch(
            Rectangle(
                (box[0][0], box[0][1]),
                box[1][0] - box[0][0],
                box[1][1] - box[0][1],
                fill=False,
                ec="#d62728",
                lw=1.0,
            )
        )
        ins.set_aspect("equal", adjustable="datalim")
        ins.set_title("plan view", fontsize=9)
        ins.tick_params(labelsize=7)
    ax.set_xlabel("x (m)", labelpad=8)
    ax.set_ylabel("y (m)", labelpad=8)
    ax.set_zlabel("z (m)", labelpad=4)
    ax.view_init(elev=26, azim=-62)
    fig.suptitle(f"Robot {run.robot!r} and the circle: {title_circle}", y=0.97)
    legend_at = (0.99, 0.5) if box is None else (0.99, 0.33)
    fig.legend(loc="center right", bbox_to_anchor=legend_at, fontsize=10, framealpha=0.9)
    fig.text(
        0.45,
        0.025,
        "Cables drawn at the final (= initial) point. Measured path: FPK of the encoder "
        f"lengths at every control tick. {scale_note}",
        **note_kw,
    )
    fig.savefig(paths[0], dpi=110)
    plt.close(fig)

    # 2. Cable lengths against step (Figure 4).
    fig, ax = plt.subplots(figsize=(10, 5.6))
    L = run.lengths_m[sl]  # noqa: N806
    for i in range(n):
        ax.plot(step, L[:, i], color=colours[i], lw=1.6, label=f"cable {i + 1}")
        ax.plot(np.arange(len(idx)), run.lengths_m[idx, i], "o", color=colours[i], ms=3)
    ax.plot([], [], "o", color="0.3", ms=3, label="settled at a point")
    ax.set_xlabel(f"step ({deg:g} degrees each)")
    ax.set_ylabel("cable length (m)")
    ax.set_title(f"Cable lengths from the encoders: {title_circle}")
    ax.set_xlim(0, spec.steps)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.text(
        0.45,
        0.015,
        "Lines: every control tick, placed between the steps by time. "
        "Dots: the lengths once settled at each point.",
        **note_kw,
    )
    fig.tight_layout(rect=(0.0, 0.04, 1.0, 1.0))
    fig.savefig(paths[1], dpi=110)
    plt.close(fig)

    # 3. FPK x, y, z against step with the commanded values (Figure 5).
    fig, axes = plt.subplots(3, 1, figsize=(10, 7.8), sharex=True)
    steps_k = np.arange(len(idx))
    for c, (name, axc) in enumerate(zip("xyz", axes, strict=True)):
        axc.plot(step, run.fpk_m[sl, c], color="#1f77b4", lw=1.6, label="FPK (every tick)")
        axc.plot(steps_k, pts[:, c], "o", mfc="none", mec="k", ms=5, label="commanded point")
        axc.set_ylabel(f"{name} (m)")
        axc.grid(True, alpha=0.3)
        lo, hi = float(np.nanmin(pts[:, c])), float(np.nanmax(pts[:, c]))
        if hi - lo < 1.0:  # a constant coordinate: show it on a metre scale, not its noise
            mid = 0.5 * (lo + hi)
            axc.set_ylim(mid - 1.0, mid + 1.0)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.935), ncols=2)
    axes[-1].set_xlabel(f"step ({deg:g} degrees each)")
    axes[-1].set_xlim(0, spec.steps)
    fig.suptitle(f"FPK Cartesian result vs commanded: {title_circle}")
    fig.text(
        0.5,
        0.012,
        "Excursions between the points are the loop's lag while moving "
        "(see circle-errors.png); at the points the error is micrometres.",
        **note_kw,
    )
    fig.tight_layout(rect=(0.0, 0.03, 1.0, 0.9))
    fig.savefig(paths[2], dpi=110)
    plt.close(fig)

    # 4. Tracking error and FPK residual over time, in millimetres.
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(11, 6.8), sharex=True)
    err = np.linalg.norm(run.fpk_m[sl] - run.setpoint_m[sl], axis=1) * 1e3
    floor = 1e-4
    a1.semilogy(t, np.maximum(err, floor), color="#1f77b4", lw=0.7, label="every tick")
    err_settled = np.linalg.norm(run.fpk_m[idx[1:]] - pts[1:], axis=1) * 1e3
    a1.semilogy(
        run.t_s[idx[1:]],
        np.maximum(err_settled, floor),
        "o",
        color="#d62728",
        ms=3.5,
        label=f"settled at the points\n(max {s.max_settled_error_m * 1e3:.3f} mm)",
    )
    a1.axhline(1.0, color="k", ls="--", lw=1, label="1 mm")
    a1.set_ylabel("|FPK - commanded| (mm)")
    a1.set_title("Tracking error: FPK position minus commanded set-point")
    a1.grid(True, which="both", alpha=0.25)
    a1.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=10)
    res = run.residual_m[sl] * 1e3
    a2.semilogy(t, np.maximum(res, floor), color="#2ca02c", lw=0.7, label="every tick")
    a2.set_ylabel("FPK residual (mm)")
    a2.set_xlabel("time (s)")
    a2.set_title(f"FPK residual: RMS mismatch of the {n} cable lengths at the solved point")
    a2.grid(True, which="both", alpha=0.25)
    a2.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=10)
    a2.set_xlim(0.0, float(t[-1]) if len(t) else 1.0)
    fig.suptitle(f"Errors: {title_circle}")
    fig.text(
        0.45,
        0.012,
        "While moving, the set-points carry velocity feed-forward: the reels follow within "
        "millimetres;\nspikes are delays of the shared CPU. "
        f"Values below {floor:g} mm are drawn at {floor:g} mm.",
        **note_kw,
    )
    fig.tight_layout(rect=(0.0, 0.05, 1.0, 1.0))
    fig.savefig(paths[3], dpi=110)
    plt.close(fig)
    return paths


# --------------------------------------------------------------------------------------------
# Command line


def cmd_circle(args: argparse.Namespace) -> int:
    """Entry point of `cablebot demo circle`: 0 = agrees, 1 = disagrees or failed, 2 = config."""
    from controller.service.config import ConfigError, load_config

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")

    def say(line: str) -> None:
        print(line, flush=True)

    if args.plot is not None and importlib.util.find_spec("matplotlib") is None:
        print(
            "cablebot demo: --plot needs matplotlib: pip install 'cablebot[plot]'",
            file=sys.stderr,
        )
        return 1
    try:
        cfg = load_config(args.config)
    except (ConfigError, OSError) as exc:
        print(f"cablebot demo: configuration: {exc}", file=sys.stderr)
        return 2
    spec = CircleSpec(
        radius_m=args.radius,
        centre_m=(args.centre[0], args.centre[1]),
        z_m=args.height,
        steps=args.steps,
        speed_mps=args.speed,
        settle_s=args.settle,
    )
    listen = None if args.no_zenoh else (args.zenoh_listen or "auto")
    try:
        run = run_circle(
            cfg, spec, zenoh_listen=listen, strict_faults=args.strict_faults, progress=say
        )
    except (DemoError, ValueError) as exc:
        print(f"cablebot demo: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("cablebot demo: interrupted", file=sys.stderr)
        return 130
    for note in run.notes:
        say(f"note: {note}")
    if run.dropped_rows:
        say(f"note: the recorder was full; {run.dropped_rows} ticks not recorded")
    summary = summarize(run)
    if args.plot is not None:
        try:
            paths = plot_circle(run, Path(args.plot), summary)
        except ImportError:
            say("pictures: matplotlib is missing; install cablebot[plot] for pictures")
        else:
            for p in paths:
                say(f"wrote {p}")
    for line in format_summary(run, summary, args.tolerance_mm * 1e-3):
        say(line)
    return 0 if summary.max_settled_error_m <= args.tolerance_mm * 1e-3 else 1


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `cablebot demo circle`."""
    p = sub.add_parser(
        "demo",
        help="run a demonstration on the simulated robot",
        description="Demonstrations that run the whole stack in one process.",
    )
    dsub = p.add_subparsers(dest="demo", metavar="DEMO")
    dsub.required = True
    c = dsub.add_parser(
        "circle",
        help="the paper's circle (example c) on the real stack, with numbers and pictures",
        description=(
            "Run the control loop, the ODrive driver, simulated ODrive nodes on a python-can "
            "virtual bus and the Zenoh publisher in this process; home at the circle's start, "
            "arm, visit the circle's points step by step (settling at each), and print the "
            "settled FPK error and the cable-length ranges. The full 72-step run on the paper "
            "robot takes about 4 minutes (1 m/s, 1 m/s^2 on 1.7 m steps)."
        ),
    )
    c.add_argument("--config", type=Path, default=None, help="robot TOML (default: built-in)")
    c.add_argument(
        "--plot", metavar="DIR", default=None, help="write the four PNG figures into DIR"
    )
    c.add_argument("--steps", type=int, default=72, metavar="N", help="points on the circle")
    c.add_argument("--radius", type=float, default=20.0, metavar="M", help="radius in m")
    c.add_argument(
        "--centre", type=float, nargs=2, default=(0.0, 0.0), metavar=("X", "Y"), help="in m"
    )
    c.add_argument("--height", type=float, default=2.0, metavar="Z", help="z in m")
    c.add_argument(
        "--speed",
        type=float,
        default=None,
        metavar="V",
        help="speed in m/s, up to the config's max_speed_mps (default: its default_speed_mps)",
    )
    c.add_argument("--settle", type=float, default=0.1, metavar="S", help="hold at each point (s)")
    c.add_argument(
        "--tolerance-mm",
        type=float,
        default=1.0,
        metavar="MM",
        help="exit 1 if the max settled error exceeds this (default 1 mm)",
    )
    c.add_argument(
        "--strict-faults",
        action="store_true",
        help=(
            "keep the config's fault thresholds (by default the demo raises them to at least "
            + ", ".join(f"{k} {v:g}" for k, v in DEMO_FAULT_FLOORS.items())
            + ")"
        ),
    )
    z = c.add_mutually_exclusive_group()
    z.add_argument(
        "--zenoh-listen",
        default=None,
        metavar="ENDPOINT",
        help="publish the pose on this Zenoh endpoint (default: a free port on 127.0.0.1)",
    )
    z.add_argument("--no-zenoh", action="store_true", help="do not open Zenoh")
    c.set_defaults(func=cmd_circle)
