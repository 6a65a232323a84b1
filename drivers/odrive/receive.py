"""The receive side of `drivers.odrive.driver.ODriveReels`: the frames a `poll` drains (through
python-can, or the SocketCAN fast path), each decoded and applied to the readings or counted
(see the driver module's docstring for the stamping and counting rules).

`ODriveReceive` is a mixin: `ODriveReels` owns the state it works on (declared below) and calls
these methods from the loop thread only.
"""

from __future__ import annotations

import can

from drivers.base import NEVER_S, AxisReading, BusStats
from drivers.odrive import cansimple as cs
from drivers.socketcan_fast import CAN_EFF_FLAG as _EFF_FLAG
from drivers.socketcan_fast import CAN_EFF_MASK as _EFF_MASK
from drivers.socketcan_fast import CAN_ERR_FLAG as _ERR_FLAG
from drivers.socketcan_fast import CAN_RTR_FLAG as _RTR_FLAG
from drivers.socketcan_fast import CAN_SFF_MASK as _SFF_MASK
from drivers.socketcan_fast import FastSocketCan

TIMESTAMP_FUTURE_TOLERANCE_S = 1.0
"""A frame timestamp further ahead of the wall clock than this is not a wall-clock reading."""
TIMESTAMP_MAX_AGE_S = 3600.0
"""A frame timestamp further behind the wall clock than this is not a wall-clock reading."""
CATCH_UP_FACTOR = 8
"""A poll that catches up with a backlog takes at most this many times `max_frames_per_poll`."""
_ENCODER = cs.EncoderEstimates
_HEARTBEAT = cs.Heartbeat


def _derive_status(r: AxisReading) -> None:
    """The generic status of a reading from its heartbeat's axis state and error bits."""
    state = r.axis_state
    error = r.axis_error
    r.ready = state == cs.AxisState.CLOSED_LOOP_CONTROL and error == 0
    r.fault = cs.fault_text(error)
    r.state_name = cs.axis_state_name(state)


class ODriveReceive:
    """The receive path of `ODriveReels` (a mixin: the driver owns the state below)."""

    _bus: can.BusABC
    _stats: BusStats
    _max_frames: int
    _catch_up_age_s: float
    _by_node: list[AxisReading | None]
    _bad_frames_by_node: dict[int, int]
    _last_decode_error: dict[int, cs.DecodeError]
    _last_get_error: dict[int, cs.GetError]

    def _catch_up(self, handled: int, limit: int, stamp: float, wall_s: float) -> int:
        """The poll's frame limit after `handled` frames, the last received at `stamp`: raised
        to read through a backlog (a loop stall, see `catch_up_age_s`), else unchanged."""
        if (
            handled == limit == self._max_frames
            and self._catch_up_age_s < wall_s - stamp < TIMESTAMP_MAX_AGE_S
        ):
            self._stats.catch_up_polls += 1
            return limit * CATCH_UP_FACTOR
        return limit

    def _drain_bus(self, now_s: float, now_ns: int, wall_s: float) -> int:
        """python-can's receive path (every interface but SocketCAN): one Message per frame."""
        recv = self._bus.recv
        take = self._take
        handled = 0
        limit = self._max_frames
        while handled < limit:
            try:
                msg = recv(0.0)
            except Exception as exc:  # a receive error must never escape into the loop
                self._stats.count_bus_error(f"receive: {type(exc).__name__}: {exc}")
                break
            if msg is None:
                break
            handled += 1
            if handled == limit:
                limit = self._catch_up(handled, limit, msg.timestamp, wall_s)
            if msg.is_error_frame:
                self._stats.count_error_frame(msg.arbitration_id)
                continue
            take(
                msg.arbitration_id,
                msg.data,
                msg.is_remote_frame,
                msg.is_extended_id,
                msg.timestamp,
                now_s,
                now_ns,
                wall_s,
            )
        return handled

    def _drain_fast(self, fast: FastSocketCan, now_s: float, now_ns: int, wall_s: float) -> int:
        """The SocketCAN fast path: batches straight off the kernel socket, no Message objects,
        until the kernel has no more (`drivers.socketcan_fast`)."""
        take = self._take
        frame = fast.frame
        handled = 0
        limit = self._max_frames
        drops = fast.kernel_drops
        while handled < limit:
            try:
                n = fast.recv_batch(limit - handled)
            except Exception as exc:  # a receive error must never escape into the loop
                self._stats.count_bus_error(f"receive: {type(exc).__name__}: {exc}")
                break
            if n == 0:
                break
            for i in range(n):
                can_id, length, data, stamp = frame(i)
                handled += 1
                if handled == limit:
                    limit = self._catch_up(handled, limit, stamp, wall_s)
                if can_id & _ERR_FLAG:
                    self._stats.count_error_frame(can_id & _EFF_MASK)
                    continue
                if can_id & _EFF_FLAG:
                    take(
                        can_id & _EFF_MASK, data[:length], False, True, stamp, now_s, now_ns, wall_s
                    )
                elif can_id & _RTR_FLAG:
                    take(can_id & _SFF_MASK, b"", True, False, stamp, now_s, now_ns, wall_s)
                else:
                    take(can_id, data[:length], False, False, stamp, now_s, now_ns, wall_s)
        if fast.kernel_drops != drops:
            self._stats.count_rx_overrun(fast.kernel_drops - drops)
        return handled

    def _take(
        self,
        arb_id: int,
        data: bytes | bytearray,
        is_remote: bool,
        is_extended: bool,
        stamp: float,
        now_s: float,
        now_ns: int,
        wall_s: float,
    ) -> None:
        """Decode one received data or remote frame (arrived at wall-clock `stamp`) and update
        the readings or the counters."""
        m = cs.decode(arb_id, data, is_remote, is_extended)
        mtype = type(m)
        if mtype is _ENCODER or mtype is _HEARTBEAT:
            rec = self._by_node[m.node_id]
            if rec is None:
                self._stats.count("unknown_node")
                return
            age = wall_s - stamp
            if age < 0.0:
                if age < -TIMESTAMP_FUTURE_TOLERANCE_S:
                    self._stats.untimed_frames += 1
                age = 0.0
            elif age > TIMESTAMP_MAX_AGE_S:
                self._stats.untimed_frames += 1
                age = 0.0
            if mtype is _ENCODER:
                rec.position_rev = m.pos_estimate_rev  # type: ignore[union-attr]
                rec.velocity_rps = m.vel_estimate_rps  # type: ignore[union-attr]
                rec.stamp_s = now_s - age
                rec.stamp_ns = now_ns - int(age * 1e9)
            else:
                state = m.axis_state  # type: ignore[union-attr]
                error = m.axis_error  # type: ignore[union-attr]
                if (
                    state != rec.axis_state
                    or error != rec.axis_error
                    or rec.heartbeat_stamp_s == NEVER_S
                ):
                    rec.axis_state = state
                    rec.axis_error = error
                    _derive_status(rec)
                rec.heartbeat_stamp_s = rec.status_stamp_s = now_s - age
        elif mtype is cs.Torques:
            rec = self._by_node[m.node_id]
            if rec is None:
                self._stats.count("unknown_node")
                return
            age = wall_s - stamp
            rec.torque_nm = m.torque_estimate_nm  # type: ignore[union-attr]
            rec.torque_stamp_s = now_s - (age if 0.0 <= age <= TIMESTAMP_MAX_AGE_S else 0.0)
        else:
            self._handle_other(m)

    def _handle_other(self, m: cs.Message | cs.DecodeError) -> None:
        if isinstance(m, cs.DecodeError):
            node = m.node_id
            self._bad_frames_by_node[node] = self._bad_frames_by_node.get(node, 0) + 1
            self._last_decode_error[node] = m
            self._stats.count(m.kind.value, decode_error=True)
        elif isinstance(m, cs.GetError):
            if self._by_node[m.node_id] is None:
                self._stats.count("unknown_node")
            else:
                self._last_get_error[m.node_id] = m
        else:
            # Host-to-ODrive commands and RTR requests: our own frames echoed back (e.g. by
            # udp_multicast) or another master on the bus. Not for us, and not lost either.
            self._stats.count("not_for_host")
