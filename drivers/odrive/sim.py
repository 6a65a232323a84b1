"""Simulated ODrive axes speaking CANSimple (firmware 0.6) on any python-can bus.

`SimODriveAxis` is a pure state object: `handle(msg)` applies one decoded command and returns the
frames the axis answers with; `step(dt_s)` advances the motion and returns the cyclic broadcasts
(encoder estimates, heartbeat) that fall due. `SimODriveBank` runs a set of axes on a bus in a
thread; `run_sim` is the same loop for a process (`python -m drivers.odrive.sim ...`).

Behaviour mirrored from firmware 0.6: IDLE until CLOSED_LOOP_CONTROL is requested; entering
closed loop is refused while an axis error is active and holds the current position
(input_pos := position, input_vel := 0); Estop drops to IDLE and latches ESTOP_REQUESTED;
Clear_Errors clears the error. In IDLE the simulated reel is braked: its position stays where it
is (a real unpowered reel under cable tension would not; that is outside the model).

Axis watchdog (`watchdog_timeout_s` > 0, the drive's `axis.config.enable_watchdog` and
`axis.config.watchdog_timeout`): every CANSimple frame a host sends to the axis feeds it (as in
the firmware's CANSimple handler; the axis's own broadcasts heard back do not); an axis in
closed loop that goes `watchdog_timeout_s` without one disarms to IDLE with
WATCHDOG_TIMER_EXPIRED (reported by heartbeat and Get_Error), so a host that dies mid-move does
not leave the axis running on its last velocity feed-forward. The timer runs only in closed loop
here (an idle axis has nothing to stop). The timer counts the time since the last feed as the
simulation sees it: a step during which the axis was fed does not count (the frame arrived
within it), and the serving loop handles every frame already received before it steps, so a
simulation thread starved on a busy host (a long late step, a backlog of frames) does not
mistake a live host for a silent one. A dead host is caught `watchdog_timeout_s` after its last
frame, and a late step ends the motion at that time (the axis does not run on through a stall).

Motion model (POSITION_CONTROL with INPUT_MODE_PASSTHROUGH, the firmware's cascaded loop):
Set_Input_Pos sets input_pos and input_vel (its Vel_FF field), and the velocity command is

    vel_cmd = clamp(input_vel + pos_gain * (input_pos - position), -vel_limit, +vel_limit)

(ODrive docs, control.md: "vel_cmd = pos_error * pos_gain + vel_feedforward"; pos_gain default
20 (rev/s)/rev). The velocity loop and the current loop are modelled as an ideal velocity
response limited by the motor's torque, i.e. the velocity moves toward vel_cmd by at most
`max_accel_rps2 * dt` (no first-order lag: the real velocity loop's bandwidth, hundreds of Hz, is
far above the position loop's 20 rad/s). So a streamed set-point with the right feed-forward is
tracked with a lag of about one command period's worth of motion, a set-point without
feed-forward with the steady lag velocity / pos_gain, and a big step overshoots when braking needs
more than `max_accel_rps2` (as a current-limited drive does). In VELOCITY_CONTROL the velocity
command is input_vel (Set_Input_Vel). The dynamics are integrated in sub-steps of at most
`MAX_SUBSTEP_S` so a late `step` (a stalled thread) cannot make the discrete P loop unstable.
At rest (no feed-forward, within `REST_SNAP_REV` of input_pos, velocity below
`REST_SNAP_RPS`) the position snaps onto input_pos, so a settled axis reports input_pos exactly.

TORQUE_CONTROL (Set_Input_Torque; the pre-tension before homing): the motor makes the torque it
is told (Torque_Target = Torque_Estimate = input_torque by Get_Torques). With a load (below) the
load decides how the reel turns: the coupling treats the reel as an ideal torque source that
pulls its cable with the tension that torque holds, turning no faster than vel_limit
(`controller.core.plant.ReelPlant.step`, `pulls_nm`), and the axis takes the turns the
coupling gives it. Without a load nothing resists the motor: a free reel spins at
G * input_torque, up to vel_limit, with G = `torque_mobility_rps_per_nm` (a friction-limited
free spin), reached at most at `max_accel_rps2`. Entering closed loop in TORQUE_CONTROL keeps
the last input_torque (the driver's `enter_torque_mode` sets it first) and starts from rest.

Load (a physical plant): the bank may be given an `AxisCoupling`, stepped once per tick after
the axes move with every axis's motor position (and the torque of every axis in torque
control); it returns the torque each motor makes or needs to hold its cable
(`controller.core.plant.ReelPlant`: one plant for all axes, since the effector couples them).
In position and velocity control the motion model above is unchanged (the motor follows its
loop whatever the load: a stiff drive); the holding torque is what the axis reports by
Get_Torques (0x1C, cyclic every `torque_period_s` when > 0, and by RTR), Torque_Target and
Torque_Estimate both; 0 in IDLE (the reel is braked: the brake, not the motor, holds the
cable). Without a coupling the torque is 0: the kinematic simulator knows no load.

Fault injection for tests: `silence(True)` (no frames in or out), `set_axis_error(code)` (disarm
with that error, reported by heartbeat), `send_corrupt()` (a wrong-length encoder frame),
`send_nan()` (an encoder frame with a NaN position), `drift(rate)` (encoder estimate drifts from
the true position at `rate` rev/s), `reboot()` (IDLE without errors, as after a reset; with
`silence` before it, the heartbeat gap of a reboot).
"""

from __future__ import annotations

import argparse
import math
import struct
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import can

from drivers.odrive import cansimple as cs
from drivers.registry import SimSettings
from drivers.simbank import SimLink, ThreadedSimBank, add_bus_arguments, floats_arg, serve_process
from drivers.socketcan_fast import (
    CAN_EFF_FLAG,
    CAN_EFF_MASK,
    CAN_ERR_FLAG,
    CAN_RTR_FLAG,
    FastSocketCan,
)

_NAN_ENCODER = struct.pack("<ff", math.nan, 0.0)

DEFAULT_POS_GAIN = 20.0
"""Firmware 0.6 default `controller.service.config.pos_gain`, (rev/s)/rev."""
MAX_SUBSTEP_S = 0.001
"""Longest integration step of the axis dynamics (a longer `step` is split)."""
_MAX_SUBSTEPS = 10_000
MAX_DRAIN_FRAMES = 10_000
"""Most frames the serving loop handles back to back before a due step (a bound, not a rate)."""
_HOST_TX_TYPES = frozenset(cs.HOST_MESSAGES)
"""What a host sends: only these feed the watchdog. What an axis sends itself (heartbeats,
encoder estimates, Get_Error and Get_Torques answers and broadcasts), heard back because
udp_multicast loops frames back, feeds nothing."""
REST_SNAP_REV = 1e-9
REST_SNAP_RPS = 1e-6


class SimODriveAxis:
    """One simulated ODrive axis; thread-safe (an internal lock guards every method)."""

    def __init__(
        self,
        node_id: int,
        *,
        initial_position_rev: float = 0.0,
        max_velocity_rps: float = 20.0,
        max_accel_rps2: float = 200.0,
        encoder_period_s: float = 0.01,
        heartbeat_period_s: float = 0.1,
        pos_gain: float = DEFAULT_POS_GAIN,
        watchdog_timeout_s: float = 0.0,
        torque_period_s: float = 0.0,
        torque_mobility_rps_per_nm: float = 5.0,
    ) -> None:
        """Create an IDLE axis at `initial_position_rev`.

        `max_velocity_rps` is the drive's vel_limit, `max_accel_rps2` its torque-limited
        acceleration, `pos_gain` the position loop gain in (rev/s)/rev, `watchdog_timeout_s`
        the axis watchdog (0 = off; see the module docstring), `torque_period_s` the period of
        the cyclic Get_Torques broadcast (0 = off: by RTR only), `torque_mobility_rps_per_nm`
        the velocity per newton metre of a free reel in TORQUE_CONTROL (G in the module
        docstring). Raises ValueError on a node id outside 0..63, a non-finite position, a
        non-positive limit, gain, mobility or period, or a negative or non-finite watchdog
        timeout or torque period.
        """
        if not 0 <= node_id <= cs.MAX_NODE_ID:
            raise ValueError(f"node id {node_id} is outside 0..63")
        if not math.isfinite(initial_position_rev):
            raise ValueError("initial_position_rev must be finite")
        for name, value in (
            ("max_velocity_rps", max_velocity_rps),
            ("max_accel_rps2", max_accel_rps2),
            ("encoder_period_s", encoder_period_s),
            ("heartbeat_period_s", heartbeat_period_s),
            ("pos_gain", pos_gain),
            ("torque_mobility_rps_per_nm", torque_mobility_rps_per_nm),
        ):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        if not (math.isfinite(watchdog_timeout_s) and watchdog_timeout_s >= 0.0):
            raise ValueError(
                f"watchdog_timeout_s must be finite and >= 0, got {watchdog_timeout_s!r}"
            )
        if not (math.isfinite(torque_period_s) and torque_period_s >= 0.0):
            raise ValueError(f"torque_period_s must be finite and >= 0, got {torque_period_s!r}")
        self.node_id = node_id
        self.max_velocity_rps = max_velocity_rps
        self.max_accel_rps2 = max_accel_rps2
        self.encoder_period_s = encoder_period_s
        self.heartbeat_period_s = heartbeat_period_s
        self.pos_gain = pos_gain
        self.watchdog_timeout_s = watchdog_timeout_s
        self.torque_period_s = torque_period_s
        self.torque_mobility_rps_per_nm = torque_mobility_rps_per_nm
        self.load_torque_nm = 0.0
        """The torque the load needs of the motor (set by the bank's coupling each tick)."""
        self.coupled = False
        """True when a coupling (a load) turns this axis in TORQUE_CONTROL (set by the bank)."""
        self.input_torque_nm = 0.0
        """The TORQUE_CONTROL set-point (Set_Input_Torque)."""
        self._torque_due_s = 0.0
        self._since_feed_s = 0.0
        self._fed = False
        """A host frame fed the watchdog since the last step (that step's time is not counted)."""
        self.position_rev = float(initial_position_rev)
        self.velocity_rps = 0.0
        self.input_pos_rev = self.position_rev
        self.input_vel_rps = 0.0
        self.axis_state: int = cs.AxisState.IDLE
        self.axis_error: int = 0
        self.disarm_reason: int = 0
        self.procedure_result = 0
        self.control_mode: int = cs.ControlMode.POSITION_CONTROL
        self.input_mode: int = cs.InputMode.PASSTHROUGH
        self.commands_received = 0
        self._silent = False
        self._drift_rate_rps = 0.0
        self._drift_rev = 0.0
        self._pending_corrupt = 0
        self._pending_nan = 0
        self._encoder_due_s = 0.0
        self._heartbeat_due_s = 0.0
        self._lock = threading.Lock()

    # --- fault injection --------------------------------------------------------------------

    def silence(self, silent: bool = True) -> None:
        """Go silent (no frames received or sent), or speak again."""
        with self._lock:
            self._silent = silent

    def set_axis_error(self, code: int) -> None:
        """Raise axis error `code` (ODriveError bits): the axis disarms to IDLE, like firmware."""
        with self._lock:
            self.axis_error |= code
            self.disarm_reason = code
            self._disarm()

    def reboot(self) -> None:
        """Restart the axis as firmware does after a reset: IDLE, no error, position control in
        passthrough, holding where the reel is (the position is kept: an absolute encoder, or an
        incremental one whose count survives a reset of the processor only)."""
        with self._lock:
            self._disarm()
            self.axis_error = 0
            self.disarm_reason = 0
            self.control_mode = cs.ControlMode.POSITION_CONTROL
            self.input_mode = cs.InputMode.PASSTHROUGH
            self.input_pos_rev = self.position_rev
            self.input_vel_rps = 0.0
            self.input_torque_nm = 0.0

    def send_corrupt(self, count: int = 1) -> None:
        """Emit `count` wrong-length (5 byte) encoder frames with the next step."""
        with self._lock:
            self._pending_corrupt += count

    def send_nan(self, count: int = 1) -> None:
        """Emit `count` encoder frames with a NaN position with the next step."""
        with self._lock:
            self._pending_nan += count

    def drift(self, rate_rev_per_s: float) -> None:
        """Let the reported encoder estimate drift from the true position at this rate."""
        if not math.isfinite(rate_rev_per_s):
            raise ValueError("drift rate must be finite")
        with self._lock:
            self._drift_rate_rps = rate_rev_per_s

    def set_load_torque(self, torque_nm: float) -> None:
        """Set the torque (N m) the load needs of the motor; a non-finite value is ignored."""
        if math.isfinite(torque_nm):
            with self._lock:
                self.load_torque_nm = torque_nm

    @property
    def pull_nm(self) -> float | None:
        """The torque the motor makes in TORQUE_CONTROL (closed loop), else None: what the
        bank hands its coupling, which then turns the reel (`follow_load`)."""
        if (
            self.axis_state == cs.AxisState.CLOSED_LOOP_CONTROL
            and self.control_mode == cs.ControlMode.TORQUE_CONTROL
        ):
            return self.input_torque_nm
        return None

    def follow_load(self, position_rev: float, dt_s: float) -> None:
        """In TORQUE_CONTROL with a load: the reel is at `position_rev` after `dt_s` (the
        coupling turned it); the velocity follows. A non-finite value is ignored."""
        if math.isfinite(position_rev) and dt_s > 0.0:
            with self._lock:
                self.velocity_rps = (position_rev - self.position_rev) / dt_s
                self.position_rev = position_rev

    @property
    def torque_estimate_nm(self) -> float:
        """The torque the axis reports: in closed loop input_torque in TORQUE_CONTROL, else the
        load's; 0 when IDLE (braked)."""
        if self.axis_state == cs.AxisState.CLOSED_LOOP_CONTROL:
            if self.control_mode == cs.ControlMode.TORQUE_CONTROL:
                return self.input_torque_nm
            return self.load_torque_nm
        return 0.0

    @property
    def encoder_estimate_rev(self) -> float:
        """The position this axis reports (true position plus accumulated drift)."""
        return self.position_rev + self._drift_rev

    # --- protocol ---------------------------------------------------------------------------

    def _disarm(self) -> None:
        self.axis_state = cs.AxisState.IDLE
        self.velocity_rps = 0.0

    def _encoder_frame(self) -> cs.Frame:
        return cs.encode_encoder_estimates(
            self.node_id, self.position_rev + self._drift_rev, self.velocity_rps
        )

    def _torques_frame(self) -> cs.Frame:
        t = self.torque_estimate_nm
        return cs.encode_torques(self.node_id, t, t)

    def _heartbeat_frame(self) -> cs.Frame:
        traj_done = self.position_rev == self.input_pos_rev and self.velocity_rps == 0.0
        return cs.encode_heartbeat(
            self.node_id, self.axis_error, self.axis_state, self.procedure_result, traj_done
        )

    def handle(self, msg: cs.Message) -> list[cs.Frame]:
        """Apply one decoded frame addressed to this axis; return the frames sent in answer.

        Frames for other nodes and ODrive-to-host messages are ignored (empty list).
        """
        with self._lock:
            if self._silent or msg.node_id != self.node_id:
                return []
            return self._handle(msg)

    def _handle(self, msg: cs.Message) -> list[cs.Frame]:
        t = type(msg)
        if t in _HOST_TX_TYPES:
            self._since_feed_s = 0.0  # any frame from a host to the axis feeds its watchdog
            self._fed = True
        if t is cs.SetInputPos:
            assert isinstance(msg, cs.SetInputPos)
            self.commands_received += 1
            self.input_pos_rev = msg.input_pos_rev
            self.input_vel_rps = msg.vel_ff_rps
        elif t is cs.SetAxisState:
            assert isinstance(msg, cs.SetAxisState)
            if msg.requested_state == cs.AxisState.CLOSED_LOOP_CONTROL:
                if self.axis_error:
                    self.procedure_result = 13  # INVALID_STATE: refused while an error is active
                else:
                    if self.axis_state != cs.AxisState.CLOSED_LOOP_CONTROL:
                        self.input_pos_rev = self.position_rev  # hold where the reel is
                        self.input_vel_rps = 0.0
                    self.axis_state = cs.AxisState.CLOSED_LOOP_CONTROL
                    self.procedure_result = 0
            elif msg.requested_state == cs.AxisState.IDLE:
                self._disarm()
        elif t is cs.Estop:
            self.axis_error |= cs.ODriveError.ESTOP_REQUESTED
            self.disarm_reason = cs.ODriveError.ESTOP_REQUESTED
            self._disarm()
        elif t is cs.ClearErrors:
            self.axis_error = 0
            self.procedure_result = 0
        elif t is cs.SetControllerMode:
            assert isinstance(msg, cs.SetControllerMode)
            self.control_mode = cs.ControlMode(msg.control_mode & 3)
            try:
                self.input_mode = cs.InputMode(msg.input_mode)
            except ValueError:
                self.input_mode = cs.InputMode.INACTIVE
        elif t is cs.SetInputTorque:
            assert isinstance(msg, cs.SetInputTorque)
            self.input_torque_nm = msg.input_torque_nm
        elif t is cs.SetInputVel:
            assert isinstance(msg, cs.SetInputVel)
            self.input_vel_rps = msg.input_vel_rps
        elif t is cs.SetLimits:
            assert isinstance(msg, cs.SetLimits)
            if msg.velocity_limit_rps > 0.0:
                self.max_velocity_rps = msg.velocity_limit_rps
        elif t is cs.RemoteRequest:
            assert isinstance(msg, cs.RemoteRequest)
            if msg.cmd_id == cs.GET_ENCODER_ESTIMATES:
                return [self._encoder_frame()]
            if msg.cmd_id == cs.HEARTBEAT:
                return [self._heartbeat_frame()]
            if msg.cmd_id == cs.GET_ERROR:
                return [cs.encode_get_error(self.node_id, self.axis_error, self.disarm_reason)]
            if msg.cmd_id == cs.GET_TORQUES:
                return [self._torques_frame()]
        return []

    def step(self, dt_s: float) -> list[cs.Frame]:
        """Advance the simulation by `dt_s` seconds; return the broadcasts that fall due."""
        self.advance(dt_s)
        return self.broadcasts(dt_s)

    def advance(self, dt_s: float) -> None:
        """Advance the motion (and watchdog, drift) by `dt_s` seconds; no frames."""
        with self._lock:
            if dt_s > 0.0:
                run_s = self._watchdog(dt_s)
                if run_s > 0.0:
                    self._move(run_s)
                self._drift_rev += self._drift_rate_rps * dt_s

    def broadcasts(self, dt_s: float) -> list[cs.Frame]:
        """The cyclic frames that fall due after `dt_s` more seconds (`step` = `advance` + this)."""
        with self._lock:
            if self._silent:
                return []
            out: list[cs.Frame] = []
            enc_id = cs.arbitration_id(self.node_id, cs.GET_ENCODER_ESTIMATES)
            while self._pending_corrupt:
                self._pending_corrupt -= 1
                out.append((enc_id, b"\x00\x00\x80\x3f\x00", False))
            while self._pending_nan:
                self._pending_nan -= 1
                out.append((enc_id, _NAN_ENCODER, False))
            self._encoder_due_s -= dt_s
            if self._encoder_due_s <= 0.0:
                self._encoder_due_s = max(self._encoder_due_s + self.encoder_period_s, 0.0)
                out.append(self._encoder_frame())
            if self.torque_period_s > 0.0:
                self._torque_due_s -= dt_s
                if self._torque_due_s <= 0.0:
                    self._torque_due_s = max(self._torque_due_s + self.torque_period_s, 0.0)
                    out.append(self._torques_frame())
            self._heartbeat_due_s -= dt_s
            if self._heartbeat_due_s <= 0.0:
                self._heartbeat_due_s = max(self._heartbeat_due_s + self.heartbeat_period_s, 0.0)
                out.append(self._heartbeat_frame())
            return out

    def _watchdog(self, dt: float) -> float:
        """Count `dt` on the watchdog; return how long of it the axis stays in closed loop
        (all of it, or up to the expiry, where it disarms: a late step on a busy host does not
        run the axis past its watchdog time)."""
        if self.watchdog_timeout_s <= 0.0 or self.axis_state != cs.AxisState.CLOSED_LOOP_CONTROL:
            self._fed = False
            return dt
        if self._fed:
            # fed during this step: the frame came within it, at the latest just now (after a
            # stall, the backlog the serving loop drained before stepping)
            self._fed = False
            return dt
        left = self.watchdog_timeout_s - self._since_feed_s
        if dt > left:
            self.axis_error |= cs.ODriveError.WATCHDOG_TIMER_EXPIRED
            self.disarm_reason = cs.ODriveError.WATCHDOG_TIMER_EXPIRED
            if left > 0.0:
                self._move(left)
            self._disarm()
            return 0.0
        self._since_feed_s += dt
        return dt

    def _move(self, dt: float) -> None:
        if self.axis_state != cs.AxisState.CLOSED_LOOP_CONTROL:
            return
        if self.control_mode == cs.ControlMode.TORQUE_CONTROL:
            if not self.coupled:  # with a load, the coupling turns the reel (`follow_load`)
                self._move_free_torque(dt)
            return
        if (
            self.velocity_rps == 0.0
            and self.input_vel_rps == 0.0
            and (
                self.control_mode == cs.ControlMode.VELOCITY_CONTROL
                or self.position_rev == self.input_pos_rev
            )
        ):
            return  # at rest on the set-point: nothing to integrate
        n = min(_MAX_SUBSTEPS, math.ceil(dt / MAX_SUBSTEP_S))
        h = dt / n
        for _ in range(n):
            self._substep(h)

    def _move_free_torque(self, dt: float) -> None:
        """TORQUE_CONTROL without a load over `dt` (module docstring): spin at G * torque."""
        if self.input_torque_nm == 0.0 and self.velocity_rps == 0.0:
            return  # no torque, at rest: nothing to integrate
        vmax = self.max_velocity_rps
        vel_cmd = max(-vmax, min(vmax, self.torque_mobility_rps_per_nm * self.input_torque_nm))
        n = min(_MAX_SUBSTEPS, math.ceil(dt / MAX_SUBSTEP_S))
        h = dt / n
        dv_max = self.max_accel_rps2 * h
        v = self.velocity_rps
        p = self.position_rev
        for _ in range(n):
            v += max(-dv_max, min(dv_max, vel_cmd - v))
            p += v * h
        self.position_rev = p
        self.velocity_rps = v

    def _substep(self, h: float) -> None:
        """One integration step of the cascaded loop (see the module docstring)."""
        vmax = self.max_velocity_rps
        dv_max = self.max_accel_rps2 * h
        v = self.velocity_rps
        mode = self.control_mode
        if mode == cs.ControlMode.POSITION_CONTROL:
            vel_cmd = self.input_vel_rps + self.pos_gain * (self.input_pos_rev - self.position_rev)
        elif mode == cs.ControlMode.VELOCITY_CONTROL:
            vel_cmd = self.input_vel_rps
        else:
            vel_cmd = 0.0
        vel_cmd = max(-vmax, min(vmax, vel_cmd))
        v_new = v + max(-dv_max, min(dv_max, vel_cmd - v))
        p_new = self.position_rev + 0.5 * (v + v_new) * h
        if (
            mode == cs.ControlMode.POSITION_CONTROL
            and self.input_vel_rps == 0.0
            and abs(self.input_pos_rev - p_new) <= REST_SNAP_REV
            and abs(v_new) <= REST_SNAP_RPS
        ):
            p_new = self.input_pos_rev  # settled (the exponential approach never ends exactly)
            v_new = 0.0
        self.position_rev = p_new
        self.velocity_rps = v_new


class AxisCoupling(Protocol):
    """What the axes move: stepped once per tick with every axis's motor position."""

    def step(
        self,
        positions_rev: Sequence[float],
        dt_s: float,
        pulls_nm: Sequence[float | None] | None = None,
        max_speeds_rps: Sequence[float] | None = None,
    ) -> Sequence[float]:
        """Advance by `dt_s` with the motors at `positions_rev` (the bank's axis order), those
        in torque control pulling with `pulls_nm` (None for the others) at most
        `max_speeds_rps`; return the torque (N m) each motor makes or needs. May raise: the
        bank counts it and keeps the last torques."""
        ...

    @property
    def positions_rev(self) -> Sequence[float]:
        """After `step`: every motor's turns (those given, or where the load turned an axis in
        torque control)."""
        ...


@dataclass
class SimStats:
    """What the serving loop did: ticks, late ticks, time spent working, coupling errors.

    `busy_s` is the time spent in the ticks' work (moving the axes, the coupling, sending), so
    ``simulated_s / busy_s`` is the real-time factor: how many times faster than real time the
    simulation could run on this CPU.
    """

    ticks: int = 0
    late_ticks: int = 0
    """Ticks that started more than one tick period late (the next deadline was reset)."""
    simulated_s: float = 0.0
    busy_s: float = 0.0
    coupling_errors: int = 0
    last_coupling_error: str | None = None

    @property
    def real_time_factor(self) -> float:
        """Simulated time over working time (inf before any work)."""
        return self.simulated_s / self.busy_s if self.busy_s > 0.0 else math.inf


def step_axes(axes: Sequence[SimODriveAxis], coupling: AxisCoupling | None, dt_s: float) -> None:
    """One tick of the simulated drives' motion, no frames: every axis advances `dt_s`, then
    the `coupling` (if any) steps with their positions and the torques of those in torque
    control, and each axis gets its load torque (one in torque control also the turns the load
    gave it). Raises whatever the coupling raises (the axes have moved; the loads stay)."""
    for axis in axes:
        axis.advance(dt_s)
    if coupling is None:
        return
    pulls = [a.pull_nm for a in axes]
    any_pull = any(p is not None for p in pulls)
    torques = coupling.step(
        [a.position_rev for a in axes],
        dt_s,
        pulls if any_pull else None,
        [a.max_velocity_rps for a in axes] if any_pull else None,
    )
    positions = coupling.positions_rev if any_pull else None
    for k, axis in enumerate(axes):
        axis.set_load_torque(torques[k])
        if positions is not None and pulls[k] is not None:
            axis.follow_load(positions[k], dt_s)


def run_sim(
    bus: can.BusABC,
    axes: Sequence[SimODriveAxis],
    stop_event: threading.Event,
    *,
    tick_s: float = 0.001,
    coupling: AxisCoupling | None = None,
    stats: SimStats | None = None,
    fast_path: bool | FastSocketCan = True,
) -> None:
    """Serve `axes` on `bus` until `stop_event` is set: answer commands, broadcast every tick.

    The bus is met through a `drivers.simbank.SimLink` (on SocketCAN, with `fast_path`, the
    fast path's batches): the answers to what was received together leave together.

    Every tick: move each axis, step the `coupling` (if any, with the torques of the axes in
    torque control) and hand each axis its torque (and an axis in torque control the turns the
    load gave it), then send the broadcasts that fall due. Receive errors, send errors
    and coupling errors are swallowed (a simulated node keeps running; coupling errors are
    counted in `stats`); undecodable frames are ignored. Returns within about one tick after
    `stop_event` is set.
    """
    by_node: dict[int, SimODriveAxis] = {a.node_id: a for a in axes}
    if len(by_node) != len(axes):
        raise ValueError("duplicate node ids among simulated axes")
    clock = time.monotonic
    last = clock()
    next_tick = last + tick_s
    st = SimStats() if stats is None else stats
    if coupling is not None:
        for a in axes:
            a.coupled = True

    link = SimLink(bus, fast_path=fast_path)
    out: list[cs.Frame] = []

    def handle(can_id: int, data: bytes | bytearray, stamp: float) -> None:
        if can_id & CAN_ERR_FLAG:
            return
        remote, extended = bool(can_id & CAN_RTR_FLAG), bool(can_id & CAN_EFF_FLAG)
        m = cs.decode(can_id & CAN_EFF_MASK, data, remote, extended)
        if not isinstance(m, cs.DecodeError):
            axis = by_node.get(m.node_id)
            if axis is not None:
                out.extend(axis.handle(m))

    while not stop_event.is_set():
        now = clock()
        remaining = next_tick - now
        if remaining > 0.0:
            link.serve(handle, remaining, remaining)
            link.send(out)
            out.clear()
            continue
        # Before stepping, every frame already received: after a stall of this thread (a busy
        # host) the commands that queued meanwhile feed the watchdogs and set the set-points
        # before the stall's time is judged, and the backlog cannot grow tick after tick.
        link.serve(handle, 0.0, math.inf, MAX_DRAIN_FRAMES)
        link.send(out)
        out.clear()
        now = clock()
        dt = now - last
        last = now
        late = remaining <= -tick_s
        next_tick = now + tick_s if late else next_tick + tick_s
        try:
            step_axes(axes, coupling, dt)
        except Exception as exc:  # the simulated robot keeps serving; the error is counted
            st.coupling_errors += 1
            st.last_coupling_error = f"{type(exc).__name__}: {exc}"
        for axis in axes:
            out.extend(axis.broadcasts(dt))
        link.send(out)
        out.clear()
        st.ticks += 1
        st.late_ticks += late
        st.simulated_s += dt
        st.busy_s += clock() - now


class SimODriveBank(ThreadedSimBank):
    """Simulated ODrive axes served on `bus` by a background thread (a context manager).

    The bank does not own the bus: the caller shuts it down after `stop()`.
    """

    thread_name = "sim-odrive"

    def __init__(
        self,
        bus: can.BusABC,
        axes: Sequence[SimODriveAxis],
        *,
        tick_s: float = 0.001,
        coupling: AxisCoupling | None = None,
    ) -> None:
        """Prepare (not start) the bank; `coupling` is the load the axes move (None: none).

        Raises ValueError on duplicate node ids or tick_s <= 0."""
        if len({a.node_id for a in axes}) != len(axes):
            raise ValueError("duplicate node ids among simulated axes")
        if not (math.isfinite(tick_s) and tick_s > 0.0):
            raise ValueError("tick_s must be finite and > 0")
        super().__init__()
        self.bus = bus
        self.axes: tuple[SimODriveAxis, ...] = tuple(axes)
        self.tick_s = tick_s
        self.coupling = coupling
        self.stats = SimStats()
        """Live counters of the serving thread (see `SimStats`)."""

    def carry(self, coupling: AxisCoupling, torque_period_s: float = 0.0) -> None:
        """Give the axes a load before `start`: `coupling` is stepped every tick, and every
        axis broadcasts Get_Torques every `torque_period_s` (0: by RTR only). Raises
        RuntimeError once started, ValueError on a negative or non-finite period."""
        if self.started:
            raise RuntimeError("SimODriveBank already started: give it its load before")
        if not (math.isfinite(torque_period_s) and torque_period_s >= 0.0):
            raise ValueError(f"torque_period_s must be finite and >= 0, got {torque_period_s!r}")
        self.coupling = coupling
        for a in self.axes:
            a.torque_period_s = torque_period_s

    def axis(self, node_id: int) -> SimODriveAxis:
        """The simulated axis with this node id. Raises KeyError if there is none."""
        for a in self.axes:
            if a.node_id == node_id:
                return a
        raise KeyError(node_id)

    def _serve(self, stop: threading.Event) -> None:
        run_sim(
            self.bus, self.axes, stop, tick_s=self.tick_s, coupling=self.coupling, stats=self.stats
        )


def open_sim_bank(
    bus: can.BusABC, node_ids: Sequence[int], options: Mapping[str, Any], sim: SimSettings
) -> SimODriveBank:
    """The registry's simulator factory (`drivers.registry`, family "odrive"): one
    `SimODriveAxis` per node with the `[sim]` settings, served by a bank (not started).

    Raises ValueError on bad node ids or settings, or a position per node missing.
    """
    if len(sim.initial_positions_rev) != len(node_ids):
        raise ValueError(
            f"{len(node_ids)} initial positions needed, got {len(sim.initial_positions_rev)}"
        )
    axes = [
        SimODriveAxis(
            int(n),
            initial_position_rev=x,
            max_velocity_rps=sim.max_velocity_rps,
            max_accel_rps2=sim.max_accel_rps2,
            encoder_period_s=sim.encoder_period_s,
            heartbeat_period_s=sim.heartbeat_period_s,
            watchdog_timeout_s=sim.watchdog_timeout_s,
        )
        for n, x in zip(node_ids, sim.initial_positions_rev, strict=True)
    ]
    return SimODriveBank(bus, axes, tick_s=sim.tick_s)


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m drivers.odrive.sim`: serve simulated axes on a bus until SIGTERM/SIGINT.

    Prints "READY <nodes>" on stdout once the bus is open and the axes are served.
    """
    p = argparse.ArgumentParser(prog="python -m drivers.odrive.sim", description=__doc__)
    add_bus_arguments(p)
    p.add_argument("--nodes", default="0,1,2,3", help="comma-separated node ids")
    p.add_argument("--initial-rev", default="0", help="one value, or one per node")
    p.add_argument("--max-velocity-rps", type=float, default=20.0)
    p.add_argument("--max-accel-rps2", type=float, default=200.0)
    p.add_argument(
        "--pos-gain", type=float, default=DEFAULT_POS_GAIN, help="position gain, (rev/s)/rev"
    )
    p.add_argument("--encoder-period-s", type=float, default=0.01)
    p.add_argument("--heartbeat-period-s", type=float, default=0.1)
    p.add_argument(
        "--watchdog-timeout-s",
        type=float,
        default=0.0,
        help="axis watchdog: IDLE after this long in closed loop without a command (0: off)",
    )
    args = p.parse_args(argv)
    nodes = [int(n) for n in args.nodes.split(",")]
    initial = floats_arg(args.initial_rev, len(nodes))
    axes = [
        SimODriveAxis(
            n,
            initial_position_rev=x,
            max_velocity_rps=args.max_velocity_rps,
            max_accel_rps2=args.max_accel_rps2,
            pos_gain=args.pos_gain,
            encoder_period_s=args.encoder_period_s,
            heartbeat_period_s=args.heartbeat_period_s,
            watchdog_timeout_s=args.watchdog_timeout_s,
        )
        for n, x in zip(nodes, initial, strict=True)
    ]
    return serve_process(
        args, nodes, lambda bus, stop: run_sim(bus, axes, stop, tick_s=args.tick_s)
    )


if __name__ == "__main__":
    sys.exit(main())
