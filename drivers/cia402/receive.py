"""The receive side of `drivers.cia402.driver.CiA402Reels`: the frames a `poll` drains (through
python-can, or the SocketCAN fast path) and the `configure` pump reads, each handed off by one
method on (id, data, stamp), TPDO decoding, the callbacks that canopen calls back with heartbeats
and EMCY, and the readings' state fields derived from them (see the driver module's docstring
for the rules).

`CiA402Receive` is a mixin: `CiA402Reels` owns the state it works on (declared below) and calls
these methods from the loop thread only (or the `configure` pump, the bus's only reader while it
runs); `DriveRecord` is the driver's record of one drive.
"""

from __future__ import annotations

import math
import struct
from array import array
from collections.abc import Callable

import can
import canopen
from canopen.emcy import EmcyError
from canopen.nmt import NMT_STATES

from drivers.base import AxisReading, BusStats
from drivers.cia402.profile import NO_EMCY_CODE, DriveState, drive_state, emcy_text
from drivers.cia402.sdo_config import SYNC_COB_ID
from drivers.socketcan_fast import (
    CAN_EFF_FLAG,
    CAN_ERR_FLAG,
    CAN_ERR_MASK,
    CAN_RTR_FLAG,
    FastSocketCan,
    flagged_id,
)

NMT_OPERATIONAL = 5
NMT_BOOT_UP = 0

ANOTHER_SYNC_PRODUCER = (
    "another SYNC producer on the bus: a SYNC (0x080) this host did not send (two CANopen "
    "masters on one bus: stop the other one)"
)
COUNT_KEPT_REV = 0.01
"""A restarted drive whose first position is within this of its last one kept its count (an
absolute encoder; the reel is braked while the drive restarts); farther, a new count began."""
SYNC_RING = 4096
"""SYNCs whose send times are kept, to tell which SYNC a drive's TPDO answers."""
MAX_ANSWER_DELAY_S = 1.0
"""A SYNC not answered this long after it was sent is taken as lost (its frame or its answer):
the drive's next TPDO answers a later one."""


class DriveRecord:
    """The driver's record of one drive (mutated by the loop thread only)."""

    __slots__ = (
        "actual_counts",
        "bad_frames",
        "boots",
        "configured",
        "counts_before_restart",
        "emcy",
        "fault_reset",
        "ff_units",
        "next_answer",
        "nmt_state",
        "node",
        "node_id",
        "prev_counts",
        "prev_sample_s",
        "reading",
        "restarted",
        "rpdo1",
        "rpdo1_cob",
        "rpdo2",
        "rpdo2_cob",
        "state",
        "statusword",
        "target_counts",
        "torque",
        "tpdo1",
    )

    def __init__(self, node_id: int, node: canopen.RemoteNode) -> None:
        self.node_id = node_id
        self.node = node
        self.reading = AxisReading(node_id)
        self.configured = False
        self.restarted = False
        self.boots = 0
        self.counts_before_restart: int | None = None
        """Position actual when the drive was last heard before a restart (its first position
        after it tells whether the count survived)."""
        """NMT boot-ups heard from the drive (a restart while it was being configured)."""
        self.statusword: int | None = None
        self.state: DriveState | None = None
        self.nmt_state: int | None = None
        self.torque: int | None = None
        self.emcy: EmcyError | None = None
        self.fault_reset = False
        self.next_answer = 0
        """Index of the next SYNC whose TPDO this drive owes (its TPDOs answer them in turn)."""
        self.actual_counts: int | None = None
        self.target_counts = 0
        self.ff_units = 0
        self.prev_counts: int | None = None
        self.prev_sample_s = -math.inf
        self.bad_frames = 0
        self.rpdo1 = struct.Struct("<")
        self.rpdo1_cob = 0
        self.rpdo2: struct.Struct | None = None
        self.rpdo2_cob = 0
        self.tpdo1 = struct.Struct("<")


class CiA402Receive:
    """The receive path of `CiA402Reels` (a mixin: the driver owns the state below)."""

    counts_per_rev: float
    _bus: can.BusABC
    _max_frames: int
    _stats: BusStats
    _network: canopen.Network
    _clock: Callable[[], float]
    _wall_ns: Callable[[], int]
    _by_node: dict[int, DriveRecord]
    _tpdo_by_cob: dict[int, DriveRecord]
    _host_cob_ids: set[int]
    _canopen_cob_ids: frozenset[int]
    _sdo_answer_ids: frozenset[int]
    _configuring: bool
    _sdo_expected: bool
    _last_sync_s: float
    _syncs_sent: int
    _syncs_heard: int
    _sync_echoes: bool
    _sync_times: array[float]
    _command_sync: int

    def _drain_bus(self) -> int:
        """python-can's receive path (every interface but SocketCAN): one Message per frame, at
        most `max_frames_per_poll`."""
        recv = self._bus.recv
        take = self._take
        handled = 0
        while handled < self._max_frames:
            try:
                msg = recv(0.0)
            except Exception as exc:  # a receive error must never escape into the loop
                self._stats.count_bus_error(f"receive: {type(exc).__name__}: {exc}")
                break
            if msg is None:
                break
            handled += 1
            take(flagged_id(msg), msg.data, msg.timestamp)
        return handled

    def _drain_fast(self, fast: FastSocketCan) -> int:
        """The SocketCAN fast path: batches straight off the kernel socket, no Message objects,
        until the kernel has no more or `max_frames_per_poll` were taken."""
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
                take(can_id, data[:length], stamp)
            handled += n
        if fast.kernel_drops != drops:
            self._stats.count_rx_overrun(fast.kernel_drops - drops)
        return handled

    def _handle(self, msg: can.Message) -> None:
        """Hand one python-can Message off (the `configure` pump's reads)."""
        self._take(flagged_id(msg), msg.data, msg.timestamp)

    def _take(self, can_id: int, data: bytes | bytearray, stamp: float) -> None:
        """Hand one received frame off: `can_id` with SocketCAN's EFF/RTR/ERR flags, its data,
        its wall-clock receive time. TPDOs of our drives are decoded here; heartbeats, EMCY
        and (while configuring) SDO answers go to canopen; the rest is counted."""
        d = self._tpdo_by_cob.get(can_id)  # a flagged id (error, extended, remote) never matches
        if d is not None:
            self._on_tpdo(d, data)
            return
        if can_id & CAN_ERR_FLAG:
            self._stats.count_error_frame(can_id & CAN_ERR_MASK)
            return
        if can_id & CAN_EFF_FLAG:
            self._stats.count("extended_id", decode_error=True)
            return
        if can_id == SYNC_COB_ID:
            self._on_sync_heard()
            return
        if can_id in self._host_cob_ids or can_id & CAN_RTR_FLAG:
            self._stats.count("not_for_host")
            return
        if can_id in self._sdo_answer_ids:
            if not self._sdo_expected:  # nobody waits for it: not queued for later
                self._stats.count("sdo_unsolicited")
                return
        elif can_id not in self._canopen_cob_ids:
            self._stats.count("unknown_cob_id")
            return
        try:
            # canopen's heartbeat, EMCY and SDO consumers only read the payload: bytes serve.
            self._network.notify(can_id, data, stamp)  # type: ignore[arg-type]
        except Exception as exc:  # canopen raises on malformed heartbeat/EMCY payloads
            kind = "length" if isinstance(exc, struct.error) else "bad_frame"
            self._stats.count(kind, decode_error=True)
            owner = self._by_node.get(can_id & 0x7F)
            if owner is not None:
                owner.bad_frames += 1

    def _on_sync_heard(self) -> None:
        """A SYNC heard: this host's own, echoed back by a bus that echoes (udp_multicast: no
        more of them than were sent), else another SYNC producer's: two masters on the bus,
        counted as a conflict (`BusStats.conflicts`; the loop faults on it by name)."""
        if self._sync_echoes and self._syncs_heard < self._syncs_sent:
            self._syncs_heard += 1
            self._stats.count("not_for_host")
            return
        self._stats.count_conflict(ANOTHER_SYNC_PRODUCER)

    def _on_tpdo(self, d: DriveRecord, data: bytes | bytearray) -> None:
        layout = d.tpdo1
        if len(data) != layout.size:
            d.bad_frames += 1
            self._stats.count("length", decode_error=True)
            return
        values = layout.unpack(data)
        counts = values[1]
        r = d.reading
        before = d.counts_before_restart
        if before is not None:
            d.counts_before_restart = None
            if abs(counts - before) > COUNT_KEPT_REV * self.counts_per_rev:
                r.count_epoch += 1  # a new count: positions before and after do not compare
        cpr = self.counts_per_rev
        t_sample = self._last_sync_s
        prev = d.prev_counts
        if prev is not None and t_sample > d.prev_sample_s:
            r.velocity_rps = (counts - prev) / cpr / (t_sample - d.prev_sample_s)
        d.prev_counts = counts
        d.prev_sample_s = t_sample
        d.actual_counts = counts
        r.position_rev = counts / cpr
        r.stamp_s = now_s = self._clock()
        r.stamp_ns = self._wall_ns()
        # Which SYNC does it answer? A drive answers them in turn, late ones too (a paused
        # drive working through its backlog): its status tells the state since the last
        # state-changing command only once it answers a SYNC sent after that command.
        k = d.next_answer
        sent = self._syncs_sent
        if k < sent:
            k = max(k, sent - SYNC_RING)
            oldest_s = now_s - MAX_ANSWER_DELAY_S
            times = self._sync_times
            while k < sent - 1 and times[k % SYNC_RING] < oldest_s:
                k += 1  # presumed lost: never answered
            d.next_answer = k + 1
        else:
            k = sent - 1  # more answers than SYNCs: it answers the last one
        if k >= self._command_sync:
            r.status_stamp_s = now_s
        if len(values) > 2:
            d.torque = values[2]
        if values[0] != d.statusword:
            d.statusword = values[0]
            self._refresh(d)

    def _heartbeat_handler(self, d: DriveRecord) -> Callable[[int], None]:
        def on_heartbeat(state: int) -> None:
            d.reading.heartbeat_stamp_s = now_s = self._clock()
            if not d.configured:  # no TPDOs: its status is its NMT state (and restart)
                d.reading.status_stamp_s = now_s
            if state == NMT_BOOT_UP:
                d.boots += 1
            if state == NMT_BOOT_UP and d.configured:
                # The drive restarted: its PDO set-up and mode are back to their defaults, and
                # its position count may have started afresh (judged on its next position).
                if d.actual_counts is not None:
                    d.counts_before_restart = d.actual_counts
                d.prev_counts = None  # no velocity across the restart
                d.configured = False
                d.restarted = True
                self._tpdo_by_cob = {c: x for c, x in self._tpdo_by_cob.items() if x is not d}
            if state != d.nmt_state:
                d.nmt_state = state
                self._refresh(d)

        return on_heartbeat

    def _emcy_handler(self, d: DriveRecord) -> Callable[[EmcyError], None]:
        consumer = d.node.emcy

        def on_emcy(entry: EmcyError) -> None:
            d.emcy = None if entry.code & 0xFF00 == 0 else entry  # 0x00xx: error reset
            # canopen keeps every EMCY in lists; keep them bounded.
            del consumer.log[:-1]
            del consumer.active[:-8]
            self._refresh(d)

        return on_emcy

    def _refresh(self, d: DriveRecord) -> None:
        """Derive the reading's state fields from statusword, NMT state, EMCY and restarts."""
        state = d.state = None if d.statusword is None else drive_state(d.statusword)
        r = d.reading
        nmt = d.nmt_state
        fault: str | None = None
        if d.restarted:
            name = "Restarted (NMT boot-up)"
            fault = "restarted: the drive sent an NMT boot-up and lost its set-up; arm again"
        elif d.configured and nmt is not None and nmt != NMT_OPERATIONAL:
            # Not a fault by itself (a heartbeat sent before NMT start can still be in
            # flight): not ready, and its PDOs stop, so a lasting one makes readings stale.
            name = f"NMT {NMT_STATES.get(nmt, str(nmt))}"
        else:
            name = "unknown" if state is None else state.value
            if state is DriveState.FAULT or state is DriveState.FAULT_REACTION_ACTIVE:
                emcy = d.emcy
                fault = (
                    f"EMCY 0x{emcy.code:04X} {emcy_text(emcy.code)}"
                    if emcy is not None
                    else f"{state.value} (no EMCY received)"
                )
        ready = (
            fault is None
            and d.configured
            and (nmt is None or nmt == NMT_OPERATIONAL)
            and state is DriveState.OPERATION_ENABLED
        )
        r.ready = ready
        r.fault = fault
        r.state_name = name
        r.axis_state = 8 if ready else (1 if state is not None or nmt is not None else 0)
        if fault is None:
            r.axis_error = 0
        else:
            r.axis_error = d.emcy.code if d.emcy is not None else NO_EMCY_CODE
