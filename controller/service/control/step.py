"""The control step: `ControlStep.tick` (read → estimate → plan → check → write) and the
fixed-rate loop that calls it (`controller.service.loop` describes the step in full).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence

from controller.core import kinematics
from controller.core.commands import Vec3
from controller.core.inertia import inertial_share, with_inertia
from controller.core.motion import BRAKE_ACCEL_SHARE
from controller.core.states import ARMED_STATES, State
from controller.core.statics import StaticsError
from controller.service.control.base import _Fault, _fmt, log
from controller.service.control.commands import CommandExecution
from controller.service.pose import PoseSample
from controller.service.runner import SPIN_S, Runner
from drivers.base import AxisReading, BusError

_ZERO: Vec3 = (0.0, 0.0, 0.0)
STOP_POINT_TOL_M = 1e-6
"""A motion held this close to where a `stop` braked it to ended by that stop."""


class ControlStep(CommandExecution):
    """The controller's control step and the fixed-rate loop that calls it."""

    # ---------------------------------------------------------------- the tick

    def tick(self, now_s: float) -> None:
        """Do exactly one control step at clock time `now_s` (see `controller.service.loop`).

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
            if drv.stats.conflicts != self._conflicts_seen:
                self._check_conflicts(now_s, state)
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
        lost = self._count_lost(readings)
        if lost is not None:
            # The offsets were taken in another count of a drive's position: no pose from them.
            self.pose_valid = False
            if self.state is not State.DISARMED:
                raise _Fault(lost)
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
        oldest_age_s = 0.0
        oldest = readings[0]
        for r in readings:
            age_s = now_s - r.stamp_s
            if age_s > stale:
                # Old encoder data is no pose (armed states have faulted on it already).
                self.pose_valid = False
                return
            if age_s > oldest_age_s:
                oldest_age_s = age_s
                oldest = r
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
                at = self._planned_at
                planned = self.planned_tensions_n
                pose, residual = self.cables.pose(
                    lengths,
                    pose,
                    self.measured_tensions_n if self._measure else None,
                    None if at is None or planned is None else (at, planned),
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
            # A drive gone quiet mid-move leaves its last reading while the others move on: the
            # residual passes its limit before the reading is stale; say which one lags.
            lag = (
                f"; node {oldest.node_id}'s reading is {oldest_age_s:.3f} s old"
                if oldest_age_s > 2.0 * self.period_s
                else ""
            )
            raise _Fault(
                f"residual: {residual * 1e3:.1f} mm > {self._residual_max_m * 1e3:.1f} mm"
                f" (slack or slipped cable{lag})"
            )
        sp = self.setpoint_m
        if sp is not None and self.state in ARMED_STATES:
            p = pose
            err = math.sqrt((p[0] - sp[0]) ** 2 + (p[1] - sp[1]) ** 2 + (p[2] - sp[2]) ** 2)
            # The pose is where the effector was when the readings were taken; the set-point has
            # moved on since by at most its speed times their age (a late reading on a busy
            # computer is not a lag of the robot; a stale one faults on its own).
            v = self.shaping.velocity_mps
            allowed = (
                self._tracking_max_m
                + math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) * oldest_age_s
            )
            if err > allowed:
                raise _Fault(f"tracking_error: {err * 1e3:.1f} mm > {allowed * 1e3:.1f} mm")

    def _tick_arming(self, readings: Sequence[AxisReading], now_s: float) -> None:
        fresh = all(r.stamp_s >= self._arm_start_s for r in readings)
        if self._arm_rev is None and fresh:
            self._arm_rev = [r.position_rev for r in readings]
            self.commanded_rev = self._arm_rev  # what a FAULT during arming keeps holding
        if self._arm_rev is not None:
            # Hold the motors where they were while they enter closed loop.
            self._send(self._arm_rev)
        closed = all(
            r.ready
            and r.fault is None
            and r.heartbeat_stamp_s >= self._arm_start_s
            and r.status_stamp_s >= r.command_stamp_s
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
                f"{', no encoder' if r.stamp_s < self._arm_start_s else ''}"
                f"{'' if r.status_fresh() else ', no answer since the arm'}"
                f"{'' if r.heartbeat_stamp_s >= self._arm_start_s else ', no heartbeat since it'})"
                for r in readings
                if not (r.ready and r.status_fresh())
                or r.fault is not None
                or r.stamp_s < self._arm_start_s
                or r.heartbeat_stamp_s < self._arm_start_s
            ]
            why = ", ".join(bad) if bad else "no valid pose"
            self._fault(f"arm_timeout: {why}")

    def _hold_at(self, p: Vec3) -> None:
        """Hold at `p`; _Fault if the payload cannot be held there (the tension rule)."""
        self.planner.hold(p)
        self.shaping.reset(p)
        self.setpoint_m = p
        self._setpoint_tick_s = self._last_tick_s
        self.setpoint_lengths_m = None
        if self.tension is not None:
            self._plan_tensions(p)

    def _tick_armed(self, dt: float) -> None:
        if dt > self._max_plan_dt_s:
            dt = self._max_plan_dt_s  # after a stall: resume, do not jump (see `loop`)
            self.dt_clamped += 1
        item = None if self._closing else self._stream_target
        if item is not None:
            self._stream_target = None
            target, epoch, arrived = item
            if epoch != self._arm_epoch:
                reason: str | None = "set-point from before the last `arm` discarded"
            elif arrived < self._motion_taken_at:
                # sent before a move, path or stop the tick took first: that one is the latest
                reason = "set-point sent before the last move, path or stop: superseded"
            else:
                reason = self._check_target(target)
            if reason is None:
                self.planner.stream(target)
                if self.state is State.HOLDING:
                    self._set_state(State.MOVING, "stream")
            else:
                self.stream_last_refusal = reason
                self.stream_refused += 1  # after the reason: a reader of the count finds it
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
        raw = self.planner.advance(dt)
        raw = (float(raw[0]), float(raw[1]), float(raw[2]))
        if not (math.isfinite(raw[0]) and math.isfinite(raw[1]) and math.isfinite(raw[2])):
            raise _Fault(f"nan_setpoint: planner gave {raw}")
        shaping = self.shaping
        sp = shaping.shape(raw, self.planner.velocity_mps, dt, self.setpoint_m, self._held_n)
        if not (math.isfinite(sp[0]) and math.isfinite(sp[1]) and math.isfinite(sp[2])):
            raise _Fault(f"nan_setpoint: shaper gave {sp}")
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
        acc = shaping.acceleration_mps2
        if self.tension is not None and (sp != self._planned_at or acc != self._planned_acc):
            self._plan_tensions(sp, acc)
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
        ff = self._velocity_ff(sp, shaping.velocity_mps, lengths, rev)
        self._send(rev, ff)
        self.commanded_rev = rev
        self.commanded_ff_rps = ff
        self.setpoint_m = sp
        self._setpoint_tick_s = self._last_tick_s  # after it: see `status`
        self.setpoint_lengths_m = lengths
        if self.state is State.MOVING and not self.planner.moving and shaping.settled:
            shaping.take_pending(sp)
            self._set_state(State.HOLDING, self._stop_reason(sp))

    def _stop_reason(self, held_m: Vec3) -> str | None:
        """Why a motion ended at `held_m`: the reason of the `stop` whose braking ended there,
        else None (it arrived, or ended where a later motion led). Forgets the stop."""
        brake, self._stop_brake = self._stop_brake, None
        if brake is not None and math.dist(brake[0], held_m) <= STOP_POINT_TOL_M:
            return brake[1]
        return None

    def _plan_tensions(self, sp: Vec3, acc: Vec3 = _ZERO) -> None:
        """The tensions that hold the payload at set-point `sp` and accelerate it at `acc`
        (`controller.core.inertia`: the held distribution and the least-norm share of m a);
        _Fault if the held distribution breaks the tension rule (limits and margin: the margin
        is the room the share takes). A held set-point is solved once."""
        assert self.tension is not None
        # The FPK's tension derivative (cable stretch) comes with this solve, every 5 cm.
        want = self.cables.wants_derivative(sp)
        try:
            res = self.tension.solve(sp, want)
        except StaticsError as exc:
            raise _Fault(f"tension: set-point {_fmt(sp)}: {exc}") from None
        reason = self.tension.reason(res)
        if reason is not None:
            raise _Fault(f"tension: set-point {_fmt(sp)}: {reason}")
        if want:
            self.cables.take_derivative(sp, res.derivative)
        planned = self._held_n = res.tensions_n
        if acc != _ZERO:
            share = inertial_share(self._anchors, sp, self.tension.mass_kg, acc)
            planned = with_inertia(planned, share)
        elif self._planned_acc != _ZERO and self.cables.stretch is not None:
            # The share is gone (the payload at rest): the pose of the same encoder readings
            # is solved again with the held tensions.
            self._fpk_lengths_m[0] = math.nan
        self.planned_tensions_n = planned
        self.planned_margin_n = res.margin_n
        self._planned_at = sp
        self._planned_acc = acc

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
            self.planner.queued_points,
        )
        try:
            self.publisher.publish_pose(sample)
        except Exception:
            self.command_errors += 1

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

    def brake_time_s(self) -> float:
        """Seconds a stop now takes to bring the set-point to rest (`MotionPlanner.brake_time_s`:
        on a path, braking along it, longer through corner arcs; 0 when still). Thread-safe:
        read while the loop may change the planner, it is retried and, should the planner keep
        changing under it, bounded from the speed at the corner arcs' braking share of the
        acceleration (`BRAKE_ACCEL_SHARE`). With input shaping the shaped set-point arrives
        the shaper's delay later. Raises nothing."""
        planner = self.planner
        lag = self.shaping.max_delay_s()
        for _ in range(3):
            try:
                t = planner.brake_time_s
            except (RuntimeError, IndexError):  # the deque changed while it was walked
                continue
            if math.isfinite(t) and t >= 0.0:
                return t + (0.0 if t == 0.0 and self.shaping.settled else lag)
        vx, vy, vz = planner.velocity_mps
        speed = math.sqrt(vx * vx + vy * vy + vz * vz)
        return speed / (float(self.cfg.limits.max_accel_mps2) * BRAKE_ACCEL_SHARE) + lag
