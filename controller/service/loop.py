"""The control step: one `Controller` owns the states, faults, commands and the tick.

Every tick (`Controller.tick`): poll the bus without blocking, read the axes, check staleness,
heartbeats and axis errors, turn motor turns into cable lengths, solve the pose by FPK, take
queued commands, advance the motion planner, check the limits, solve the set-point's cable
lengths by IPK, check the cable speeds, command the motors and publish the pose
(`controller.service.pose`). A `controller.service.runner.Runner` (`Controller.runner`) calls
`tick` against absolute deadlines on the monotonic clock; its figures are in
`status()["loop"]`.

Velocity feed-forward: every set-point goes out with the motor velocity that follows it, so an
ODrive in position control + passthrough (vel_cmd = vel_ff + pos_gain * position error) tracks a
moving set-point without the steady lag velocity / pos_gain. The set-point velocity v (the
planner's) maps to cable length rates dL_i/dt = u_i . v, with u_i the unit vector from anchor i to
the set-point, and to motor rev/s through the reel model's slope at the commanded turns. It is
zero while holding and in FAULT (the hold re-sends the last good position with no feed-forward).

Stalls: the planner advances by the elapsed time, but by at most `MAX_PLANNER_DT_PERIODS` loop
periods per tick. After a CPU stall the motion therefore resumes where it was (it runs a little
slower in wall time) instead of jumping ahead by the whole gap, which the reels could not follow
and which would trip the cable-speed check; `status()["loop"]["dt_clamped"]` counts such ticks.

Threading: the loop thread calls `tick` (through the runner) and is the only one that touches
the driver.
Other threads (Zenoh, the daemon) use `submit`, `submit_setpoint`, `submit_velocity`,
`request_estop` and `status`, which are thread-safe.

Safety: on FAULT the motors keep receiving the last good set-point (a suspended load must not
fall); nothing non-finite is ever commanded (a non-finite set-point is itself a fault); e-stop
is taken at the start of the next tick, ahead of every queued command.

Commands: which verbs each state accepts is `controller.core.states.COMMAND_RULES`, asked for every
command and every streamed set-point. A set-point is taken only while HOLDING or MOVING and only
within the armed session it arrived in: one that arrives while disarmed, arming, in FAULT or
ESTOPPED is discarded (counted in `status()["stream"]["discarded"]`), so arming always starts
by holding the measured pose.

Limits: `controller.core.workspace.Workspace` (`self.workspace`) decides every target, point,
leg, cable length and cable speed. Paths: a move or path is checked against it and prepared
(speed, repeated points) in the thread that submits it, vectorised (`path_failure`); the tick
only checks the first leg from where the set-point comes to rest and hands the prepared points
to the planner, which builds each leg when it reaches it. A path of any length costs the tick
the same.

Velocity input (`submit_velocity`, a joystick's `<prefix>/velocity` samples) follows the same
rules (latest wins, taken only while HOLDING or MOVING and within its armed session, otherwise
discarded and counted in `status()["velocity"]["discarded"]`) and is flown by the planner's
velocity mode (`controller.core.motion`): max speed and acceleration, the braking look-ahead
against the workspace (`Workspace.check_segment`, the point and cable-length checks a streamed
target gets, plus the shortest cable along the way; with `[payload]` also the tension rule at
points along it: `_check_segment`), and the dead-man `limits.velocity_timeout_s`
counted in planner time (after a stall the robot has moved only as far as the planner advanced).
A non-zero sample takes over from a move or path; a zero one does not stop it.

Axes: the step sees every drive family alike, through the generic status of its readings
(`drivers.base.AxisReading`: `ready`, `fault`, `state_name`, stamps); "closed loop" here means
`ready` (ODrive: CLOSED_LOOP_CONTROL without an error; CiA 402: Operation enabled), and fault
reasons name the drive's state and fault as the driver does (e.g. `axis_error: node 2
ESTOP_REQUESTED (0x2000000)`, `axis_state: node 1 left closed loop (IDLE)`).

E-stop confirmation: after an e-stop every axis must report, by a heartbeat newer than the
e-stop, that it left closed loop within `ESTOP_CONFIRM_S`. An axis that does not is named in the
state reason (`estop_unconfirmed: ...`, published on `<prefix>/state`) and in
`status()["estop"]`, and the Estop is sent again with an IDLE request every `ESTOP_CONFIRM_S`
until every axis complies (a node that ignores Estop may still obey IDLE).
"""

from __future__ import annotations

import concurrent.futures
import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from controller.core import kinematics
from controller.core.commands import (
    Arm,
    Command,
    CommandRefused,
    Disarm,
    Estop,
    Home,
    Move,
    Path,
    Pretension,
    Reset,
    Setpoint,
    Stop,
    Vec3,
    Velocity,
)
from controller.core.motion import MotionPlanner, check_speed, dedupe_path
from controller.core.pretension import PretensionRun
from controller.core.reel import ReelModel
from controller.core.states import ARMED_STATES, State, check_transition, refusal
from controller.core.statics import SINGULAR_ROW, StaticsError, TensionCheck
from controller.core.workspace import Workspace, points_array
from controller.service.cables import CableModel
from controller.service.config import RobotConfig, tension_check
from controller.service.pose import NullPublisher, PoseSample, Publisher
from controller.service.runner import SPIN_S, LoopStats, Runner
from drivers.base import AxisReading, BusError, ReelDriver, TorqueDriver

log = logging.getLogger("cablebot.loop")

COMMAND_QUEUE_SIZE = 32
ESTOP_CONFIRM_S = 0.2
"""Every axis must confirm leaving closed loop this soon after an e-stop (module docstring)."""
MAX_PLANNER_DT_PERIODS = 4.0
"""The planner advances at most this many loop periods per tick (see the module docstring)."""
TENSION_SAMPLE_FRACTION = 0.01
"""A move's or path's legs are checked for tensions at points this fraction of the anchors'
span apart (the tick checks every set-point on them too)."""
TENSION_MAX_SAMPLES = 200_000
"""At most this many tension samples per command (the spacing grows to fit)."""
_MAX_COMMANDS_PER_TICK = 8


# --------------------------------------------------------------------------------------------
# The controller


class _Fault(Exception):
    """Raised inside the tick to abort the step and enter FAULT with `reason`."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True, slots=True)
class _Motion:
    """A move or path checked and prepared outside the tick (see `Controller._prepare_motion`)."""

    points_m: tuple[Vec3, ...]
    """The points, consecutive repeats dropped."""
    speed_mps: float
    """The speed to run at (the requested one, limited to the maximum)."""
    limited_to_mps: float | None
    """The maximum speed, when the requested one was above it."""
    refusal: str | None
    """Why the command is refused whatever the state (a point or leg outside the limits, a
    speed below the minimum), or None."""


_VERBS: Mapping[type, str] = {
    Move: "move",
    Path: "path",
    Stop: "stop",
    Estop: "estop",
    Arm: "arm",
    Disarm: "disarm",
    Reset: "reset",
    Home: "home",
    Pretension: "pretension",
    Setpoint: "setpoint",
    Velocity: "velocity",
}

_Pending = tuple[Command, "concurrent.futures.Future[dict[str, Any]]", _Motion | None]


class Controller:
    """The cable robot's controller: states, faults, commands, motion and the control step.

    `cfg` is a `controller.service.config.RobotConfig`; `driver` a `drivers.base.ReelDriver` whose
    `node_ids` are those of `cfg.reels`, in the same order. `offsets_rev` (node id -> motor
    offset) overrides the state file. `clock` and `sleep` are those of `runner`. Raises
    ValueError if the driver's axes do not match.
    """

    def __init__(
        self,
        cfg: RobotConfig,
        driver: ReelDriver,
        publisher: Publisher | None = None,
        *,
        clock: Callable[[], float] = time.monotonic,
        wall_clock_ns: Callable[[], int] = time.time_ns,
        offsets_rev: Mapping[int, float] | None = None,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.cfg = cfg
        self._sleep = sleep
        self.driver = driver
        self.publisher: Publisher = publisher if publisher is not None else NullPublisher()
        self._clock = clock
        self._wall_ns = wall_clock_ns
        node_ids = tuple(int(r.node_id) for r in cfg.reels)
        if tuple(driver.node_ids) != node_ids:
            raise ValueError(f"driver node ids {driver.node_ids} != config {node_ids}")
        self.node_ids = node_ids
        self.n = len(node_ids)
        self.geometry = cfg.geometry
        self._anchors: tuple[tuple[float, float, float], ...] = tuple(
            (float(a[0]), float(a[1]), float(a[2])) for a in self.geometry.anchors_m
        )
        self.period_s = 1.0 / float(cfg.loop.rate_hz)
        self._max_plan_dt_s = MAX_PLANNER_DT_PERIODS * self.period_s
        self.publish_every = max(1, int(cfg.loop.publish_every))
        # Immutable: read from any thread (the Zenoh interface pre-checks commands with it).
        self.workspace = Workspace.from_limits(cfg.limits, self.geometry)
        self._default_speed_mps = min(
            float(cfg.limits.default_speed_mps),
            float(cfg.limits.max_speed_mps),
        )
        self.planner = MotionPlanner(
            cfg.limits.max_speed_mps,
            cfg.limits.max_accel_mps2,
            self._default_speed_mps,
            velocity_timeout_s=cfg.limits.velocity_timeout_s,
            check_segment=self._check_segment,
        )
        f = cfg.faults
        self._stale_s = float(f.stale_timeout_s)
        self._hb_timeout_s = float(f.heartbeat_timeout_s)
        self._residual_max_m = float(f.residual_max_m)
        self._tracking_max_m = float(f.tracking_max_m)
        self._arm_timeout_s = float(f.arm_timeout_s)
        self._bus_err_timeout_s = float(f.bus_error_timeout_s)
        self._bus_err_since_s: float | None = None

        # Statics: the tension rule for commands and set-points, the planned and measured tensions.
        self.tension: TensionCheck | None = (
            None
            if cfg.tension is None or cfg.payload is None
            else tension_check(cfg.payload, cfg.tension, cfg.geometry)
        )
        self.cables = CableModel.from_config(cfg, self.tension)
        """Rigid or stretching cables: homing lengths, commanded lengths (IPK), pose (FPK)."""
        span = max(math.dist(a, b) for a in self._anchors for b in self._anchors)
        self._tension_step_m = TENSION_SAMPLE_FRACTION * span
        self.planned_tensions_n: tuple[float, ...] | None = None
        """Tensions that hold the payload at the last good set-point (None: not known)."""
        self.planned_margin_n: float | None = None
        self._planned_at: Vec3 | None = None
        self._measure = cfg.loop.torque_telemetry != "off"
        self.measured_tensions_n: list[float | None] = [None] * self.n
        """Tensions from the motors' torque telemetry (None: no fresh reading)."""
        self._slack_n = f.slack_tension_n
        self._over_n = None if cfg.tension is None else cfg.tension.max_n
        self._tension_time_s = float(f.slack_time_s)
        self._slack_since: list[float | None] = [None] * self.n
        self._over_since: list[float | None] = [None] * self.n

        self._base_reels: tuple[ReelModel, ...] = tuple(r.reel for r in cfg.reels)
        self.reels: list[ReelModel] = list(self._base_reels)
        self.homed = False
        self.home_source = "none"
        self._state_file: str | None = cfg.homing.state_file
        self._power_up: Vec3 | None = (
            None
            if cfg.homing.power_up_position_m is None
            else tuple(float(v) for v in cfg.homing.power_up_position_m)  # type: ignore[assignment]
        )
        if offsets_rev is not None:
            self._apply_offsets(offsets_rev, "given")
        elif self._state_file:
            self._load_state_file()

        self.state = State.DISARMED
        self.reason: str | None = None
        self.state_stamp_ns = self._wall_ns()
        self._queue: queue.Queue[_Pending] = queue.Queue(maxsize=COMMAND_QUEUE_SIZE)
        self._estop_futures: list[concurrent.futures.Future[dict[str, Any]]] = []
        self._estop_lock = threading.Lock()
        self._estop_flag = False
        self._stream_target: tuple[Vec3, int] | None = None
        """The latest streamed set-point and the armed session (`_arm_epoch`) it arrived in."""
        self._arm_epoch = 0
        """Counts `arm` commands taken: a set-point from an earlier session is discarded."""
        self.stream_refused = 0
        self.stream_last_refusal: str | None = None
        self.stream_discarded = 0
        """Set-points discarded because the state takes none (written by the submitting thread)."""
        self._velocity_cmd: tuple[Vec3, int] | None = None
        """The latest velocity sample and the armed session it arrived in (like a set-point)."""
        self.velocity_discarded = 0
        """Velocity samples discarded: not armed when sent, or from an earlier armed session."""
        self._estop_at_s = 0.0
        self._estop_check_s = 0.0
        self._estop_confirmed = True
        self._estop_unconfirmed: tuple[int, ...] = ()
        self.estop_repeats = 0

        # Per-tick working values (the last tick's).
        self.lengths_m: list[float] = [math.nan] * self.n
        self._fpk_lengths_m: list[float] = [math.nan] * self.n
        """The lengths the current pose was solved from (NaN: none yet)."""
        self.fpk_solves = 0
        self.pose_m: Vec3 | None = None
        self.residual_m: float | None = None
        self.pose_valid = False
        self.pose_stamp_ns = 0
        """Wall-clock arrival time of the newest encoder reading the pose came from."""
        self.setpoint_m: Vec3 | None = None
        """Set-point commanded on the last good tick (the hold set-point in FAULT)."""
        self.setpoint_lengths_m: tuple[float, ...] | None = None
        self.commanded_rev: list[float] | None = None
        """Last good motor set-points; re-sent every tick in FAULT."""
        self.commanded_ff_rps: list[float] = [0.0] * self.n
        """Velocity feed-forward sent with the last set-point (motor rev/s)."""
        self._zero_ff: tuple[float, ...] = (0.0,) * self.n
        self.dt_clamped = 0
        """Ticks whose planner step was cut to MAX_PLANNER_DT_PERIODS periods (stalls)."""
        self._arm_start_s = 0.0
        self._arm_rev: list[float] | None = None
        self._last_tick_s: float | None = None
        self._bus_errors_seen = driver.stats.bus_errors
        self.seq = 0
        self.ticks = 0
        self.command_errors = 0
        self.hold_failures = 0

        self.loop_stats = LoopStats()
        """The figures of the runner that calls `tick` (`runner`), reported in `status()`."""
        self._pretension: PretensionRun | None = None
        """The pre-tension in progress (PRETENSIONING), else None."""
        self._pretension_at: Vec3 = (0.0, 0.0, 0.0)
        self._torque_driver: TorqueDriver | None = None
        """The driver as a `TorqueDriver`, from the first pre-tension on."""
        self._pt_lengths_m: list[float] = [0.0] * self.n
        self._pt_rates_mps: list[float] = [0.0] * self.n
        self._pt_torques_nm: list[float] = [0.0] * self.n
        self.pretension_result: dict[str, Any] | None = None
        """How the last pre-tension ended (None: none has ended since start-up)."""
        self._save_threads: list[threading.Thread] = []
        self._closing = False
        """Set by `begin_shutdown`: no new motion is taken."""

    # ---------------------------------------------------------------- homing / offsets

    def _apply_offsets(self, offsets_rev: Mapping[int, float], source: str) -> None:
        """Use motor offsets (node id -> offset_rev) for the reel models; marks homed."""
        models = []
        for nid, base in zip(self.node_ids, self._base_reels, strict=True):
            off = float(offsets_rev[nid])
            if not math.isfinite(off):
                raise ValueError(f"offset of node {nid} is not finite")
            models.append(_with_offset(base, off))
        self.reels = models
        self.homed = True
        self.home_source = source

    def _load_state_file(self) -> None:
        from controller.service import offsets as homing  # lazily: only with a state file

        assert self._state_file is not None
        try:
            data = homing.load_offsets(self._state_file)
        except Exception as exc:  # a broken file must not stop the daemon; stay unhomed
            log.error("homing state file %s unusable: %s", self._state_file, exc)
            return
        if data is None:
            log.info("no homing state file at %s", self._state_file)
            return
        try:
            rec = homing.parse_record(data, self._state_file, self.cfg.name, self.node_ids)
        except homing.HomingError as exc:
            log.warning("homing state file ignored: %s", exc)
            return
        offsets = rec.offsets_rev
        self._apply_offsets(offsets, "state_file")
        log.info("homing offsets loaded from %s", self._state_file)

    def _home_at(self, readings: Sequence[AxisReading], position_m: Vec3) -> tuple[float, ...]:
        """Set the reel offsets so that the current readings map to `position_m`; the pose is
        `position_m` from now on (not from the next tick's solve: a status read in between
        must not show the pose of the old offsets under the new home)."""
        lengths = self.cables.home_lengths_m(position_m)
        self.reels = [
            base.with_home(r.position_rev, L)
            for base, r, L in zip(self._base_reels, readings, lengths, strict=True)
        ]
        self.homed = True
        self.lengths_m[:] = [float(v) for v in lengths]
        self._fpk_lengths_m[:] = self.lengths_m
        self.pose_m = (float(position_m[0]), float(position_m[1]), float(position_m[2]))
        self.residual_m = 0.0
        return tuple(m.offset_rev for m in self.reels)

    # ---------------------------------------------------------------- thread-safe API

    def submit(self, cmd: Command) -> concurrent.futures.Future[dict[str, Any]]:
        """Queue `cmd` for the loop; the future resolves with a reply dict or CommandRefused.

        Estop bypasses the queue (it is never refused as busy). A full queue refuses at once
        with CommandRefused("busy"). Setpoint and Velocity commands go to `submit_setpoint` /
        `submit_velocity`.
        """
        fut: concurrent.futures.Future[dict[str, Any]] = concurrent.futures.Future()
        if isinstance(cmd, Estop):
            with self._estop_lock:
                self._estop_futures.append(fut)
                self._estop_flag = True
            return fut
        if isinstance(cmd, Setpoint | Velocity):
            try:
                if isinstance(cmd, Setpoint):
                    why = self._offer_setpoint(cmd.position_m)
                else:
                    why = self._offer_velocity(cmd.velocity_mps)
            except ValueError as exc:
                why = str(exc)
            if why is None:
                fut.set_result({"ok": True})
            else:
                fut.set_exception(CommandRefused(why))
            return fut
        motion = None
        if isinstance(cmd, Move | Path):
            # Here, in the submitting thread: O(number of points), so never in the tick.
            motion = self._prepare_motion(cmd)
        try:
            self._queue.put_nowait((cmd, fut, motion))
        except queue.Full:
            fut.set_exception(CommandRefused("busy: command queue full"))
        return fut

    def request_estop(self) -> None:
        """Ask for an e-stop at the start of the next tick (thread-safe, never blocks)."""
        with self._estop_lock:
            self._estop_flag = True

    def submit_setpoint(self, position_m: Sequence[float]) -> None:
        """Stream a target position; the latest one wins, validated and limited in the tick.

        Taken only while HOLDING or MOVING (`COMMAND_RULES`); otherwise discarded and counted.
        Raises ValueError/TypeError/IndexError for a position that is not three numbers.
        """
        self._offer_setpoint(position_m)

    def _offer_setpoint(self, position_m: Sequence[float]) -> str | None:
        """Store a streamed set-point for the tick, or return why the state discards it."""
        p = (float(position_m[0]), float(position_m[1]), float(position_m[2]))
        # Read the session before the state: if the state then says armed, the session read is
        # that one or an earlier one (discarded by the tick), never a later one.
        epoch = self._arm_epoch
        state = self.state
        why = refusal(state, "setpoint")
        if why is not None:
            self.stream_discarded += 1
            return self._refusal_text(state, why)
        self._stream_target = (p, epoch)  # one reference assignment: atomic
        return None

    def submit_velocity(self, velocity_mps: Sequence[float]) -> None:
        """Velocity input: fly at `velocity_mps` (latest wins; see the module docstring).

        Taken only while HOLDING or MOVING (`COMMAND_RULES`); otherwise discarded and counted.
        Raises ValueError/TypeError/IndexError for a velocity that is not three finite numbers.
        """
        self._offer_velocity(velocity_mps)

    def _offer_velocity(self, velocity_mps: Sequence[float]) -> str | None:
        """Store a velocity sample for the tick, or return why the state discards it."""
        v = (float(velocity_mps[0]), float(velocity_mps[1]), float(velocity_mps[2]))
        if not (math.isfinite(v[0]) and math.isfinite(v[1]) and math.isfinite(v[2])):
            raise ValueError(f"velocity_mps must be finite, got {list(v)}")
        epoch = self._arm_epoch  # before the state: see `_offer_setpoint`
        state = self.state
        why = refusal(state, "velocity")
        if why is not None:
            self.velocity_discarded += 1
            return self._refusal_text(state, why)
        self._velocity_cmd = (v, epoch)  # one reference assignment: atomic
        return None

    def _prepare_motion(self, cmd: Move | Path) -> _Motion:
        """Check a move's or path's points, legs and speed and prepare them for the planner.

        Reads only immutable limits and configuration: safe in any thread. Vectorised over the
        points; the leg from where the set-point comes to rest to the first point depends on
        the state and is checked in the tick. Raises nothing (a problem becomes `refusal`).
        """
        limited: float | None = None
        if cmd.speed_mps is None:
            speed = self._default_speed_mps
        else:
            why = check_speed(cmd.speed_mps)
            if why is not None:
                return _Motion((), 0.0, None, f"speed_mps: {why}")
            speed = float(cmd.speed_mps)
            vmax = float(self.cfg.limits.max_speed_mps)
            if speed > vmax:
                speed = limited = vmax
        if isinstance(cmd, Move):
            points: Sequence[Vec3] = (cmd.position_m,)
        else:
            points = cmd.points_m
        try:
            arr = points_array(points) if len(points) > 1 else None
            failure = self.workspace.path_failure(points, array=arr)
            if failure is None and self.tension is not None:
                failure = self._tension_failure(points, None)
            if failure is not None:
                i, why = failure
                where = "target" if isinstance(cmd, Move) else f"points_m[{i}]"
                return _Motion((), speed, limited, f"{where} {_fmt(points[i])}: {why}")
            if (
                arr is not None
                and type(points) is tuple
                and bool(np.all(np.any(arr[1:] != arr[:-1], axis=1)))
            ):
                pts: tuple[Vec3, ...] = points  # checked finite, no repeats: as it is
            else:
                pts = dedupe_path(points)
        except Exception as exc:  # e.g. a malformed point built in code: refuse, do not raise
            return _Motion((), speed, limited, f"invalid points: {exc}")
        return _Motion(pts, speed, limited, None)

    # ---------------------------------------------------------------- state changes

    def _set_state(self, new: State, reason: str | None = None) -> None:
        if new is self.state:
            return
        check_transition(self.state, new)
        old = self.state
        self.state = new
        self.reason = reason
        self.state_stamp_ns = self._wall_ns()
        if new is State.FAULT or new is State.ESTOPPED:
            log.error("state %s -> %s: %s", old.value, new.value, reason)
        else:
            log.info("state %s -> %s%s", old.value, new.value, f": {reason}" if reason else "")
        try:
            self.publisher.publish_state(new.value, reason, self.state_stamp_ns)
        except Exception:
            log.exception("publish_state failed")

    def _set_reason(self, reason: str) -> None:
        """Change the reason of the current state and publish it (same state, new reason)."""
        self.reason = reason
        log.error("state %s: %s", self.state.value, reason)
        try:
            self.publisher.publish_state(self.state.value, reason, self._wall_ns())
        except Exception:
            log.exception("publish_state failed")

    def _fault(self, reason: str) -> None:
        """Enter FAULT (from an armed, arming or pretensioning state); the last good set-point
        stays commanded (after a pre-tension: the turns where the reels were)."""
        if self.state in (State.ARMING, State.HOLDING, State.MOVING, State.PRETENSIONING):
            if self._end_pretension() is not None:
                self.pretension_result = {"ok": False, "reason": reason}
            self._set_state(State.FAULT, reason)
            self.planner_hold()
            self.commanded_ff_rps = list(self._zero_ff)  # the hold has no feed-forward
            self._stream_target = None
            self._velocity_cmd = None

    def planner_hold(self) -> None:
        """Put the planner on hold at the last good set-point (no further motion)."""
        if self.setpoint_m is not None:
            self.planner.hold(self.setpoint_m)

    # ---------------------------------------------------------------- the tick

    def tick(self, now_s: float) -> None:
        """Do exactly one control step at clock time `now_s` (see the module docstring).

        Never raises for faults of the robot; they become the FAULT state.
        """
        dt = self.period_s if self._last_tick_s is None else now_s - self._last_tick_s
        if not (dt > 0.0):
            dt = self.period_s
        self._last_tick_s = now_s
        self.ticks += 1
        drv = self.driver

        if self._estop_flag:
            self._do_estop(now_s)

        try:
            drv.poll()
        except Exception as exc:  # the contract says poll never raises; be safe anyway
            self._fault(f"bus_error: poll: {exc}")
        readings = drv.read()
        state = self.state

        try:
            if state is State.HOLDING or state is State.MOVING:
                self._check_axes(readings, now_s)
            be = drv.stats.bus_errors
            if be != self._bus_errors_seen:
                self._bus_errors_seen = be
                self._bus_errors_persist(now_s, state)
            else:
                self._bus_err_since_s = None
            self._solve_pose(readings, now_s)
            if self._measure:
                self._measure_tensions(readings, now_s, state)
        except _Fault as f:
            self._fault(f.reason)

        if self._queue.queue:  # lock-free peek at the deque; get_nowait() takes the lock
            self._take_commands(readings, now_s)

        state = self.state
        if state is State.ARMING:
            try:
                self._tick_arming(readings, now_s)
            except _Fault as f:
                self._fault(f.reason)
        elif state is State.HOLDING or state is State.MOVING:
            try:
                self._tick_armed(dt)
            except _Fault as f:
                self._fault(f.reason)
        elif state is State.PRETENSIONING:
            try:
                self._tick_pretension(readings, now_s)
            except _Fault as f:
                self._fault(f.reason)
        if self.state is State.FAULT:
            self._hold_last()
        elif self.state is State.ESTOPPED and not self._estop_confirmed:
            self._confirm_estop(readings, now_s)

        if self.ticks % self.publish_every == 0:
            self._publish_pose()

    def _bus_errors_persist(self, now_s: float, state: State) -> None:
        """New bus errors this tick: fault (when armed or arming) once they have gone on for
        `faults.bus_error_timeout_s`. One lost frame at the loop rate is harmless (the ODrive
        keeps its last set-point), a bus-off or a dead link is not."""
        since = self._bus_err_since_s
        if since is None:
            self._bus_err_since_s = since = now_s
        if (state in ARMED_STATES or state is State.ARMING) and (
            now_s - since >= self._bus_err_timeout_s
        ):
            raise _Fault(
                f"bus_error: {self.driver.stats.last_error} (failing for {now_s - since:.3f} s)"
            )

    def _check_axes(
        self, readings: Sequence[AxisReading], now_s: float, *, ready: bool = True
    ) -> bool:
        """Armed: every axis without a fault, fresh, and (with `ready`) ready (the drives'
        generic status); _Fault naming the first that is not. Returns whether every axis is
        ready."""
        stale = self._stale_s
        hb = self._hb_timeout_s
        all_ready = True
        for r in readings:
            if r.fault is not None:
                raise _Fault(f"axis_error: node {r.node_id} {r.fault}")
            if now_s - r.stamp_s > stale:
                raise _Fault(f"stale_encoder: node {r.node_id} age {now_s - r.stamp_s:.3f} s")
            if now_s - r.heartbeat_stamp_s > hb:
                raise _Fault(
                    f"stale_heartbeat: node {r.node_id} age {now_s - r.heartbeat_stamp_s:.3f} s"
                )
            if not r.ready:
                if ready:
                    raise _Fault(f"axis_state: node {r.node_id} left closed loop ({r.state_name})")
                all_ready = False
        return all_ready

    def _solve_pose(self, readings: Sequence[AxisReading], now_s: float) -> None:
        """Lengths from the encoders, then the pose by FPK (invalid when unhomed or unheard)."""
        lengths = self.lengths_m
        if not self.homed:
            if self._power_up is not None and all(
                now_s - r.stamp_s <= self._stale_s for r in readings
            ):
                self._home_at(readings, self._power_up)
                self.home_source = "power_up"
                log.info("homed at the configured power-up pose %s", _fmt(self._power_up))
            else:
                self.pose_valid = False
                return
        newest_ns = 0
        for i, r in enumerate(readings):
            if r.stamp_ns > newest_ns:
                newest_ns = r.stamp_ns
            lengths[i] = (
                self.reels[i].length_m(r.position_rev) if r.stamp_s > -math.inf else math.nan
            )
        self.pose_stamp_ns = newest_ns
        if not all(map(math.isfinite, lengths)):
            self.pose_valid = False
            return
        stale = self._stale_s
        for r in readings:
            if now_s - r.stamp_s > stale:
                # Old encoder data is no pose (armed states have faulted on it already).
                self.pose_valid = False
                return
        pose = self.pose_m
        residual = self.residual_m
        if (
            pose is None
            or residual is None
            or not self.pose_valid
            or lengths != self._fpk_lengths_m
            or self.cables.measured  # the measured tensions move the pose too
        ):
            # New encoder data (at 1 kHz with 2 ms broadcasts, every other tick has none):
            # solve; otherwise the pose of the same lengths is the one already solved.
            try:
                pose, residual = self.cables.pose(
                    lengths, pose, self.measured_tensions_n if self._measure else None
                )
            except kinematics.KinematicsError as exc:
                self.pose_valid = False
                if self.state is not State.DISARMED and self._pretension is None:
                    raise _Fault(f"fpk_unreachable: {exc}") from None
                return
            self.pose_m = pose
            self.residual_m = residual
            self._fpk_lengths_m[:] = lengths
            self.fpk_solves += 1
        ok = all(map(math.isfinite, pose)) and math.isfinite(residual)
        self.pose_valid = ok
        if not ok:
            raise _Fault("fpk_unreachable: non-finite solution")
        if (
            residual > self._residual_max_m
            and self.state is not State.DISARMED
            and self._pretension is None  # slack cables are what a pre-tension takes up
        ):
            raise _Fault(
                f"residual: {residual * 1e3:.1f} mm > {self._residual_max_m * 1e3:.1f} mm"
                " (slack or slipped cable)"
            )
        sp = self.setpoint_m
        if sp is not None and self.state in ARMED_STATES:
            p = pose
            err = math.sqrt((p[0] - sp[0]) ** 2 + (p[1] - sp[1]) ** 2 + (p[2] - sp[2]) ** 2)
            if err > self._tracking_max_m:
                raise _Fault(
                    f"tracking_error: {err * 1e3:.1f} mm > {self._tracking_max_m * 1e3:.1f} mm"
                )

    def _tick_arming(self, readings: Sequence[AxisReading], now_s: float) -> None:
        fresh = all(r.stamp_s >= self._arm_start_s for r in readings)
        if self._arm_rev is None and fresh:
            self._arm_rev = [r.position_rev for r in readings]
            self.commanded_rev = self._arm_rev  # what a FAULT during arming keeps holding
        if self._arm_rev is not None:
            # Hold the motors where they were while they enter closed loop.
            self._send(self._arm_rev)
        closed = all(
            r.ready and r.fault is None and r.heartbeat_stamp_s >= self._arm_start_s
            for r in readings
        )
        if closed and fresh and self.pose_valid and self.pose_m is not None:
            self.commanded_rev = list(self._arm_rev) if self._arm_rev is not None else None
            self._hold_at(self.pose_m)
            self._set_state(State.HOLDING)
            return
        if now_s - self._arm_start_s > self._arm_timeout_s:
            bad = [
                f"node {r.node_id} ({r.state_name}"
                f"{'' if r.fault is None else ', ' + r.fault}"
                f"{', no encoder' if r.stamp_s < self._arm_start_s else ''})"
                for r in readings
                if not r.ready or r.fault is not None or r.stamp_s < self._arm_start_s
            ]
            why = ", ".join(bad) if bad else "no valid pose"
            self._fault(f"arm_timeout: {why}")

    def _hold_at(self, p: Vec3) -> None:
        """Hold at `p`; _Fault if the payload cannot be held there (the tension rule)."""
        self.planner.hold(p)
        self.setpoint_m = p
        self.setpoint_lengths_m = None
        if self.tension is not None:
            self._plan_tensions(p)

    def _tick_armed(self, dt: float) -> None:
        if dt > self._max_plan_dt_s:
            dt = self._max_plan_dt_s  # after a stall: resume, do not jump (module docstring)
            self.dt_clamped += 1
        item = None if self._closing else self._stream_target
        if item is not None:
            self._stream_target = None
            target, epoch = item
            if epoch != self._arm_epoch:
                reason: str | None = "set-point from before the last `arm` discarded"
            else:
                reason = self._check_target(target)
            if reason is None:
                self.planner.stream(target)
                if self.state is State.HOLDING:
                    self._set_state(State.MOVING, "stream")
            else:
                self.stream_refused += 1
                self.stream_last_refusal = reason
        vel = None if self._closing else self._velocity_cmd
        if vel is not None:
            self._velocity_cmd = None
            if vel[1] != self._arm_epoch:
                self.velocity_discarded += 1  # sent in an earlier armed session
            elif (
                self.planner.command_velocity(vel[0])
                and self.state is State.HOLDING
                and self.planner.moving
            ):
                self._set_state(State.MOVING, "velocity")
        sp = self.planner.advance(dt)
        sp = (float(sp[0]), float(sp[1]), float(sp[2]))
        if not (math.isfinite(sp[0]) and math.isfinite(sp[1]) and math.isfinite(sp[2])):
            raise _Fault(f"nan_setpoint: planner gave {sp}")
        reason = self.workspace.check_point(sp)
        if reason is not None:
            raise _Fault(f"limit: set-point {_fmt(sp)}: {reason}")
        try:
            lengths = tuple(kinematics.ipk_point(self.geometry, sp))
        except kinematics.KinematicsError as exc:
            raise _Fault(f"ipk: {exc}") from None
        reason = self.workspace.check_lengths(lengths)
        if reason is not None:
            raise _Fault(f"limit: {reason}")
        if self.tension is not None and sp != self._planned_at:
            self._plan_tensions(sp)
        try:
            paid = self.cables.commanded_lengths_m(lengths, self.planned_tensions_n)
        except kinematics.KinematicsError as exc:
            raise _Fault(f"ipk: {exc}") from None
        prev = self.setpoint_lengths_m
        if prev is not None:
            reason = self.workspace.check_cable_speeds(prev, lengths, dt)
            if reason is not None:
                raise _Fault(f"cable_speed: {reason}")
        reels = self.reels
        rev = [reels[i].position_rev(paid[i]) for i in range(self.n)]
        ff = self._velocity_ff(sp, self.planner.velocity_mps, lengths, rev)
        self._send(rev, ff)
        self.commanded_rev = rev
        self.commanded_ff_rps = ff
        self.setpoint_m = sp
        self.setpoint_lengths_m = lengths
        if self.state is State.MOVING and not self.planner.moving:
            self._set_state(State.HOLDING)

    def _plan_tensions(self, sp: Vec3) -> None:
        """The tensions that hold the payload at set-point `sp`; _Fault if they break the
        tension rule (limits and margin). A held set-point is solved once."""
        assert self.tension is not None
        try:
            res = self.tension.solve(sp)
        except StaticsError as exc:
            raise _Fault(f"tension: set-point {_fmt(sp)}: {exc}") from None
        reason = self.tension.reason(res)
        if reason is not None:
            raise _Fault(f"tension: set-point {_fmt(sp)}: {reason}")
        self.planned_tensions_n = res.tensions_n
        self.planned_margin_n = res.margin_n
        self._planned_at = sp

    def _measure_tensions(
        self, readings: Sequence[AxisReading], now_s: float, state: State
    ) -> None:
        """Cable tensions from the torque telemetry (reel model, work balance); while HOLDING
        or MOVING, _Fault when one stays below `faults.slack_tension_n` or above the tension
        maximum for `faults.slack_time_s`, or when an axis's torque reading is stale."""
        armed = state is State.HOLDING or state is State.MOVING
        stale = self._stale_s
        reels = self.reels
        out = self.measured_tensions_n
        for i, r in enumerate(readings):
            age = now_s - r.torque_stamp_s
            t: float | None = None
            if age <= stale and r.ready:
                try:
                    t = reels[i].tension_n(r.position_rev, r.torque_nm)
                except ValueError:  # reel slope zero: no tension can be read
                    t = None
            out[i] = t
            if not armed:
                self._slack_since[i] = self._over_since[i] = None
                continue
            if t is None:
                if now_s - self._arm_start_s > stale and age > stale:
                    raise _Fault(f"stale_torque: node {r.node_id} age {age:.3f} s")
                continue
            slack = self._slack_n
            if slack is not None and t < slack:
                since = self._slack_since[i]
                if since is None:
                    self._slack_since[i] = since = now_s
                if now_s - since >= self._tension_time_s:
                    raise _Fault(f"slack: cable {i + 1} at {t:.3g} N")
            else:
                self._slack_since[i] = None
            over = self._over_n
            if over is not None and t > over:
                since = self._over_since[i]
                if since is None:
                    self._over_since[i] = since = now_s
                if now_s - since >= self._tension_time_s:
                    raise _Fault(f"over_tension: cable {i + 1} at {t:.4g} N > {over:.4g} N")
            else:
                self._over_since[i] = None

    def _velocity_ff(
        self, sp: Vec3, v_mps: Vec3, lengths: Sequence[float], rev: Sequence[float]
    ) -> list[float]:
        """Motor velocity feed-forward (rev/s) for set-point `sp` moving at `v_mps`.

        `lengths` are the cable lengths at `sp` (IPK), `rev` the motor turns commanded for them.
        dL_i/dt = (sp - anchor_i) . v / L_i, then rev/s through reel i's slope at `rev[i]`.
        Raises _Fault if a value comes out non-finite (it cannot for a checked set-point).
        """
        vx, vy, vz = v_mps
        if vx == 0.0 and vy == 0.0 and vz == 0.0:
            return list(self._zero_ff)
        x, y, z = sp
        reels = self.reels
        out = []
        for i, (ax, ay, az) in enumerate(self._anchors):
            rate = ((x - ax) * vx + (y - ay) * vy + (z - az) * vz) / lengths[i]
            try:
                w = reels[i].velocity_rps(rev[i], rate)
            except ValueError:  # reel slope zero (spool fully paid out): no usable feed-forward
                w = 0.0
            if not math.isfinite(w):
                raise _Fault(f"nan_setpoint: velocity feed-forward of cable {i + 1} is {w!r}")
            out.append(w)
        return out

    def _send(self, rev: Sequence[float], ff: Sequence[float] | None = None) -> None:
        """Command motor turns with velocity feed-forward `ff` (rev/s; None = zero); a
        non-finite value or a bus error faults instead."""
        for v in rev:
            if not math.isfinite(v):
                raise _Fault(f"nan_setpoint: {list(rev)}")
        try:
            self.driver.command(rev, ff if ff is not None else self._zero_ff)
        except BusError:
            # Counted in driver.stats.bus_errors; the next tick faults if they persist.
            pass
        except ValueError as exc:
            raise _Fault(f"nan_setpoint: driver refused: {exc}") from None

    def _hold_last(self) -> None:
        """In FAULT: keep sending the last good set-point, with zero velocity feed-forward, so
        the motors hold the load."""
        rev = self.commanded_rev
        if rev is None:
            return
        try:
            self.driver.command(rev, self._zero_ff)
        except Exception:  # already in FAULT; keep trying every tick
            self.hold_failures += 1

    def _publish_pose(self) -> None:
        valid = self.pose_valid
        self.seq += 1
        sample = PoseSample(
            self.seq,
            self.pose_stamp_ns if self.pose_stamp_ns > 0 else self._wall_ns(),
            self.pose_m if valid else None,
            tuple(self.lengths_m),
            self.residual_m if valid else None,
            valid,
            self.state.value,
            self.planned_tensions_n if self.setpoint_m is not None else None,
            tuple(self.measured_tensions_n) if self._measure else None,
        )
        try:
            self.publisher.publish_pose(sample)
        except Exception:
            self.command_errors += 1

    # ---------------------------------------------------------------- commands

    def _do_estop(self, now_s: float) -> None:
        with self._estop_lock:
            futures = self._estop_futures
            self._estop_futures = []
            self._estop_flag = False
        err: str | None = None
        try:
            self.driver.estop()
        except Exception as exc:
            err = str(exc)
        if self._pretension is not None:
            self._end_pretension()  # after the Estop: restores the drives' velocity limits
            self.pretension_result = {"ok": False, "reason": "estop"}
        if self.state is not State.ESTOPPED:
            self._set_state(State.ESTOPPED, "estop" if err is None else f"estop (bus: {err})")
            self._estop_unconfirmed = ()
            self.estop_repeats = 0
        # Every e-stop (a repeated one too) restarts the confirmation from its own time.
        self._estop_at_s = now_s
        self._estop_check_s = now_s + ESTOP_CONFIRM_S
        self._estop_confirmed = False
        self.commanded_rev = None
        self.setpoint_m = None
        self.setpoint_lengths_m = None
        self._stream_target = None
        self._velocity_cmd = None
        for fut in futures:
            fut.set_result({"ok": True, "state": self.state.value})

    def _confirm_estop(self, readings: Sequence[AxisReading], now_s: float) -> None:
        """In ESTOPPED until confirmed: has every axis reported leaving closed loop since the
        e-stop? Past the deadline: name the axes that have not, send Estop and IDLE again."""
        since = self._estop_at_s
        for r in readings:
            if r.heartbeat_stamp_s <= since or r.ready:
                break
        else:
            self._estop_confirmed = True
            if self._estop_unconfirmed:
                late = ", ".join(f"node {n}" for n in self._estop_unconfirmed)
                self._estop_unconfirmed = ()
                self._set_reason(
                    f"estop (confirmed: {late} left closed loop only after "
                    f"{self.estop_repeats} repeat(s) of Estop and IDLE)"
                )
            return
        if now_s < self._estop_check_s:
            return
        self._estop_check_s = now_s + ESTOP_CONFIRM_S
        bad = [r for r in readings if r.heartbeat_stamp_s <= since or r.ready]
        self.estop_repeats += 1
        errors = []
        for send in (self.driver.estop, self.driver.disarm):
            try:
                send()
            except Exception as exc:
                errors.append(str(exc))
        nodes = tuple(r.node_id for r in bad)
        if nodes != self._estop_unconfirmed:
            self._estop_unconfirmed = nodes
            what = ", ".join(
                f"node {r.node_id} still in closed loop ({r.state_name})"
                if r.heartbeat_stamp_s > since
                else f"node {r.node_id} silent (no heartbeat since the Estop)"
                for r in bad
            )
            bus = f" (bus: {'; '.join(errors)})" if errors else ""
            self._set_reason(
                f"estop_unconfirmed: {what} {now_s - since:.2f} s after Estop; "
                f"Estop repeated and IDLE requested{bus}"
            )

    def _take_commands(self, readings: Sequence[AxisReading], now_s: float) -> None:
        for _ in range(_MAX_COMMANDS_PER_TICK):
            try:
                cmd, fut, motion = self._queue.get_nowait()
            except queue.Empty:
                return
            if not fut.set_running_or_notify_cancel():
                continue
            try:
                reply = self._execute(cmd, readings, now_s, motion)
            except CommandRefused as exc:
                log.info("refused %s: %s", type(cmd).__name__.lower(), exc)
                fut.set_exception(exc)
            except Exception as exc:  # a bug must not kill the loop
                log.exception("command %r failed", cmd)
                fut.set_exception(CommandRefused(f"internal error: {exc}"))
            else:
                if isinstance(reply, concurrent.futures.Future):  # answered later (homing save)
                    reply.add_done_callback(_chain(fut))
                else:
                    fut.set_result(reply)

    def _refusal_text(self, state: State, why: str) -> str:
        """The refusal message for a verb `state` refuses with reason `why` (COMMAND_RULES)."""
        if state is State.FAULT or state is State.ESTOPPED:
            return f"not allowed in {state.value} ({self.reason}): {why}"
        return f"not allowed in {state.value}: {why}"

    def _check_segment(self, a: Sequence[float], b: Sequence[float]) -> str | None:
        """Velocity mode's look-ahead: `Workspace.check_segment`, then with `[payload]` the
        tension rule at points `_tension_step_m` apart along a->b (b included; a is where the
        set-point is). Scalar: the look-ahead is a braking distance, a few samples. Raises
        nothing."""
        reason = self.workspace.check_segment(a, b)
        chk = self.tension
        if reason is not None or chk is None:
            return reason
        ax, ay, az = float(a[0]), float(a[1]), float(a[2])
        dx, dy, dz = float(b[0]) - ax, float(b[1]) - ay, float(b[2]) - az
        n = max(1, math.ceil(math.sqrt(dx * dx + dy * dy + dz * dz) / self._tension_step_m))
        for k in range(1, n + 1):
            f = k / n
            q = (ax + f * dx, ay + f * dy, az + f * dz)
            why = chk.check(q)
            if why is not None:
                return f"at {_fmt(q)}: {why}"
        return None

    def _check_target(self, p: Sequence[float]) -> str | None:
        """Why `p` is not an allowed target (`Workspace.check_target`, then with `[payload]`
        the payload's cable tensions within their limits and margin), or None if it is.
        Raises nothing."""
        reason = self.workspace.check_target(p)
        if reason is None and self.tension is not None:
            reason = self.tension.check(p)
        return reason

    def _execute(
        self,
        cmd: Command,
        readings: Sequence[AxisReading],
        now_s: float,
        motion: _Motion | None = None,
    ) -> dict[str, Any] | concurrent.futures.Future[dict[str, Any]]:
        """Carry out one command in the tick: its reply, or a future of it when it comes later
        (a homing save). Raises CommandRefused when the state or the limits refuse it."""
        S = State  # noqa: N806
        verb = _VERBS.get(type(cmd))
        if verb is None:
            raise CommandRefused(f"unsupported command {type(cmd).__name__}")
        if self._closing and isinstance(cmd, Move | Path | Arm | Home | Pretension):
            raise CommandRefused("shutting down: no new motion")
        why = refusal(self.state, verb)
        if why is not None:
            raise CommandRefused(self._refusal_text(self.state, why))
        if isinstance(cmd, Move | Path):
            if motion is None:  # not submitted through `submit`: prepare it here
                motion = self._prepare_motion(cmd)
            self._start_motion(motion, cmd)
            reply: dict[str, Any] = {"ok": True}
            if isinstance(cmd, Move):
                reply["target_m"] = list(cmd.position_m)
            else:
                reply["points"] = len(cmd.points_m)
            reply["speed_mps"] = motion.speed_mps
            if motion.limited_to_mps is not None:
                reply["speed_limited_to_mps"] = motion.limited_to_mps
            return reply
        if isinstance(cmd, Stop):
            if self.state is S.PRETENSIONING:
                self._stop_pretension()
            elif self.state in ARMED_STATES:
                self.planner.stop()
            return {"ok": True, "state": self.state.value}
        if isinstance(cmd, Arm):
            if not self.homed:
                raise CommandRefused("not homed: run `home` at a known pose first")
            try:
                self.driver.arm()
            except Exception as exc:
                raise CommandRefused(f"bus_error: arm: {exc}") from None
            self._arm_start_s = now_s
            self._arm_rev = None
            self.commanded_rev = None
            self.setpoint_m = None
            self.setpoint_lengths_m = None
            # A new armed session: set-points streamed before it are never taken.
            self._arm_epoch += 1
            self._stream_target = None
            self._velocity_cmd = None
            self._set_state(S.ARMING)
            return {"ok": True, "state": S.ARMING.value}
        if isinstance(cmd, Disarm):
            self._disarm("disarm")
            return {"ok": True, "state": self.state.value}
        if isinstance(cmd, Reset):
            if self.state is not S.DISARMED:
                self._disarm("reset")
            return {"ok": True, "state": self.state.value}
        if isinstance(cmd, Home):
            return self._execute_home(cmd, readings, now_s)
        if isinstance(cmd, Pretension):
            return self._start_pretension(cmd, readings, now_s)
        raise CommandRefused(f"unsupported command {type(cmd).__name__}")

    def _start_motion(self, motion: _Motion, cmd: Move | Path) -> None:
        """Start a prepared move or path (a move is a one-point path): O(1) in its length.

        Raises CommandRefused (nothing changed) if the preparation refused it or if the first
        leg leaves the limits; that leg starts where the set-point will come to rest (a motion
        that arrives while moving first brakes to a stop).
        """
        if motion.refusal is not None:
            raise CommandRefused(motion.refusal)
        first = motion.points_m[0]
        if self.setpoint_m is not None:
            start = self.planner.rest_point_m
            reason = self.workspace.check_segment(start, first)
            if reason is None and self.tension is not None:
                failure = self._tension_failure((first,), start)
                reason = None if failure is None else failure[1].removeprefix("on the leg to it: ")
            if reason is not None:
                where = "target" if isinstance(cmd, Move) else "points_m[0]"
                raise CommandRefused(
                    f"{where} {_fmt(first)}: on the leg to it from {_fmt(start)}: {reason}"
                )
        self.planner.follow_points(motion.points_m, motion.speed_mps)
        if self.state is State.HOLDING:
            self._set_state(State.MOVING, "move" if isinstance(cmd, Move) else "path")

    def _tension_failure(
        self, points: Sequence[Sequence[float]], start_m: Sequence[float] | None
    ) -> tuple[int, str] | None:
        """The first point of `points` (or point on the leg to it, from `start_m` for point 0)
        where the payload cannot be held by the tension rule, as (index, reason), or None.

        Each leg is sampled every `TENSION_SAMPLE_FRACTION` of the anchors' span (coarser if
        that would exceed `TENSION_MAX_SAMPLES`) and solved in one batch; the first failing
        sample is solved again for its reason. Raises nothing for finite points (checked by
        the limits before)."""
        chk = self.tension
        assert chk is not None
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if start_m is None:
            starts = np.vstack([pts[:1], pts[:-1]])
        else:
            starts = np.vstack([np.asarray(start_m, dtype=np.float64).reshape(1, 3), pts[:-1]])
        leg = pts - starts
        length = np.sqrt(np.einsum("ij,ij->i", leg, leg))
        step = self._tension_step_m
        counts = np.maximum(1, np.ceil(length / step)).astype(np.int64)
        total = int(counts.sum())
        if total > TENSION_MAX_SAMPLES:
            counts = np.maximum(1, np.ceil(counts * (TENSION_MAX_SAMPLES / total))).astype(np.int64)
        idx = np.repeat(np.arange(len(pts)), counts)
        # fraction j / m_k along leg k, j = 1..m_k: the last sample is the point itself
        first = np.cumsum(counts) - counts
        frac = (np.arange(idx.size) - first[idx] + 1) / counts[idx]
        samples = starts[idx] + frac[:, None] * leg[idx]
        _, margin, _, limiting = chk.statics.solve_batch(samples, chk.mass_kg)
        bad = np.flatnonzero((limiting == SINGULAR_ROW) | (margin < chk.margin_n))
        if bad.size == 0:
            return None
        j = int(bad[0])
        i = int(idx[j])
        q = (float(samples[j, 0]), float(samples[j, 1]), float(samples[j, 2]))
        reason = chk.check(q) or "the tension rule fails there"
        if frac[j] < 1.0:
            return i, f"on the leg to it: at {_fmt(q)}: {reason}"
        return i, reason

    def _disarm(self, why: str) -> None:
        if self._end_pretension() is not None:
            self.pretension_result = {"ok": False, "reason": why}
        try:
            self.driver.disarm()
        except Exception as exc:
            log.error("disarm failed on the bus: %s", exc)
        self.commanded_rev = None
        self.setpoint_m = None
        self.setpoint_lengths_m = None
        self._stream_target = None
        self._velocity_cmd = None
        self._estop_unconfirmed = ()
        self._set_state(State.DISARMED, why)

    def _refuse_stale(self, readings: Sequence[AxisReading], now_s: float) -> None:
        """CommandRefused naming every axis without a fresh encoder reading (homing needs
        them all)."""
        old = [r for r in readings if now_s - r.stamp_s > self._stale_s]
        if old:
            ages = ", ".join(
                f"node {r.node_id} "
                + (f"{now_s - r.stamp_s:.3f} s old" if math.isfinite(r.stamp_s) else "never heard")
                for r in old
            )
            raise CommandRefused(
                f"stale_encoder: no fresh encoder reading ({ages}; faults.stale_timeout_s is "
                f"{self._stale_s:g} s): check the drive's encoder broadcast rate, or raise "
                "faults.stale_timeout_s"
            )

    def _execute_home(
        self, cmd: Home, readings: Sequence[AxisReading], now_s: float
    ) -> dict[str, Any] | concurrent.futures.Future[dict[str, Any]]:
        self._refuse_stale(readings, now_s)
        reason = self._check_target(cmd.position_m)
        if reason is not None:
            raise CommandRefused(f"home position {_fmt(cmd.position_m)}: {reason}")
        offsets = self._home_at(readings, cmd.position_m)
        self.home_source = "home"
        if self.state is State.HOLDING:
            # Keep the motors where they are: the same turns now mean the home pose.
            self._hold_at(cmd.position_m)
            self.setpoint_lengths_m = None
        log.info("homed at %s: offsets_rev %s", _fmt(cmd.position_m), offsets)
        reply: dict[str, Any] = {
            "ok": True,
            "position_m": list(cmd.position_m),
            "offsets_rev": dict(zip(map(str, self.node_ids), offsets, strict=True)),
            "saved": False,
        }
        saved = self._save_home(offsets, cmd.position_m, reply)
        return reply if saved is None else saved

    def _save_home(
        self, offsets: Sequence[float], position_m: Vec3, reply: dict[str, Any]
    ) -> concurrent.futures.Future[dict[str, Any]] | None:
        """Save the homing offsets to the state file off the loop thread: a future of `reply`
        with "saved" (and "state_file" or "error"), or None without a state file."""
        if not self._state_file:
            return None
        from controller.service import offsets as homing

        state = homing.make_record(
            self.cfg.name, dict(zip(self.node_ids, offsets, strict=True)), position_m
        )
        path = self._state_file
        # fsync can take tens of ms: save off the loop thread and answer when it is on disk.
        outer: concurrent.futures.Future[dict[str, Any]] = concurrent.futures.Future()

        def save() -> None:
            try:
                homing.save_offsets(path, state)
            except Exception as exc:
                log.error("saving homing offsets to %s failed: %s", path, exc)
                outer.set_result({**reply, "saved": False, "error": str(exc)})
            else:
                log.info("homing offsets saved to %s", path)
                outer.set_result({**reply, "saved": True, "state_file": path})

        t = threading.Thread(target=save, name="cablebot-home-save", daemon=True)
        self._save_threads = [th for th in self._save_threads if th.is_alive()] + [t]
        t.start()
        return outer

    # ---------------------------------------------------------------- pre-tension

    def _start_pretension(
        self, cmd: Pretension, readings: Sequence[AxisReading], now_s: float
    ) -> dict[str, Any]:
        """Start the pre-tension at `cmd.position_m` (`controller.core.pretension`): torque
        control on every reel, each pulling with its cable's statics tension at that pose.
        Raises CommandRefused (nothing sent) when the drive family has no torque control, there
        is no `[payload]`, an encoder reading is stale, the pose breaks a limit or a reel's
        slope is zero; CommandRefused naming the bus when entering torque control fails."""
        drv = self.driver
        if not isinstance(drv, TorqueDriver):
            raise CommandRefused(
                f"pretension: cablebot has no torque control for {self.cfg.drive.kind} drives; "
                "home without --pretension"
            )
        chk = self.tension
        if chk is None:
            raise CommandRefused(
                "pretension: needs [payload] mass_kg (the reels pull with the tensions that hold "
                "the payload at the home pose)"
            )
        if self.cfg.sim.enabled and self.cfg.sim.plant == "kinematic":
            raise CommandRefused(
                "pretension: the kinematic simulator carries no load, so its reels would spin "
                'free; use [sim] plant = "physical"'
            )
        self._refuse_stale(readings, now_s)
        p = cmd.position_m
        reason = self._check_target(p)
        if reason is not None:
            raise CommandRefused(f"home position {_fmt(p)}: {reason}")
        tensions = chk.solve(p).tensions_n
        settings = self.cfg.homing.pretension
        reels = self.reels
        try:
            torques = [
                reels[i].torque_nm(r.position_rev, tensions[i]) for i, r in enumerate(readings)
            ]
            limits = [
                abs(reels[i].velocity_rps(r.position_rev, settings.speed_mps))
                for i, r in enumerate(readings)
            ]
            lengths = [reels[i].length_m(r.position_rev) for i, r in enumerate(readings)]
            run = PretensionRun(settings, tensions, lengths, now_s)
        except ValueError as exc:  # a reel slope of zero, a non-finite number
            raise CommandRefused(f"pretension: {exc}") from None
        try:
            limited = drv.enter_torque_mode(torques, limits)
        except (BusError, ValueError) as exc:
            raise CommandRefused(f"bus_error: pretension: {exc}") from None
        self._torque_driver = drv
        self._pretension = run
        self._pretension_at = p
        self.pretension_result = None
        self.commanded_rev = None
        self.commanded_ff_rps = list(self._zero_ff)
        self.setpoint_m = None
        self.setpoint_lengths_m = None
        self._stream_target = None
        self._velocity_cmd = None
        self._arm_epoch += 1  # set-points streamed before it are never taken after it
        speed = (
            f"at most {settings.speed_mps:g} m/s of cable"
            if limited
            else "as fast as the drives' own velocity limit lets them"
        )
        self._set_state(
            State.PRETENSIONING,
            f"pretension: the reels pull in torque control ({speed}) until still, then home "
            f"at {_fmt(p)}",
        )
        return {
            "ok": True,
            "state": State.PRETENSIONING.value,
            "position_m": list(p),
            "tensions_n": list(tensions),
            "torques_nm": torques,
            "speed_limited": limited,
        }

    def _tick_pretension(self, readings: Sequence[AxisReading], now_s: float) -> None:
        """One tick of the pre-tension: axis checks, travel and stillness (`PretensionRun`),
        then the torques of the tensions, or the home pose once the reels are still. _Fault on
        an axis fault, a stale reading, an axis not in closed loop after `faults.arm_timeout_s`,
        or the run failing."""
        run = self._pretension
        assert run is not None
        ready = self._check_axes(readings, now_s, ready=False)
        if not ready and now_s - run.start_s > self._arm_timeout_s:
            r = next(r for r in readings if not r.ready)
            raise _Fault(
                f"pretension: node {r.node_id} not in closed loop after "
                f"{self._arm_timeout_s:g} s ({r.state_name})"
            )
        if ready:
            reels = self.reels
            lengths = self._pt_lengths_m
            rates = self._pt_rates_mps
            for i, r in enumerate(readings):
                lengths[i] = reels[i].length_m(r.position_rev)
                rates[i] = reels[i].length_rate_mps(r.position_rev, r.velocity_rps)
            why = run.update(now_s, lengths, rates)
            if why is not None:
                raise _Fault(f"pretension: {why}")
            if run.done:
                self._finish_pretension(readings, run)
                return
        drv = self._torque_driver
        assert drv is not None  # set with the run
        # The tensions through the reel model at this tick's turns: a spool that builds up
        # keeps pulling the tension, not the torque, of the start.
        torques = self._pt_torques_nm
        reels = self.reels
        tensions = run.tensions_n
        for i, r in enumerate(readings):
            torques[i] = reels[i].torque_nm(r.position_rev, tensions[i])
        try:
            drv.command_torque(torques)
        except BusError:
            pass  # counted in driver.stats.bus_errors; the next tick faults if they persist
        except ValueError as exc:
            raise _Fault(f"nan_setpoint: driver refused a torque: {exc}") from None

    def _finish_pretension(self, readings: Sequence[AxisReading], run: PretensionRun) -> None:
        """The reels are still: hold their turns in position control, declare the home pose
        there, save the offsets, and go HOLDING. _Fault if the pose cannot be held."""
        p = self._pretension_at
        self._end_pretension()
        offsets = self._home_at(readings, p)
        self.home_source = "pretension"
        measured = list(self.measured_tensions_n) if self._measure else None
        after = run.still_after_s if run.still_after_s is not None else 0.0
        log.info(
            "pretension: still after %.2f s; homed at %s: offsets_rev %s", after, _fmt(p), offsets
        )
        result: dict[str, Any] = {
            "ok": True,
            "position_m": list(p),
            "still_after_s": after,
            "tensions_n": list(run.tensions_n),
            "measured_tensions_n": measured,
            "offsets_rev": dict(zip(map(str, self.node_ids), offsets, strict=True)),
            "saved": False,
        }
        self.pretension_result = result
        saved = self._save_home(offsets, p, result)
        if saved is not None:

            def record(fut: concurrent.futures.Future[dict[str, Any]]) -> None:
                self.pretension_result = fut.result()  # one reference assignment: atomic

            saved.add_done_callback(record)
        self._set_state(State.HOLDING, f"pretension: still after {after:.2f} s, homed")
        self._hold_at(p)
        self.setpoint_lengths_m = None

    def _end_pretension(self) -> list[float] | None:
        """Leave torque control if a pre-tension is running: every drive holds the turns its
        reel is at (they become the commanded turns, as in FAULT) and gets its velocity limit
        back. Returns those turns, or None when no pre-tension was running. Never raises."""
        if self._pretension is None:
            return None
        self._pretension = None
        positions = [r.position_rev for r in self.driver.read()]
        drv = self._torque_driver
        try:
            assert drv is not None  # set with the run
            drv.leave_torque_mode(positions)
        except Exception as exc:  # the hold is re-sent every tick in FAULT
            log.error("pretension: leaving torque control failed: %s", exc)
        self.commanded_rev = positions
        self.commanded_ff_rps = list(self._zero_ff)
        return positions

    def _stop_pretension(self) -> None:
        """`stop` while pretensioning: the drives hold where the reels are; HOLDING at the
        measured pose when it is known, else FAULT (nothing to hold the pose by)."""
        self._end_pretension()
        self.pretension_result = {"ok": False, "reason": "stopped"}
        pose = self.pose_m
        if self.homed and self.pose_valid and pose is not None:
            self._set_state(State.HOLDING, "pretension stopped: holding where the reels are")
            try:
                self._hold_at(pose)
            except _Fault as f:
                self._fault(f.reason)
        else:
            self._fault(
                "pretension stopped before the reels were still, with no known pose: the motors "
                "hold their turns; reset, then home"
            )

    def _pretension_status(self, now_s: float) -> dict[str, Any]:
        """The pre-tension part of `status()`."""
        run = self._pretension
        active = run is not None
        return {
            "active": active,
            "position_m": list(self._pretension_at) if active else None,
            "tensions_n": list(run.tensions_n) if run is not None else None,
            "elapsed_s": now_s - run.start_s if run is not None else None,
            "fastest_cable_mps": (
                run.worst_mps if run is not None and math.isfinite(run.worst_mps) else None
            ),
            "result": self.pretension_result,
        }

    # ---------------------------------------------------------------- status

    def status(self) -> dict[str, Any]:
        """A JSON-ready snapshot of the controller (thread-safe, for `<prefix>/status`)."""
        now = self._clock()
        axes = []
        for r in self.driver.read():
            r = r.snapshot()
            axes.append(
                {
                    "node_id": r.node_id,
                    "ready": r.ready,
                    "fault": r.fault,
                    "state": r.state_name,
                    "axis_state": r.axis_state,
                    "axis_error": r.axis_error,
                    "position_rev": r.position_rev,
                    "age_s": _finite_or_none(now - r.stamp_s),
                    "heartbeat_age_s": _finite_or_none(now - r.heartbeat_stamp_s),
                }
            )
        bs = self.driver.stats.snapshot()
        valid = self.pose_valid
        pose = self.pose_m
        sp = self.setpoint_m
        return {
            "state": self.state.value,
            "reason": self.reason,
            "state_stamp_ns": self.state_stamp_ns,
            "homed": self.homed,
            "home_source": self.home_source,
            "pose": {
                "valid": valid,
                "position_m": list(pose) if valid and pose is not None else None,
                "residual_m": self.residual_m if valid else None,
                "cable_lengths_m": [_finite_or_none(v) for v in self.lengths_m],
            },
            "setpoint_m": list(sp) if sp is not None else None,
            "tensions": self._tension_status(sp is not None),
            "pretension": self._pretension_status(now),
            "axes": axes,
            "loop": {
                "rate_hz": 1.0 / self.period_s,
                "ticks": self.ticks,
                **self.loop_stats.figures(),
                "dt_clamped": self.dt_clamped,
            },
            "stream": {
                "refused": self.stream_refused,
                "last_refusal": self.stream_last_refusal,
                "discarded": self.stream_discarded,
            },
            "velocity": {
                "command_mps": list(self.planner.velocity_command_mps),
                "discarded": self.velocity_discarded,
                "deadman_stops": self.planner.deadman_stops,
                "boundary_brakes": self.planner.boundary_brakes,
            },
            "estop": (
                {
                    "confirmed": self._estop_confirmed,
                    "unconfirmed_nodes": list(self._estop_unconfirmed),
                    "repeats": self.estop_repeats,
                }
                if self.state is State.ESTOPPED
                else None
            ),
            "bus": {
                "frames_rx": bs.frames_rx,
                "frames_tx": bs.frames_tx,
                "decode_errors": bs.decode_errors,
                "dropped": bs.dropped,
                "commands_heard": bs.commands_heard,
                "bus_errors": bs.bus_errors,
                "ff_clamped": bs.ff_clamped,
                "last_error": bs.last_error,
                "errors_by_kind": dict(bs.errors_by_kind),
            },
            "config": self.cfg.summary(),
        }

    def _tension_status(self, commanded: bool) -> dict[str, Any] | None:
        """The statics part of `status()`: None without `[payload]`."""
        chk = self.tension
        if chk is None:
            return None
        planned = self.planned_tensions_n if commanded else None
        return {
            "mass_kg": chk.mass_kg,
            "min_n": chk.statics.t_min_n,
            "max_n": chk.statics.t_max_n,
            "margin_required_n": chk.margin_n,
            "planned_n": list(planned) if planned is not None else None,
            "planned_margin_n": self.planned_margin_n if planned is not None else None,
            "measured_n": list(self.measured_tensions_n) if self._measure else None,
            "telemetry": self.cfg.loop.torque_telemetry,
        }

    # ---------------------------------------------------------------- the fixed-rate loop

    def runner(self, *, spin_s: float = SPIN_S) -> Runner:
        """A `Runner` that calls `tick` at the configured rate on this controller's clock and
        sleep (spinning the last `spin_s` before each deadline), writing its figures to
        `loop_stats` so that `status()` reports them. Raises nothing.
        """
        return Runner(
            self.tick,
            self.period_s,
            clock=self._clock,
            sleep=self._sleep,
            spin_s=spin_s,
            stats=self.loop_stats,
        )

    def run(
        self,
        stop: threading.Event,
        *,
        on_watchdog: Callable[[], None] | None = None,
        watchdog_period_s: float = 0.0,
    ) -> None:
        """Call `tick` at the configured rate until `stop` is set (`runner().run`, which see)."""
        self.runner().run(stop, on_watchdog=on_watchdog, watchdog_period_s=watchdog_period_s)

    # ---------------------------------------------------------------- shutdown

    def begin_shutdown(self) -> concurrent.futures.Future[dict[str, Any]]:
        """Start a shutdown: from now on no new motion is taken (move, path, streamed set-points,
        arm, home are refused or ignored) and any motion brakes to a hold at `max_accel_mps2`
        (a queued Stop, whose future is returned). Thread-safe; the loop keeps running."""
        self._closing = True
        return self.submit(Stop())

    def brake_time_s(self) -> float:
        """Seconds the set-point needs to come to rest from its current speed at the configured
        acceleration (0 when still). Thread-safe (reads one tuple)."""
        vx, vy, vz = self.planner.velocity_mps
        return math.sqrt(vx * vx + vy * vy + vz * vz) / float(self.cfg.limits.max_accel_mps2)

    def send_final_hold(self) -> bool:
        """Shutdown, after the loop thread has stopped: command the last set-point once more with
        zero velocity feed-forward, so the drives hold still on it instead of running on to
        `vel_ff / pos_gain` past it. Only while the motors are commanded (ARMING, HOLDING,
        MOVING, FAULT with a set-point). Returns True if it was sent; never raises.

        Call it only when the runner has returned: the loop thread is otherwise the driver's only
        user.
        """
        rev = self.commanded_rev
        commanded = (State.ARMING, State.HOLDING, State.MOVING, State.FAULT)
        if rev is None or self.state not in commanded:
            return False
        try:
            self.driver.command(rev, self._zero_ff)
        except Exception as exc:
            log.error("final hold not sent: %s", exc)
            return False
        self.commanded_ff_rps = list(self._zero_ff)
        return True

    def wait_for_saves(self, timeout_s: float = 2.0) -> None:
        """Wait (bounded) for homing saves in flight, e.g. before exiting."""
        deadline = time.monotonic() + timeout_s
        for t in list(self._save_threads):
            t.join(max(0.0, deadline - time.monotonic()))


# --------------------------------------------------------------------------------------------
# helpers


def _with_offset(model: ReelModel, offset_rev: float) -> ReelModel:
    from dataclasses import replace

    return replace(model, offset_rev=offset_rev)


def _chain(
    outer: concurrent.futures.Future[dict[str, Any]],
) -> Callable[[concurrent.futures.Future[dict[str, Any]]], None]:
    """A done-callback that copies a future's result into `outer`."""

    def done(f: concurrent.futures.Future[dict[str, Any]]) -> None:
        outer.set_result(f.result())

    return done


def _finite_or_none(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _fmt(p: Sequence[float]) -> str:
    return "[" + ", ".join(f"{float(v):.4f}" for v in p) + "]"
