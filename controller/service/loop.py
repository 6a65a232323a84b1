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

Layout: `Controller` is assembled here from its parts in `controller.service.control`, each a
class built on the one before it: `base.ControllerState` (the shared state, the constructor, the
homing offsets), `faults.FaultHandling` (state changes, fault detection, FAULT hold, e-stop,
disarm), `homing.Homing` (home, its save, the pre-tension), `commands.CommandExecution`
(submitting, preparing and executing commands, one handler per verb), `step.ControlStep` (the
tick and the fixed-rate loop) and `status.StatusReport` (`status()`).
"""

from __future__ import annotations

from controller.service.control.base import (
    COMMAND_QUEUE_SIZE,
    ESTOP_CONFIRM_S,
    MAX_PLANNER_DT_PERIODS,
    TENSION_MAX_SAMPLES,
    TENSION_SAMPLE_FRACTION,
)
from controller.service.control.status import StatusReport
from controller.service.control.step import ControlStep

__all__ = [
    "COMMAND_QUEUE_SIZE",
    "ESTOP_CONFIRM_S",
    "MAX_PLANNER_DT_PERIODS",
    "TENSION_MAX_SAMPLES",
    "TENSION_SAMPLE_FRACTION",
    "Controller",
]


class Controller(ControlStep, StatusReport):
    """The cable robot's controller: states, faults, commands, motion and the control step.

    `cfg` is a `controller.service.config.RobotConfig`; `driver` a `drivers.base.ReelDriver` whose
    `node_ids` are those of `cfg.reels`, in the same order. `offsets_rev` (node id -> motor
    offset) overrides the state file. `clock` and `sleep` are those of `runner`. Raises
    ValueError if the driver's axes do not match.
    """
