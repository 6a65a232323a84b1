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
four PNG figures (matplotlib, the optional `plot` extra) with `cablebot plot`'s drawing: the
run becomes a `plot.Trace` (`circle_trace`) whose waypoints are the circle's points, so the
cable lengths and the position are drawn against the step, as in the paper's figures.

The run in pieces: `plan_circle` checks the circle against the robot before anything starts,
`DemoStack` starts and stops the stack, `_lap` visits the points, `_circle_run` turns the
recorder's rows into a `CircleRun`; `summarize` and `format_summary` give the numbers.

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

from controller.cli.plot import FIGURES, Trace, Waypoints, plot_trace
from controller.cli.shape import RobotShape

log = logging.getLogger("cablebot.demo")

FloatArray = npt.NDArray[np.float64]
Vec3 = tuple[float, float, float]

PLOT_NAME = "circle"
PLOT_FILES: tuple[str, ...] = tuple(f"{PLOT_NAME}-{fig}.png" for fig in FIGURES)
"""The figures `plot_circle` writes, in `cablebot plot`'s order: circle-3d.png,
circle-cable-lengths.png, circle-fpk-xyz.png, circle-errors.png."""

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
    shape: RobotShape | None
    """The robot as the figures draw it (None: its configuration made no drawable shape)."""
    notes: list[str] = field(default_factory=list)


SETTLE_WINDOW_S = 0.1
SETTLE_TOL_M = 1e-6
"""Settled: after the hold, the FPK position moved less than this over the last window. The
reels' position loops settle exponentially (time constant 1 / pos_gain = 50 ms), so this is in
effect "the float32 encoder readings stopped changing for two time constants", i.e. the reels
sit on their set-points to within a float32 step."""


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
DEMO_SIM_WATCHDOG_FLOOR_S = 2.0
"""The simulated drives' axis watchdog, at least (unless `strict_faults` or the configuration
turns it off): a stall of this process longer than the watchdog would disarm an axis
(WATCHDOG_TIMER_EXPIRED) and fault the run, as a stall beyond the stale timeout would."""


def demo_config(
    cfg: Any, *, channel: str, zenoh_listen: str | None, strict_faults: bool = False
) -> Any:
    """The demo's copy of `cfg`: in-process virtual bus with simulated nodes, no state file,
    no power-up pose (the demo homes explicitly), publish every tick, Zenoh listening only on
    `zenoh_listen` (no connect, no scouting, no config file); unless `strict_faults`, the fault
    thresholds are raised to at least `DEMO_FAULT_FLOORS` and a simulated drive watchdog that
    is on to at least `DEMO_SIM_WATCHDOG_FLOOR_S`. Raises nothing.
    """
    from controller.service.config import BusConfig, HomingConfig

    faults = cfg.faults
    sim = replace(cfg.sim, enabled=True)
    if not strict_faults:
        faults = replace(
            faults,
            **{k: max(float(getattr(faults, k)), v) for k, v in DEMO_FAULT_FLOORS.items()},
        )
        if sim.watchdog_timeout_s > 0.0:
            watchdog_s = max(float(sim.watchdog_timeout_s), DEMO_SIM_WATCHDOG_FLOOR_S)
            sim = replace(sim, watchdog_timeout_s=watchdog_s)

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
        sim=sim,
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


@dataclass(frozen=True, slots=True)
class CirclePlan:
    """What `plan_circle` worked out before anything starts: the points, speeds and sizes."""

    points: tuple[Vec3, ...]
    """The circle's `steps + 1` points; the first is the start, the last repeats it."""
    speed_mps: float
    accel_mps2: float
    motion_s: float
    """Motion time of the lap, rest to rest at every point (without the settle holds)."""
    rate_hz: float
    capacity: int
    """Rows the recorder preallocates: twice the expected run plus a minute, at the loop rate."""


def plan_circle(cfg: Any, spec: CircleSpec) -> CirclePlan:
    """Check `spec` against `cfg` (speed, settle time, the robot's limits) and plan the lap.

    Raises ValueError for a speed outside (0, max_speed_mps], a negative settle time or a
    circle that leaves the limits.
    """
    from controller.core.motion import circle_path
    from controller.core.workspace import Workspace

    points = tuple(circle_path(spec.radius_m, spec.centre_m, spec.z_m, spec.steps))
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
    accel = float(lim.max_accel_mps2)
    motion_s = estimate_duration_s(points, speed, accel)
    rate_hz = float(cfg.loop.rate_hz)
    expect_s = motion_s + spec.steps * (spec.settle_s + 0.05) + 5.0
    return CirclePlan(
        points=points,
        speed_mps=speed,
        accel_mps2=accel,
        motion_s=motion_s,
        rate_hz=rate_hz,
        capacity=int(rate_hz * (2.0 * expect_s + 60.0)),
    )


def _announce(
    cfg: Any, dcfg: Any, spec: CircleSpec, plan: CirclePlan, say: Callable[[str], None]
) -> None:
    """Say what is about to run: the robot, the bus, the circle, any fault threshold raised."""
    say(
        f"robot {cfg.name!r} ({len(cfg.reels)} reels) from {cfg.source}; simulated ODrive nodes "
        f"{list(dcfg.node_ids)} on python-can virtual bus {dcfg.bus.channel!r}; "
        f"loop {plan.rate_hz:g} Hz"
    )
    say(
        f"circle: radius {spec.radius_m:g} m about ({spec.centre_m[0]:g}, {spec.centre_m[1]:g}) "
        f"at z = {spec.z_m:g} m, {spec.steps} steps at {plan.speed_mps:g} m/s "
        f"(accel {plan.accel_mps2:g} m/s^2), {spec.settle_s:g} s settle: "
        f"about {plan.motion_s + spec.steps * spec.settle_s:.0f} s"
    )
    changed = [
        f"{k} {getattr(dcfg.faults, k):g} (config {getattr(cfg.faults, k):g})"
        for k in DEMO_FAULT_FLOORS
        if getattr(dcfg.faults, k) != getattr(cfg.faults, k)
    ]
    wd_s, cfg_wd_s = dcfg.sim.watchdog_timeout_s, cfg.sim.watchdog_timeout_s
    if wd_s != cfg_wd_s:
        changed.append(f"simulated drive watchdog {wd_s:g} s (config {cfg_wd_s:g} s)")
    if changed:
        say(
            "fault thresholds raised for a simulation sharing this process and CPU: "
            + ", ".join(changed)
            + " (--strict-faults keeps the config's)"
        )


class DemoStack:
    """The demo's running robot, as a context manager: the daemon's stack (simulated nodes on
    the virtual bus, driver, controller) with the effector powered up at `start_m`, Zenoh on
    `endpoint` when it opens, a `Recorder` as the controller's publisher, and the loop thread
    (started as the daemon starts it). Leaving the context stops and closes all of it.
    """

    def __init__(
        self,
        dcfg: Any,
        start_m: Vec3,
        capacity: int,
        endpoint: str | None,
        say: Callable[[str], None],
    ) -> None:
        self.dcfg = dcfg
        self.start_m = start_m
        self.capacity = capacity
        self.endpoint = endpoint
        self.say = say
        self.notes: list[str] = []
        self.zenoh_text = "off (--no-zenoh)"
        self._stack: Any = None
        self.controller: Any = None
        self.recorder: Recorder
        self._stop = threading.Event()
        self._crashed: list[BaseException] = []
        self._thread: threading.Thread | None = None
        self._switch_s = sys.getswitchinterval()

    def __enter__(self) -> DemoStack:
        """Build and start everything; raises what `build_stack` raises (after closing)."""
        from controller.service.daemon import build_stack
        from controller.service.runner import start_loop

        try:
            # The simulated reels power up with the effector at the circle's start.
            sim_cfg = replace(
                self.dcfg, homing=replace(self.dcfg.homing, power_up_position_m=self.start_m)
            )
            # The daemon's own builder; Zenoh is optional here (opened below, or not at all).
            self._stack = build_stack(self.dcfg, zenoh=False, sim_cfg=sim_cfg)
            self.controller = self._stack.controller
            inner = self._open_zenoh()
            self.recorder = Recorder(self.controller, len(self.dcfg.reels), self.capacity, inner)
            self.controller.publisher = self.recorder
            # As the daemon runs it (its loop thread, switch interval and gc freeze).
            self._thread, _sched = start_loop(
                self.controller.runner(), self.dcfg.loop, self._stop, on_crash=self._crashed.append
            )
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        """Stop the loop and close everything."""
        self.close()

    def close(self) -> None:
        """Stop the loop thread, restore the interpreter's settings, close the stack."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        sys.setswitchinterval(self._switch_s)
        gc.unfreeze()
        if self._stack is not None:
            self._stack.close()
            self._stack = None

    def _open_zenoh(self) -> Any:
        """The Zenoh publisher on `endpoint`, or a `NullPublisher` (with a note why)."""
        from controller.service.pose import NullPublisher

        inner: Any = NullPublisher()
        if self.endpoint is not None:
            try:
                from controller.service.zenoh_io import ZenohInterface

                iface = ZenohInterface(self.dcfg.zenoh, self.controller)
                iface.open()
            except Exception as exc:
                self.zenoh_text = f"unavailable ({type(exc).__name__}: {exc}); publishing nothing"
                self.notes.append(f"Zenoh {self.zenoh_text}")
            else:
                from controller.service.daemon import start_truth_feed

                inner = iface
                self._stack.closers.append(("zenoh", iface.close))
                self.zenoh_text = f"{self.endpoint}, key {self.dcfg.zenoh.prefix}/pose"
                # the physical plant's truth, as the daemon publishes it
                if start_truth_feed(self.dcfg, self._stack.sim_bank, iface, self._stack.closers):
                    self.zenoh_text += " and sim/truth"
        self.say(f"Zenoh: {self.zenoh_text}")
        if not isinstance(inner, NullPublisher):
            self.say(
                f"  watch it: cablebot pose --connect {self.endpoint} "
                f"--prefix {self.dcfg.zenoh.prefix}"
            )
        return inner

    def fault(self) -> str | None:
        """Why the run cannot go on (the loop crashed, FAULT or ESTOPPED), or None."""
        from controller.core.states import State

        if self._crashed:
            return f"control loop crashed: {self._crashed[0]!r}"
        st = self.controller.state
        if st is State.FAULT or st is State.ESTOPPED:
            return f"{st.value}: {self.controller.reason}"
        return None

    def home_and_arm(self, arm_timeout_s: float) -> None:
        """Home at `start_m` (retrying while the first encoder frames arrive), arm, and wait
        for HOLDING. Raises DemoError."""
        from controller.core.commands import Arm, Home
        from controller.core.states import State

        deadline = time.monotonic() + 5.0
        while True:
            try:
                _result(self.controller.submit(Home(self.start_m)), 3.0, "home")
                break
            except DemoError as exc:
                if "stale_encoder" not in str(exc) or time.monotonic() > deadline:
                    raise
                time.sleep(0.02)
        _result(self.controller.submit(Arm()), 3.0, "arm")
        _wait(
            lambda: self.controller.state is State.HOLDING,
            arm_timeout_s + 3.0,
            "arming",
            self.fault,
        )

    def go_to(self, p: Vec3, speed_mps: float, timeout_s: float, what: str) -> None:
        """Send a one-point path to `p` and wait until the set-point is there and the robot
        HOLDING. Raises DemoError."""
        from controller.core.commands import Path as PathCmd
        from controller.core.states import State

        ctl = self.controller
        _result(ctl.submit(PathCmd((p,), speed_mps)), 3.0, what)
        _wait(
            lambda: ctl.state is State.HOLDING and ctl.setpoint_m == p,
            timeout_s,
            what,
            self.fault,
        )

    def settle(self, settle_s: float) -> int:
        """Hold `settle_s`, then until the FPK position over the last `SETTLE_WINDOW_S` moved
        less than `SETTLE_TOL_M` (bounded); return the settled row. Raises DemoError."""
        from controller.core.states import State

        recorder = self.recorder
        t_arrive = time.monotonic()
        first = recorder.count

        def converged() -> bool:
            if recorder.last_time_s() < t_arrive + settle_s:
                return False
            w = recorder.rows(first)
            w = w[w[:, 0] >= w[-1, 0] - SETTLE_WINDOW_S, 4:7]
            if len(w) < 3 or not np.all(np.isfinite(w)):
                return False
            return bool(np.max(np.ptp(w, axis=0)) <= SETTLE_TOL_M)

        _wait(converged, settle_s + 5.0, "settling", self.fault)
        if self.controller.state is not State.HOLDING:
            raise DemoError(f"left HOLDING while settling: {self.controller.state.value}")
        return recorder.count - 1


def _lap(
    ds: DemoStack, spec: CircleSpec, plan: CirclePlan, say: Callable[[str], None]
) -> list[int]:
    """Visit the circle's points one step at a time, settling at each; the settled rows (the
    start's first). Says the settled error at every sixth of the lap. Raises DemoError."""
    pts = plan.points
    t0 = time.monotonic()
    settled = [ds.settle(spec.settle_s)]
    every = max(1, spec.steps // 6)
    for k in range(1, spec.steps + 1):
        leg_s = estimate_duration_s(pts[k - 1 : k + 1], plan.speed_mps, plan.accel_mps2)
        ds.go_to(pts[k], plan.speed_mps, 3.0 * leg_s + 5.0, f"step {k}")
        settled.append(ds.settle(spec.settle_s))
        if k % every == 0 or k == spec.steps:
            p = pts[k]
            row = ds.recorder.rows(settled[-1])[0]
            err_mm = float(np.linalg.norm(row[4:7] - np.asarray(p))) * 1e3
            say(
                f"  step {k:3d}/{spec.steps}: at ({p[0]:7.3f}, {p[1]:7.3f}, {p[2]:.3f}) m, "
                f"settled FPK error {err_mm:.4f} mm, {time.monotonic() - t0:5.1f} s"
            )
    return settled


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
    from controller.core.commands import Disarm

    say = progress if progress is not None else (lambda s: None)
    plan = plan_circle(cfg, spec)
    from controller.service.zenoh_io import free_tcp_port  # Zenoh only when used

    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}" if zenoh_listen == "auto" else zenoh_listen
    channel = f"cablebot-demo-{uuid.uuid4().hex[:12]}"
    dcfg = demo_config(cfg, channel=channel, zenoh_listen=endpoint, strict_faults=strict_faults)
    _announce(cfg, dcfg, spec, plan, say)
    start = plan.points[0]
    with DemoStack(dcfg, start, plan.capacity, endpoint, say) as ds:
        ds.home_and_arm(float(cfg.faults.arm_timeout_s))
        say(f"homed at ({start[0]:g}, {start[1]:g}, {start[2]:g}) m and armed: HOLDING")
        t0 = time.monotonic()
        settled = _lap(ds, spec, plan, say)
        wall_s = time.monotonic() - t0
        _result(ds.controller.submit(Disarm()), 3.0, "disarm")
    return _circle_run(cfg, spec, plan, ds, settled, wall_s)


def _circle_run(
    cfg: Any, spec: CircleSpec, plan: CirclePlan, ds: DemoStack, settled: list[int], wall_s: float
) -> CircleRun:
    """The `CircleRun` of a finished lap (`ds` stopped): the recorder's rows split into arrays
    (times from the first settled sample), the reels' largest turns and slopes, the robot's
    shape."""
    from controller.cli.shape import ShapeError

    data = ds.recorder.rows()
    reels = list(ds.controller.reels)
    n = len(cfg.reels)
    i0 = settled[0]
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
    notes = list(ds.notes)
    try:
        shape: RobotShape | None = RobotShape.from_summary(cfg.summary())
    except ShapeError as exc:
        shape = None
        notes.append(f"no robot drawn: {exc}")
    return CircleRun(
        robot=str(cfg.name),
        spec=spec,
        speed_mps=plan.speed_mps,
        rate_hz=plan.rate_hz,
        anchors_m=np.asarray(cfg.geometry.anchors_m, dtype=np.float64),
        points_m=np.asarray(plan.points, dtype=np.float64),
        t_s=data[:, 0] - data[i0, 0],
        setpoint_m=data[:, 1:4].copy(),
        fpk_m=data[:, 4:7].copy(),
        residual_m=data[:, 7].copy(),
        valid=data[:, 8] > 0.5,
        state=[_STATE_NAMES[c] if 0 <= c < len(_STATE_NAMES) else "?" for c in codes],
        lengths_m=lengths.copy(),
        settled_index=np.asarray(settled, dtype=np.int64),
        turns_max_abs_rev=turns_max,
        reel_slope_m_per_rev=slopes,
        zenoh=ds.zenoh_text,
        wall_s=wall_s,
        overruns=int(ds.controller.loop_stats.overruns),
        ticks=int(ds.controller.ticks),
        dropped_rows=ds.recorder.dropped,
        shape=shape,
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


def circle_trace(run: CircleRun) -> Trace:
    """The run as `cablebot plot` draws it: from the first settled sample on, the set-point
    of every tick, and the circle's points as waypoints (the figures then go by step)."""
    i0 = int(run.settled_index[0])
    spec = run.spec
    return Trace(
        title=(
            f"{run.robot!r}, circle of radius {spec.radius_m:g} m about "
            f"({spec.centre_m[0]:g}, {spec.centre_m[1]:g}) at z = {spec.z_m:g} m, "
            f"{spec.steps} steps"
        ),
        t_s=run.t_s[i0:],
        position_m=run.fpk_m[i0:],
        lengths_m=run.lengths_m[i0:],
        residual_m=run.residual_m[i0:],
        state=run.state[i0:],
        status_t_s=run.t_s[i0:],
        setpoint_m=run.setpoint_m[i0:],
        status_position_m=run.fpk_m[i0:],
        setpoint_source="every tick",
        shape=run.shape,
        waypoints=Waypoints(
            run.points_m,
            run.settled_index - i0,
            step_label=f"step ({360.0 / spec.steps:g} degrees each)",
        ),
        notes=list(run.notes),
    )


def plot_circle(run: CircleRun, out_dir: Path) -> list[Path]:
    """Write the four PNG figures (`PLOT_FILES`) into `out_dir` with `cablebot plot`'s
    drawing, and return their paths.

    Raises ImportError without matplotlib (the `plot` extra), OSError if a file cannot be
    written.
    """
    return plot_trace(circle_trace(run), out_dir, PLOT_NAME)


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
            paths = plot_circle(run, Path(args.plot))
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
            + f", and the simulated drives' watchdog to {DEMO_SIM_WATCHDOG_FLOOR_S:g} s)"
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
