"""The controller's state: every attribute the parts of `controller.service.loop.Controller` share,
set up once by the constructor, and the homing offsets it starts from.

The parts build on it (`faults`, `homing`, `commands`, `step`, `status`); `ControllerState`
declares the few methods a part calls in a part built on top of it, for the type checker only.
"""

from __future__ import annotations

import concurrent.futures
import itertools
import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from controller.core.commands import Command, Vec3
from controller.core.motion import MotionPlanner
from controller.core.motion.shaper import ShaperError
from controller.core.pretension import PretensionRun
from controller.core.reel import ReelModel
from controller.core.states import State
from controller.core.statics import PATH_MAX_SAMPLES, TensionCheck
from controller.core.vibration import ModesError
from controller.core.workspace import Workspace
from controller.service.cables import CableModel
from controller.service.config import RobotConfig, tension_check
from controller.service.pose import NullPublisher, Publisher
from controller.service.runner import LoopStats
from controller.service.shaping import LoopShaper
from drivers.base import AxisReading, ReelDriver, TorqueDriver

log = logging.getLogger("cablebot.loop")

COMMAND_QUEUE_SIZE = 32
ESTOP_CONFIRM_S = 0.2
"""Every axis must confirm leaving closed loop this soon after an e-stop (see
`controller.service.loop`)."""
CONFLICT_HOLDOFF_S = 2.0
"""An arm is refused this long after another bus master was last heard (`BusStats.conflicts`)."""
MAX_PLANNER_DT_PERIODS = 4.0
"""The planner advances at most this many loop periods per tick (see `controller.service.loop`)."""
TENSION_SAMPLE_FRACTION = 0.01
"""A move's or path's legs are checked for tensions at points this fraction of the anchors'
span apart (the tick checks every set-point on them too)."""
TENSION_MAX_SAMPLES = PATH_MAX_SAMPLES
"""At most this many tension samples per command (the spacing grows to fit)."""


def make_planner(
    cfg: RobotConfig,
    *,
    check_segment: Callable[[Sequence[float], Sequence[float]], str | None] | None = None,
    max_accel_mps2: float | None = None,
) -> MotionPlanner:
    """The motion planner of the robot `cfg` as the control loop builds it (the G-code dry run
    plans on the same), with `check_segment` for velocity mode and the acceleration lowered to
    `max_accel_mps2` if given (never raised). Raises ValueError for limits the planner
    refuses (a validated configuration has none)."""
    lim = cfg.limits
    accel = (
        lim.max_accel_mps2 if max_accel_mps2 is None else min(max_accel_mps2, lim.max_accel_mps2)
    )
    return MotionPlanner(
        lim.max_speed_mps,
        accel,
        min(float(lim.default_speed_mps), float(lim.max_speed_mps)),
        velocity_timeout_s=lim.velocity_timeout_s,
        check_segment=check_segment,
        junction_deviation_m=lim.junction_deviation_m,
        anchors_m=cfg.anchors_m,
        max_cable_speed_mps=lim.max_cable_speed_mps,
        max_queued_points=lim.max_queued_points,
    )


def tension_sample_step_m(cfg: RobotConfig) -> float:
    """How far apart a move's or path's legs are checked for tensions (m):
    `TENSION_SAMPLE_FRACTION` of the anchors' span."""
    anchors = cfg.anchors_m
    return TENSION_SAMPLE_FRACTION * max(math.dist(a, b) for a in anchors for b in anchors)


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


_Pending = tuple[Command, "concurrent.futures.Future[dict[str, Any]]", _Motion | None, int]
"""A queued command, its future, its prepared motion and its place in arrival order."""
Reply = dict[str, Any] | concurrent.futures.Future[dict[str, Any]]
"""A command's reply, or a future of it when it comes later (a homing save)."""


class ControllerState:
    """The controller's state and its set-up (`controller.service.loop.Controller` documents
    the arguments). Raises ValueError if the driver's axes do not match the configuration.
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
        self.planner = make_planner(cfg, check_segment=self._check_segment)
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
            else tension_check(cfg.payload, cfg.tension, cfg.geometry, cfg.reels)
        )
        self.cables = CableModel.from_config(cfg, self.tension)
        """Rigid, stretching or heavy cables: homing lengths, commanded lengths (IPK), pose
        (FPK)."""
        try:
            self.shaping = LoopShaper(cfg, self.period_s, self.tension)
        except (ShaperError, ModesError) as exc:
            raise ValueError(f"shaper: {exc}") from None
        """The input shaper between the planner and the set-point (`[shaper]`; "off" passes
        the planner's set-point through)."""
        self._tension_step_m = tension_sample_step_m(cfg)
        self.planned_tensions_n: tuple[float, ...] | None = None
        """Tensions that hold the payload at the last good set-point (None: not known)."""
        self.planned_margin_n: float | None = None
        self._planned_at: Vec3 | None = None
        self._held_n: tuple[float, ...] | None = None
        """The tensions that hold the payload still at the last set-point planned (without the
        m a share): the modes' stiffness."""
        self._planned_acc: Vec3 = (0.0, 0.0, 0.0)
        """The set-point's acceleration the planned tensions include (its m a share)."""
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
        self._home_epochs: list[int] = []
        """Each drive's `count_epoch` when the offsets were taken (they hold in it only)."""
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
        self._stream_target: tuple[Vec3, int, int] | None = None
        """The latest streamed set-point, the armed session (`_arm_epoch`) it arrived in and its
        place in arrival order (`_arrivals`)."""
        self._arrivals = itertools.count()
        """Arrival order of commands and streamed set-points (next() is atomic in CPython)."""
        self._motion_taken_at = -1
        """The arrival place of the last motion command the tick took: a set-point that came
        before it is superseded, though the tick meets it after."""
        self._stop_brake: tuple[Vec3, str] | None = None
        """Where a `stop` taken while MOVING brakes to and why: the HOLDING there carries the
        reason (a motion that replaced the braking ends elsewhere and carries none)."""
        self._arm_epoch = 0
        """Counts `arm` commands taken: a set-point from an earlier session is discarded."""
        self.stream_refused = 0
        self.stream_last_refusal: str | None = None
        self.stream_discarded = 0
        self.stream_last_discard: str | None = None
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

        self._init_step_values(driver)

    def _init_step_values(self, driver: ReelDriver) -> None:
        """The per-tick working values (the last tick's), the pre-tension's and the
        shutdown's, as they are before the first tick."""
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
        self._setpoint_tick_s: float | None = None
        """The clock time of the tick that computed `setpoint_m` (written after it)."""
        """Set-point commanded on the last good tick (the hold set-point in FAULT)."""
        self.setpoint_lengths_m: tuple[float, ...] | None = None
        self.commanded_rev: list[float] | None = None
        """Last good motor set-points; re-sent every tick in FAULT."""
        self.commanded_ff_rps: list[float] = [0.0] * self.n
        """Velocity feed-forward sent with the last set-point (motor rev/s)."""
        self._zero_ff: tuple[float, ...] = (0.0,) * self.n
        self.path_speed_mps: float | None = None
        """The speed requested by the last move, path or append taken (status `path.speed_mps`)."""
        self.dt_clamped = 0
        """Ticks whose planner step was cut to MAX_PLANNER_DT_PERIODS periods (stalls)."""
        self._arm_start_s = 0.0
        self._arm_rev: list[float] | None = None
        self._last_tick_s: float | None = None
        self._bus_errors_seen = driver.stats.bus_errors
        self._conflicts_seen = driver.stats.conflicts
        self._conflict_s: float | None = None
        """When another bus master was last heard (None: never)."""
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

    if TYPE_CHECKING:
        # The seams: a part calling a method of a part built on top of it. Declared for the
        # type checker only (it checks each against the implementation), never at run time.

        def _check_segment(self, a: Sequence[float], b: Sequence[float]) -> str | None: ...

        def _check_target(self, p: Sequence[float]) -> str | None: ...

        def _end_pretension(self) -> list[float] | None: ...

        def _hold_at(self, p: Vec3) -> None: ...

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
        self._home_epochs = [r.count_epoch for r in self.driver.read()]

    def _count_lost(self, readings: Sequence[AxisReading]) -> str | None:
        """The reason the homing no longer holds: a drive's position count started afresh since
        the offsets were taken (None while it holds). Raises nothing."""
        epochs = self._home_epochs
        for i in range(len(epochs)):
            r = readings[i]
            if r.count_epoch != epochs[i]:
                return (
                    f"count_lost: node {r.node_id}'s position count started afresh (it restarted"
                    " and its encoder lost the count): home at a known pose"
                )
        return None

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
        self._home_epochs = [r.count_epoch for r in readings]
        self.lengths_m[:] = [float(v) for v in lengths]
        self._fpk_lengths_m[:] = self.lengths_m
        self.pose_m = (float(position_m[0]), float(position_m[1]), float(position_m[2]))
        self.residual_m = 0.0
        return tuple(m.offset_rev for m in self.reels)


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
