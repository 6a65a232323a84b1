"""The driver contract: what the control loop sees of any reel driver.

`AxisReading` is the latest known state of one reel motor, `BusStats` the receive/transmit
counters of one bus, and `ReelDriver` the protocol every driver implements (the ODrive one is
`drivers.odrive.driver.ODriveReels`). Only the standard library is imported here, so the loop
can depend on this module without pulling in python-can.
"""

from __future__ import annotations

import errno
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

NEVER_S = -math.inf
"""`stamp_s` / `heartbeat_stamp_s` value of an axis that has never been heard from."""


class DriverError(RuntimeError):
    """Base class of the errors the driver layer raises on its transmit/open paths."""


class BusError(DriverError):
    """Sending on the bus failed (python-can `CanError` or OS error); the message says which.

    `ODriveReels.command/arm/disarm/estop` raise it after counting the failure in
    `BusStats.bus_errors` and `BusStats.last_error`, so the loop can enter its fault state.
    """


class ArmRefused(DriverError):
    """The driver cannot arm now and sent nothing (CiA 402: a restarted drive is being
    configured again beside the loop); the message names the drives and why. Arming again
    later can succeed."""


@dataclass(slots=True)
class AxisReading:
    """Latest known state of one reel motor (one drive axis).

    The driver keeps one mutable instance per axis and updates it in place while polling;
    `ReelDriver.read()` returns those instances (copy them with `snapshot()` to keep a value).
    The control loop reads only the generic status (`ready`, `fault`, `state_name`) and the
    stamps; `axis_state` / `axis_error` are the drive's raw numbers, kept for diagnostics.
    """

    node_id: int
    position_rev: float = 0.0
    """Motor turns from Get_Encoder_Estimates (always finite)."""
    velocity_rps: float = 0.0
    """Motor turns per second from Get_Encoder_Estimates (always finite)."""
    stamp_s: float = NEVER_S
    """Clock time (time.monotonic() by default) of the encoder reading: when its frame arrived
    on the bus (ODrive: the interface's receive timestamp, not when the loop read it) or, for a
    CiA 402 TPDO, when `poll` handled it; -inf = never."""
    stamp_ns: int = 0
    """time.time_ns() wall clock of the same arrival; 0 = never."""
    axis_state: int = 0
    """The drive's raw state number (ODrive: AxisState from the last heartbeat, 0 UNDEFINED
    until one arrives, 8 CLOSED_LOOP_CONTROL); for diagnostics, the loop does not read it."""
    axis_error: int = 0
    """The drive's raw error number (ODrive: axis error bits of the last heartbeat); 0 = no
    error; for diagnostics, the loop does not read it."""
    heartbeat_stamp_s: float = NEVER_S
    """Clock time when the last heartbeat arrived on the bus; -inf = never."""
    ready: bool = False
    """The axis follows set-points (ODrive: CLOSED_LOOP_CONTROL; CiA 402: Operation enabled)."""
    fault: str | None = None
    """A readable name of the drive's fault with its code (ODrive: "ESTOP_REQUESTED
    (0x2000000)"; CiA 402: "EMCY 0x2310 Continuous over-current (Current)"); None = no fault."""
    state_name: str = "unknown"
    """The drive's own name for its state, for people (ODrive: "IDLE"; CiA 402: "Operation
    enabled"); "unknown" until the drive has been heard."""
    torque_nm: float = 0.0
    """The motor's torque estimate (N m, motor's positive direction; ODrive Get_Torques),
    always finite; meaningful once `torque_stamp_s` is set."""
    torque_stamp_s: float = NEVER_S
    """Clock time when the last torque reading arrived on the bus; -inf = never."""
    command_stamp_s: float = NEVER_S
    """Clock time when the driver last sent this axis a command that changes its state (arm,
    disarm, e-stop, entering torque control, clearing errors); -inf = never."""
    status_stamp_s: float = NEVER_S
    """Clock time of the drive's latest report of its status (`ready`, `fault`,
    `state_name`) that answers the last state-changing command: the driver moves it only on a
    report the drive sent after taking that command (ODrive: a heartbeat that arrived after
    it was sent; CiA 402: a statusword answering a SYNC sent after it); -inf = none yet.
    While it is older than `command_stamp_s` the status fields still show the drive's state
    before the command (see `status_fresh`)."""
    count_epoch: int = 0
    """How many times the drive's position count started afresh (CiA 402: a drive whose
    position after a restart is not the one before, as an incremental encoder's): positions
    of different epochs are not comparable, so homing offsets taken before no longer hold."""

    def status_fresh(self) -> bool:
        """True if `ready`, `fault` and `state_name` come from a report that answers the last
        state-changing command (`status_stamp_s >= command_stamp_s`), so the drive's state can
        be judged on them; False while the drive has not answered it yet. Raises nothing."""
        return self.status_stamp_s >= self.command_stamp_s

    def snapshot(self) -> AxisReading:
        """Return an independent copy of this reading."""
        return AxisReading(
            self.node_id,
            self.position_rev,
            self.velocity_rps,
            self.stamp_s,
            self.stamp_ns,
            self.axis_state,
            self.axis_error,
            self.heartbeat_stamp_s,
            self.ready,
            self.fault,
            self.state_name,
            self.torque_nm,
            self.torque_stamp_s,
            self.command_stamp_s,
            self.status_stamp_s,
            self.count_epoch,
        )

    def encoder_age_s(self, now_s: float) -> float:
        """Seconds since the last encoder frame at clock time `now_s` (inf if never)."""
        return now_s - self.stamp_s

    def heartbeat_age_s(self, now_s: float) -> float:
        """Seconds since the last heartbeat at clock time `now_s` (inf if never)."""
        return now_s - self.heartbeat_stamp_s


@dataclass(slots=True)
class BusStats:
    """Counters of one driver's bus traffic.

    `decode_errors` counts frames that failed to decode (wrong length, NaN/inf value, unknown
    command, extended id); `dropped` counts well-formed frames that were ignored (unknown node,
    messages the driver does not use); `commands_heard` counts host-to-drive commands heard on
    the bus (cablebot's own, echoed back by udp_multicast, or another master's): traffic, not
    loss; `errors_by_kind` breaks all three down by name (e.g.
    "length", "non_finite", "unknown_command", "unknown_node"; "rx_overrun" for frames the
    kernel dropped from a full receive queue, "error_frame" for SocketCAN error frames, which are
    bus errors, not dropped frames). `bus_errors`/`last_error` count and describe failed sends,
    error frames and receive-side OS errors.
    """

    frames_rx: int = 0
    frames_tx: int = 0
    decode_errors: int = 0
    dropped: int = 0
    bus_errors: int = 0
    last_error: str | None = None
    ff_clamped: int = 0
    """Velocity feed-forward values clamped to the int16 wire range (±32.767 rev/s)."""
    errors_by_kind: dict[str, int] = field(default_factory=dict)
    untimed_frames: int = 0
    """Frames whose interface timestamp was not a wall-clock reading (stamped at poll time)."""
    catch_up_polls: int = 0
    """Polls that read past their frame cap to catch up with a backlog (after a loop stall)."""
    commands_heard: int = 0
    """Host-to-drive commands heard on the bus (own frames echoed back, or another master's)."""
    conflicts: int = 0
    """Frames heard that only a bus master sends and this host did not send (CiA 402: another
    SYNC producer): two masters on one bus. The loop faults on it by name (`last_conflict`)."""
    last_conflict: str | None = None

    def count(self, kind: str, *, decode_error: bool = False) -> None:
        """Count one received frame that was not taken, by `kind`: a decode error
        (`decode_error`), host traffic heard on the bus (kind "not_for_host": `commands_heard`,
        not a loss), or else a dropped frame. Raises nothing."""
        if decode_error:
            self.decode_errors += 1
        elif kind == "not_for_host":
            self.commands_heard += 1
        else:
            self.dropped += 1
        self.errors_by_kind[kind] = self.errors_by_kind.get(kind, 0) + 1

    def count_bus_error(self, text: str) -> None:
        """Count one failed send (or receive-side OS error) described by `text`."""
        self.bus_errors += 1
        self.last_error = text

    def count_send_failure(self, what: str, exc: BaseException) -> str:
        """Count one frame that could not be sent (`what`: the frame, e.g. "0x202" or
        "Estop to node 1") and return its name, the one wording of every drive family and send
        path: "send <what>: <errno name>: <error>" for an OS error with an errno (e.g.
        "ENOBUFS: No buffer space available"), else "send <what>: <exception type>:
        <exception>". Raises nothing."""
        if isinstance(exc, OSError) and exc.errno:
            cause = f"{errno.errorcode.get(exc.errno, type(exc).__name__)}: {exc.strerror}"
        else:
            cause = f"{type(exc).__name__}: {exc}"
        text = f"send {what}: {cause}"
        self.count_bus_error(text)
        return text

    def count_error_frame(self, error_id: int) -> None:
        """Count one SocketCAN error frame (`error_id`: its id without the flag, the error
        class bits): a bus error (bus-off, controller or protocol trouble; the loop faults when
        they persist), kind "error_frame", not a dropped data frame. Raises nothing."""
        self.count_bus_error(f"CAN error frame 0x{error_id:x}")
        self.errors_by_kind["error_frame"] = self.errors_by_kind.get("error_frame", 0) + 1

    def count_conflict(self, text: str) -> None:
        """Count one frame of another bus master (`text` names it). Raises nothing."""
        self.conflicts += 1
        self.last_conflict = text
        self.errors_by_kind["another_master"] = self.errors_by_kind.get("another_master", 0) + 1

    def count_rx_overrun(self, lost: int) -> None:
        """Count `lost` frames the kernel dropped because the receive queue was full (the loop
        did not poll in time): dropped frames of kind "rx_overrun", not bus errors (the
        stale-reading rules judge the stall). Raises nothing."""
        if lost > 0:
            self.dropped += lost
            self.errors_by_kind["rx_overrun"] = self.errors_by_kind.get("rx_overrun", 0) + lost

    def snapshot(self) -> BusStats:
        """Return an independent copy of these counters."""
        return BusStats(
            self.frames_rx,
            self.frames_tx,
            self.decode_errors,
            self.dropped,
            self.bus_errors,
            self.last_error,
            self.ff_clamped,
            dict(self.errors_by_kind),
            self.untimed_frames,
            self.catch_up_polls,
            self.commands_heard,
            self.conflicts,
            self.last_conflict,
        )


@runtime_checkable
class ReelDriver(Protocol):
    """A set of reel motors on one bus, as the control loop drives them.

    Threading: one thread (the loop) calls every method; none blocks on the bus for long.
    """

    node_ids: tuple[int, ...]

    def poll(self) -> int:
        """Drain received frames without blocking and update readings; return frames handled.

        Never raises for bad frames: they are counted in `stats` and dropped.
        """
        ...

    def read(self) -> Sequence[AxisReading]:
        """Latest reading per axis, in the order of `node_ids`; no I/O."""
        ...

    def command(
        self, positions_rev: Sequence[float], velocity_ff_rps: Sequence[float] | None = None
    ) -> None:
        """Send position set-points (motor turns), one per axis.

        Raises ValueError (and sends nothing) if any value is not finite or the lengths are
        wrong; raises BusError if the bus refuses a frame.
        """
        ...

    def arm(self) -> None:
        """Clear errors, select position control with passthrough input, enter closed loop."""
        ...

    def disarm(self) -> None:
        """Request IDLE on every axis."""
        ...

    def estop(self) -> None:
        """Send Estop to every axis."""
        ...

    def request_encoders(self) -> None:
        """Ask every axis for its encoder estimates (RTR poll); the answers arrive via poll()."""
        ...

    @property
    def stats(self) -> BusStats:
        """Traffic counters (a live object; copy with `snapshot()`)."""
        ...


@runtime_checkable
class ConfigurableDriver(Protocol):
    """A driver whose drives need setting up before cyclic operation (CiA 402: SDO set-up of
    every drive, then NMT start); the daemon calls `configure()` before its loop runs."""

    def configure(self) -> None:
        """Set up every drive (blocking, bounded). Raises a DriverError naming the node and
        the step that failed."""
        ...


@runtime_checkable
class TorqueDriver(Protocol):
    """A driver whose axes can pull with a set torque instead of holding a position: the
    pre-tension before homing (every reel winds gently at a set torque until still).

    The loop calls `enter_torque_mode` once, then `command_torque` every tick (which also
    feeds the drives' watchdogs), then `leave_torque_mode` to hold where the reels came to
    rest. A family without torque control does not implement it; the loop refuses the
    pre-tension for it by name.
    """

    def enter_torque_mode(
        self, torques_nm: Sequence[float], velocity_limits_rps: Sequence[float] | None = None
    ) -> bool:
        """Select torque control on every axis with `torques_nm` (one per axis, N m, motor's
        positive direction) set before the mode changes, so no axis ever pulls with zero (a
        suspended load would drop), and enter closed loop (clearing errors first on an axis
        that is not in closed loop yet). With `velocity_limits_rps` (one per axis, > 0) the
        drives turn no faster than that while in torque mode, where the family can set it
        (ODrive: Set_Limits, which needs the configured current limit). Returns True if the
        velocity limits were applied. Raises ValueError (nothing sent) on a non-finite value,
        a non-positive limit or a wrong count, BusError if a send fails."""
        ...

    def command_torque(self, torques_nm: Sequence[float]) -> None:
        """Send one torque set-point per axis (N m, motor's positive direction). Raises
        ValueError (and sends nothing) on a non-finite value or a wrong count, BusError if
        the bus refuses a frame."""
        ...

    def leave_torque_mode(self, positions_rev: Sequence[float]) -> None:
        """Hold `positions_rev` (one per axis) in position control with passthrough input:
        the position set-point goes out before the mode change, so no drive jumps to an old
        set-point; restores the velocity limits `enter_torque_mode` lowered. Raises
        ValueError (nothing sent) on a non-finite value or a wrong count, BusError."""
        ...
