"""`ODriveReels`: the `ReelDriver` for ODrive axes speaking CANSimple (firmware 0.6).

Receive path (`poll`): drains the bus without blocking (at most `max_frames_per_poll` frames a
call, so a flooded bus cannot stretch a tick; a backlog of old frames left by a loop stall is read
through up to `CATCH_UP_FACTOR` times that, see `catch_up_age_s`), decodes each frame with
`drivers.odrive.cansimple`, and updates one mutable `AxisReading` per axis: encoder estimates from
the cyclic broadcast (or the RTR replies), axis state and axis error from the heartbeat, and with
them the generic status the loop reads: `ready` (CLOSED_LOOP_CONTROL without an error), `fault`
(the error bits by name with the raw value, e.g. "ESTOP_REQUESTED (0x2000000)") and `state_name`
(the AxisState name, e.g. "IDLE"; worked out only when state or error change); the motor's
torque estimate from Get_Torques (cyclic, or by RTR with `torque_rtr`). Each update
is stamped with the frame's arrival time, not the time it was taken off the queue, so frames
that waited in the receive queue (a stalled loop) are as old as they are: python-can's
`Message.timestamp` is a wall-clock (time.time()) reading on the interfaces cablebot uses, so
its age against the wall clock now, taken from the injected clock (time.monotonic by default)
now, gives the arrival on that clock; the age is clamped at 0 (no frame arrives in the future).
A timestamp more than `TIMESTAMP_FUTURE_TOLERANCE_S` ahead of the wall clock or more than
`TIMESTAMP_MAX_AGE_S` behind it is on some other clock: that frame is stamped at poll time
instead and counted in `stats.untimed_frames`. Nothing raises out of `poll`: bad frames are
counted in `stats` by kind and dropped, frames from nodes not in `node_ids` are counted
("unknown_node") and dropped, and a receive-side bus error is counted.

Transmit path: `command`, `arm`, `disarm`, `estop`, `request_encoders`, and the torque mode of
the pre-tension before homing (`drivers.base.TorqueDriver`: `enter_torque_mode`,
`command_torque`, `leave_torque_mode`). A failed send is counted in
`stats.bus_errors`/`stats.last_error`; the method still tries every axis, then raises
`BusError` naming what failed so the loop can fault.

Freshness after a state-changing command (`arm`, `disarm`, `estop`, `clear_errors`, and
`enter_torque_mode` for the axes it brings into closed loop): the driver stamps the axis's
`command_stamp_s` once the frames are sent, and `status_stamp_s` follows the heartbeats; until a
heartbeat arrives after the command (`AxisReading.status_fresh`), `ready`/`fault`/`state_name`
still describe the drive before it (an e-stop's error, say, until the drive takes the
Clear_Errors), and the loop does not judge the axis on them.

Velocity limit in torque mode: an ODrive in TORQUE_CONTROL turns as fast as the torque
imbalance drives it, up to its vel_limit. `enter_torque_mode` can lower vel_limit for the
pre-tension, but CANSimple sets vel_limit and the current limit together (Set_Limits), so it
does so only when the driver knows both configured values (`velocity_limit_rps`,
`current_limit_a`, the `[drive]` options of the same names), which `leave_torque_mode` (or the
next `arm`) restores.

Velocity feed-forward travels as an int16 in 0.001 rev/s, so it is limited to ±32.767 rev/s:
`command` clamps it to that range (counting `stats.ff_clamped`) instead of refusing the set-point,
because the feed-forward only shapes tracking; the position set-point itself is never altered.

The receive path (with the timestamp constants) is in `drivers.odrive.receive`, the torque mode
in `drivers.odrive.torque`: mixins of `ODriveReels`.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import can

from drivers.base import AxisReading, BusError, BusStats
from drivers.bus import frame_message
from drivers.odrive import cansimple as cs
from drivers.odrive.receive import ODriveReceive
from drivers.odrive.torque import F32_MAX, ODriveTorqueMode, as_float
from drivers.registry import LoopSettings
from drivers.socketcan_fast import FastSocketCan, open_fast_path

DEFAULT_SEND_TIMEOUT_S = 0.005


@dataclass(frozen=True, slots=True)
class AxisFault:
    """A named problem with one axis found by `ODriveReels.check`."""

    node_id: int
    kind: str
    """"silent" (no encoder frames), "no_heartbeat", "axis_error" or "bad_frames"."""
    detail: str


class ODriveReels(ODriveReceive, ODriveTorqueMode):
    """Reel motors on ODrive axes (CANSimple node ids `node_ids`) over one python-can bus.

    The bus is owned by the caller (open it with `drivers.bus.open_bus`, shut it down after).
    Not thread-safe: one thread (the control loop) calls every method.
    """

    def __init__(
        self,
        bus: can.BusABC,
        node_ids: Iterable[int],
        *,
        encoder_rtr: bool = False,
        encoder_rtr_period_s: float = 0.0,
        torque_rtr: bool = False,
        torque_rtr_period_s: float = 0.01,
        max_frames_per_poll: int = 256,
        catch_up_age_s: float = math.inf,
        send_timeout_s: float = DEFAULT_SEND_TIMEOUT_S,
        clock: Callable[[], float] = time.monotonic,
        wall_clock_ns: Callable[[], int] = time.time_ns,
        velocity_limit_rps: float | None = None,
        current_limit_a: float | None = None,
        fast_path: bool | FastSocketCan = True,
    ) -> None:
        """Set up readings for `node_ids` (0..63, unique, at least one).

        `fast_path`: on a python-can SocketCAN bus, receive and send through the bus's kernel
        socket directly (`drivers.socketcan_fast`: batched system calls, no Message objects,
        kernel filters passing only these nodes' data frames and error frames); False keeps
        python-can's path (every other interface always does); a `FastSocketCan` is used as
        given (tests, the benchmark).

        `encoder_rtr`: also request encoder estimates by RTR at the end of every `poll()`
        (answers arrive by the next poll), for ODrives whose cyclic broadcast is off, at most
        once per `encoder_rtr_period_s` (0 = every poll). Mind the bus load: each round is
        2 frames per axis, so 4 axes polled at 1 kHz fill a 1 Mbit/s bus; 2-5 ms is sane there.
        `torque_rtr`: likewise request Get_Torques every `torque_rtr_period_s` (the torques of
        drives that do not broadcast them).
        `catch_up_age_s`: when a poll reaches `max_frames_per_poll` and the last frame taken
        arrived longer ago than this, the queue holds a backlog (the loop stalled), not a flood:
        that poll goes on, up to `CATCH_UP_FACTOR` times the cap, so the readings reach the
        newest frames instead of showing frames from before the stall (inf = never).
        `velocity_limit_rps` / `current_limit_a`: the drives' own configured vel_limit (rev/s)
        and current limit (A), None = unknown; with both the torque mode may lower vel_limit
        and restores these after (module docstring).
        Raises ValueError on bad node ids, a non-positive `max_frames_per_poll` or
        `catch_up_age_s`, a negative `encoder_rtr_period_s`, or a limit that is not a finite
        float32 > 0; OSError if a SocketCAN socket refuses the fast path's options.
        """
        ids = tuple(int(n) for n in node_ids)
        if not ids:
            raise ValueError("ODriveReels needs at least one node id")
        if len(set(ids)) != len(ids):
            raise ValueError(f"duplicate node ids in {ids}")
        for n in ids:
            if not 0 <= n <= cs.MAX_NODE_ID:
                raise ValueError(f"node id {n} is outside 0..63")
        if max_frames_per_poll <= 0:
            raise ValueError("max_frames_per_poll must be > 0")
        if not catch_up_age_s > 0.0:
            raise ValueError("catch_up_age_s must be > 0")
        if not (math.isfinite(encoder_rtr_period_s) and encoder_rtr_period_s >= 0.0):
            raise ValueError("encoder_rtr_period_s must be finite and >= 0")
        if not (math.isfinite(torque_rtr_period_s) and torque_rtr_period_s >= 0.0):
            raise ValueError("torque_rtr_period_s must be finite and >= 0")
        for name, limit in (
            ("velocity_limit_rps", velocity_limit_rps),
            ("current_limit_a", current_limit_a),
        ):
            f = None if limit is None else as_float(limit)
            if limit is not None and (f is None or not 0.0 < f <= F32_MAX):
                raise ValueError(f"{name} must be finite and > 0, got {limit!r}")
        self.node_ids: tuple[int, ...] = ids
        self.velocity_limit_rps = None if velocity_limit_rps is None else float(velocity_limit_rps)
        """The drives' configured vel_limit (rev/s), None = unknown."""
        self.current_limit_a = None if current_limit_a is None else float(current_limit_a)
        """The drives' configured current limit (A), None = unknown."""
        self._limits_lowered = False
        self._bus = bus
        self._encoder_rtr = encoder_rtr
        self._encoder_rtr_period_s = encoder_rtr_period_s
        self._next_rtr_s = -math.inf
        self._torque_rtr = torque_rtr
        self._torque_rtr_period_s = torque_rtr_period_s
        self._next_torque_rtr_s = -math.inf
        self._max_frames = max_frames_per_poll
        self._catch_up_age_s = catch_up_age_s
        self._send_timeout_s = send_timeout_s
        self._clock = clock
        self._wall_ns = wall_clock_ns
        self._readings: tuple[AxisReading, ...] = tuple(AxisReading(n) for n in ids)
        self._by_node: list[AxisReading | None] = [None] * (cs.MAX_NODE_ID + 1)
        for r in self._readings:
            self._by_node[r.node_id] = r
        self._stats = BusStats()
        self._bad_frames_by_node: dict[int, int] = {}
        self._last_decode_error: dict[int, cs.DecodeError] = {}
        self._last_get_error: dict[int, cs.GetError] = {}
        # Kernel filter: every CANSimple message of our nodes (id = node << 5 | command).
        self._fast = open_fast_path(
            bus, [(n << 5, 0x7E0) for n in ids], fast_path=fast_path, send_timeout_s=send_timeout_s
        )

    @property
    def fast_path(self) -> bool:
        """True when this driver uses the SocketCAN fast path (`drivers.socketcan_fast`)."""
        return self._fast is not None

    # --- receive ----------------------------------------------------------------------------

    def poll(self) -> int:
        """Drain up to `max_frames_per_poll` received frames without blocking (more to catch up
        with a backlog, see `catch_up_age_s`); update readings.

        Returns the number of frames taken off the bus. Never raises: bad frames, unknown nodes
        and receive errors are counted in `stats`.
        """
        clock = self._clock
        # One clock pair per poll: a frame's age against the wall clock now, subtracted from the
        # loop's clock now, is its arrival on the loop's clock (module docstring).
        now_s = clock()
        now_ns = self._wall_ns()
        wall_s = now_ns * 1e-9
        if self._fast is not None:
            handled = self._drain_fast(self._fast, now_s, now_ns, wall_s)
        else:
            handled = self._drain_bus(now_s, now_ns, wall_s)
        self._stats.frames_rx += handled
        if self._encoder_rtr:
            now = now_s
            if now >= self._next_rtr_s:
                self._next_rtr_s = now + self._encoder_rtr_period_s
                with contextlib.suppress(BusError):  # counted in stats; poll never raises
                    self.request_encoders()
        if self._torque_rtr and now_s >= self._next_torque_rtr_s:
            self._next_torque_rtr_s = now_s + self._torque_rtr_period_s
            with contextlib.suppress(BusError):
                self.request_torques()
        return handled

    def read(self) -> Sequence[AxisReading]:
        """Latest reading per axis, in `node_ids` order (live objects updated by `poll`)."""
        return self._readings

    def reading(self, node_id: int) -> AxisReading:
        """The live reading of axis `node_id`. Raises KeyError if it is not one of ours."""
        rec = self._by_node[node_id] if 0 <= node_id <= cs.MAX_NODE_ID else None
        if rec is None:
            raise KeyError(node_id)
        return rec

    @property
    def stats(self) -> BusStats:
        """Traffic counters (live; copy with `snapshot()`)."""
        return self._stats

    def last_get_error(self, node_id: int) -> cs.GetError | None:
        """The last Get_Error reply of `node_id` (see `request_errors`), or None."""
        return self._last_get_error.get(node_id)

    def last_decode_error(self, node_id: int) -> cs.DecodeError | None:
        """The last undecodable frame that claimed to come from `node_id`, or None."""
        return self._last_decode_error.get(node_id)

    def check(
        self,
        max_encoder_age_s: float,
        max_heartbeat_age_s: float,
        now_s: float | None = None,
    ) -> tuple[AxisFault, ...]:
        """Name what is wrong with each axis now: silent, no heartbeat, axis error, bad frames.

        `now_s` defaults to the driver's clock. "bad_frames" reports axes that sent undecodable
        frames since the last `check` (the per-axis count is reset).
        """
        now = self._clock() if now_s is None else now_s
        faults: list[AxisFault] = []
        for r in self._readings:
            age = now - r.stamp_s
            if age > max_encoder_age_s:
                faults.append(
                    AxisFault(r.node_id, "silent", f"no encoder estimate for {age:.3f} s")
                )
            hb_age = now - r.heartbeat_stamp_s
            if hb_age > max_heartbeat_age_s:
                faults.append(
                    AxisFault(r.node_id, "no_heartbeat", f"no heartbeat for {hb_age:.3f} s")
                )
            if r.axis_error:
                faults.append(
                    AxisFault(
                        r.node_id,
                        "axis_error",
                        f"axis error 0x{r.axis_error:x} ({cs.error_names(r.axis_error)})",
                    )
                )
            bad = self._bad_frames_by_node.pop(r.node_id, 0)
            if bad:
                last = self._last_decode_error.get(r.node_id)
                what = f"{last.kind.value}: {last.detail}" if last else "?"
                faults.append(
                    AxisFault(r.node_id, "bad_frames", f"{bad} bad frame(s), last {what}")
                )
        return tuple(faults)

    # --- transmit ---------------------------------------------------------------------------

    def _send_all(self, frames: Sequence[cs.Frame], what: str) -> None:
        if self._fast is not None:
            self._send_fast(self._fast, frames, what)
            return
        failures: list[str] = []
        bus = self._bus
        timeout = self._send_timeout_s
        for arb_id, data, is_remote in frames:
            try:
                bus.send(frame_message(arb_id, data, is_remote), timeout=timeout)
            except Exception as exc:  # CanError, OSError, or anything an interface raises
                failures.append(
                    self._stats.count_send_failure(f"{what} to node {arb_id >> 5}", exc)
                )
            else:
                self._stats.frames_tx += 1
        if failures:
            raise BusError("; ".join(failures))

    def _send_fast(self, fast: FastSocketCan, frames: Sequence[cs.Frame], what: str) -> None:
        """`_send_all` on the SocketCAN fast path: one system call per 64 frames."""
        failed: Sequence[tuple[int, BaseException]] | None
        try:
            failed = fast.send_frames(frames)
        except Exception as exc:  # not a frame's failure: none of them is known to be sent
            failed = [(i, exc) for i in range(len(frames))]
        if failed is None:
            self._stats.frames_tx += len(frames)
            return
        count = self._stats.count_send_failure
        texts = [count(f"{what} to node {frames[i][0] >> 5}", exc) for i, exc in failed]
        self._stats.frames_tx += len(frames) - len(failed)
        raise BusError("; ".join(texts))

    def command(
        self, positions_rev: Sequence[float], velocity_ff_rps: Sequence[float] | None = None
    ) -> None:
        """Send Set_Input_Pos to every axis (motor turns, `node_ids` order).

        Raises ValueError, sending nothing, if a sequence has the wrong length or any value is
        not finite (or a position exceeds float32). Velocity feed-forward is clamped to
        ±32.767 rev/s (counted in `stats.ff_clamped`). Raises BusError if a send fails (after
        trying every axis).
        """
        ids = self.node_ids
        n = len(ids)
        if len(positions_rev) != n:
            raise ValueError(f"command needs {n} positions, got {len(positions_rev)}")
        if velocity_ff_rps is not None and len(velocity_ff_rps) != n:
            raise ValueError(
                f"command needs {n} velocity feed-forwards, got {len(velocity_ff_rps)}"
            )
        frames: list[cs.Frame] = []
        vmax = cs.VEL_FF_MAX_RPS
        for i in range(n):
            p = positions_rev[i]
            if not math.isfinite(p) or abs(p) > 3.0e38:
                raise ValueError(f"position for node {ids[i]} is not a finite float32: {p!r}")
            v = 0.0 if velocity_ff_rps is None else velocity_ff_rps[i]
            if not math.isfinite(v):
                raise ValueError(f"velocity feed-forward for node {ids[i]} is not finite: {v!r}")
            if v > vmax or v < -vmax:
                v = vmax if v > 0.0 else -vmax
                self._stats.ff_clamped += 1
            frames.append(cs.encode_set_input_pos(ids[i], p, v))
        self._send_all(frames, "Set_Input_Pos")

    def arm(self) -> None:
        """Clear errors, select POSITION_CONTROL + PASSTHROUGH, hold, enter CLOSED_LOOP_CONTROL.

        Before the state request each axis with an encoder reading gets Set_Input_Pos at its
        current position, so closed loop starts holding where the reel is. Confirmation comes
        by heartbeat (axis_state 8). If a torque mode lowered the velocity limits and was not
        left (a fault or an e-stop in between), the configured limits are restored first.
        Raises BusError if a send fails.
        """
        frames: list[cs.Frame] = self._restore_limit_frames()
        for r in self._readings:
            frames.append(cs.encode_clear_errors(r.node_id))
            frames.append(
                cs.encode_set_controller_mode(
                    r.node_id, cs.ControlMode.POSITION_CONTROL, cs.InputMode.PASSTHROUGH
                )
            )
            if r.stamp_ns:
                frames.append(cs.encode_set_input_pos(r.node_id, r.position_rev))
            frames.append(cs.encode_set_axis_state(r.node_id, cs.AxisState.CLOSED_LOOP_CONTROL))
        try:
            self._send_all(frames, "arm")
        finally:
            self._commanded(self._readings)
        self._limits_lowered = False

    def _commanded(self, readings: Sequence[AxisReading]) -> None:
        """Stamp a state-changing command just sent to the axes of `readings`: their status is
        judged again only on heartbeats that arrive from now on (`AxisReading.status_fresh`).
        The stamp is taken after the send, so a heartbeat the drive sent before it took the
        command is not taken for its answer."""
        now_s = self._clock()
        for r in readings:
            r.command_stamp_s = now_s

    def disarm(self) -> None:
        """Request IDLE on every axis. Raises BusError if a send fails."""
        try:
            self._send_all(
                [cs.encode_set_axis_state(n, cs.AxisState.IDLE) for n in self.node_ids], "disarm"
            )
        finally:
            self._commanded(self._readings)

    def estop(self) -> None:
        """Send Estop to every axis (each tried even if one fails). Raises BusError on failure."""
        try:
            self._send_all([cs.encode_estop(n) for n in self.node_ids], "Estop")
        finally:
            self._commanded(self._readings)

    def clear_errors(self) -> None:
        """Send Clear_Errors to every axis. Raises BusError if a send fails."""
        try:
            self._send_all([cs.encode_clear_errors(n) for n in self.node_ids], "Clear_Errors")
        finally:
            self._commanded(self._readings)

    def set_limits(self, velocity_limit_rps: float, current_limit_a: float) -> None:
        """Send Set_Limits to every axis. Raises ValueError if not finite, BusError on failure."""
        self._send_all(
            [cs.encode_set_limits(n, velocity_limit_rps, current_limit_a) for n in self.node_ids],
            "Set_Limits",
        )

    def request_encoders(self) -> None:
        """RTR-request Get_Encoder_Estimates from every axis. Raises BusError on failure."""
        self._send_all(
            [cs.encode_rtr(n, cs.GET_ENCODER_ESTIMATES) for n in self.node_ids], "encoder RTR"
        )

    def request_torques(self) -> None:
        """RTR-request Get_Torques from every axis. Raises BusError on failure."""
        self._send_all([cs.encode_rtr(n, cs.GET_TORQUES) for n in self.node_ids], "torque RTR")

    def request_errors(self) -> None:
        """RTR-request Get_Error from every axis (see `last_get_error`). Raises BusError."""
        self._send_all([cs.encode_rtr(n, cs.GET_ERROR) for n in self.node_ids], "Get_Error RTR")


_OPTIONS = frozenset({"velocity_limit_rps", "current_limit_a"})
"""The `[drive]` options of the "odrive" family (`drivers.registry`)."""


def open_driver(
    bus: can.BusABC, node_ids: Sequence[int], options: Mapping[str, Any], loop: LoopSettings
) -> ODriveReels:
    """The registry's factory (`drivers.registry`, family "odrive"; options
    `velocity_limit_rps` and `current_limit_a`, the drives' configured limits).

    After a loop stall the driver reads through the queued frames to the newest in one poll
    (frames older than half the stale timeout are a backlog), rather than show frames from
    before the stall. Raises ValueError on bad node ids, unknown options or a bad limit.
    """
    unknown = sorted(set(options) - _OPTIONS)
    if unknown:
        raise ValueError(
            f"ODrive drives take no [drive] options named {unknown} "
            f"(known: {', '.join(sorted(_OPTIONS))})"
        )
    return ODriveReels(
        bus,
        node_ids,
        encoder_rtr=loop.encoder_rtr,
        torque_rtr=loop.torque_rtr,
        torque_rtr_period_s=loop.torque_rtr_period_s,
        catch_up_age_s=loop.stale_timeout_s / 2.0,
        velocity_limit_rps=options.get("velocity_limit_rps"),
        current_limit_a=options.get("current_limit_a"),
    )


def startup_note(reading: AxisReading, armed: bool) -> tuple[int, str] | None:
    """What the daemon says about an axis's first heartbeat (registry "startup_note"): an
    axis in closed loop before cablebot armed it (WARNING), or one that its watchdog stopped
    (INFO); None otherwise."""
    if not armed and reading.axis_state == cs.AxisState.CLOSED_LOOP_CONTROL:
        return (
            logging.WARNING,
            f"ODrive node {reading.node_id} is in closed loop before cablebot armed it: another "
            "controller drives it, or its watchdog (axis.config.enable_watchdog) is off and a "
            "previous controller left it running",
        )
    if reading.axis_error & cs.ODriveError.WATCHDOG_TIMER_EXPIRED:
        return (
            logging.INFO,
            f"ODrive node {reading.node_id} reports WATCHDOG_TIMER_EXPIRED: its watchdog stopped "
            "it after the previous controller went quiet (arming clears it)",
        )
    return None
