"""`CiA402Reels`: the `ReelDriver` for CANopen servo drives (CiA 402) in cyclic synchronous
position mode, with the `canopen` package doing the protocol work.

Start-up (`configure`, blocking, bounded by SDO timeouts): every drive is put into NMT
PRE-OPERATIONAL and configured by SDO, relying on none of its defaults: SYNC consumer COB-ID
0x80 (0x1005), heartbeat producer time (0x1017), modes of operation = cyclic synchronous
position (0x6060 = 8, checked in 0x6061), interpolation period = the loop period (0x60C2),
RPDO1 = controlword 0x6040 + target position 0x607A, RPDO2 = velocity offset 0x60B1 (the
velocity feed-forward; off with `velocity_offset=False`), TPDO1 = statusword 0x6041 + position
actual 0x6064 (+ torque actual 0x6077 with `torque=True`), all synchronous (transmission type
1: RPDOs act and TPDOs answer on every SYNC); every other PDO is disabled. Then NMT
OPERATIONAL. canopen's `PdoMap.save()` writes the PDO parameters in the order CiA 301 asks
(disable, mapping count 0, entries, count, enable).

The bus belongs to the control loop's thread: no canopen Notifier reads it. `poll()` drains it
without blocking (at most `max_frames_per_poll` frames) and hands each frame on as (id, data,
stamp): TPDOs of our drives are decoded here with one precompiled struct per PDO (derived from
canopen's mapping of it, so the per-tick path does no per-variable work); everything else goes
to canopen through `network.notify` (heartbeats to its NMT master, EMCY to its EMCY consumer,
SDO answers to its SDO client). canopen's SDO client waits for its answers on a queue that the
receive path fills, so while `configure` runs a temporary receive thread is the bus's only
reader, through python-can's `recv` (the loop thread is blocked in `configure` meanwhile, and
`poll` reads nothing until it returns); it is joined before `configure` returns. SDO requests
and NMT commands leave through canopen's `network.send_message`, bounded by `send_timeout_s`.
A drive that restarts (NMT boot-up) loses that set-up: `arm` then configures it again on a
worker thread beside the loop (`drivers.cia402.reconfigure`), and refuses (`ArmRefused`) until
it is done, while `poll` stays the bus's only reader and keeps cycling the other drives, so
their SYNC and set-points never pause for the SDO exchanges.

The SocketCAN fast path (`drivers.socketcan_fast`, the default on a python-can SocketCAN bus,
`fast_path`): `poll()` takes the frames off the bus's kernel socket in batches (`recvmmsg`, no
`can.Message` per frame), and a cycle's RPDOs and SYNC leave in one `sendmmsg` per 64 frames
(one call for up to 31 drives with both RPDOs, two RPDOs and the SYNC). Kernel filters
pass only our drives' TPDO1 (0x180 + n), EMCY (0x080 + n), SDO answers (0x580 + n) and
heartbeats (0x700 + n), the SYNC (0x080) and error frames: other nodes' and other hosts' frames
never reach Python (they are not counted as `unknown_cob_id` or `not_for_host`), and frames the
kernel dropped from a full receive queue (a loop stall) are counted as dropped, kind
"rx_overrun". A SYNC heard is another producer's (the fast path never hears its own frames; on a
bus that echoes them, udp_multicast, no more are taken as ours than were sent): two masters on
one bus, counted in `stats.conflicts` and named in `stats.last_conflict`; the loop faults on it.
Every other interface keeps python-can's path: one `recv` and one `send` per frame.

Cyclic operation: each `command()` writes every drive's RPDOs and then produces one SYNC (the
driver is the SYNC producer, at the loop rate); the drives apply the set-points and answer
with their TPDOs at that SYNC, read by the next `poll()`. While the loop sends no set-points
(disarmed, arming, e-stopped), `poll()` runs the same cycle with the held set-points, at most
once per poll and half a period, so statuswords and positions stay fresh. The CiA 402 state
machine is stepped one transition per cycle toward what the host wants (`arm`: Operation
enabled, with one fault-reset edge for a faulted drive; `disarm`: Switch on disabled; `estop`:
Quick stop, in every drive's RPDO of one cycle, so one SYNC stops them all at once). While a
drive is not in Operation enabled its target position is its actual position, so enabling
holds the reel where it is.

Readings: `position_rev` = position actual / `counts_per_rev`; `velocity_rps` estimated from
successive positions over the times of the SYNCs they answer; `stamp_s`/`stamp_ns` (TPDO) and
`heartbeat_stamp_s` (NMT heartbeat; a silent drive's stamp ages) are the driver's clocks when
`poll` handles the frame, not its arrival: a frame that waited in the receive queue is stamped
when it is read; `ready` = Operation
enabled; `fault` = a name built from the statusword's Fault bit and the last EMCY (code and
text), or the drive's NMT restart; `state_name` = the CiA 402 state. The loop reads only those;
the raw numbers are kept for diagnostics: `axis_state` 8 while Operation enabled, else 1 (0
before the drive was heard); `axis_error` = the EMCY code while faulted (0x1000 without one),
else 0.

Freshness after a state-changing command (`arm`, `disarm`, `estop`): a drive answers the SYNCs
in turn, so after a stall (its process paused, a backlog) its first TPDOs answer SYNCs sent
before the command, with the statuswords of then. The driver keeps the send times of the
SYNCs (`SYNC_RING`) and counts each drive's answers against them (a SYNC unanswered after
`MAX_ANSWER_DELAY_S` is taken as lost); `status_stamp_s` moves only on a TPDO answering the
first SYNC after the command or a later one, and `command_stamp_s` marks the command, so
`AxisReading.status_fresh` tells the loop when the status describes the drive since then.

`open_driver` and `check_options` are the registry's entries for the "cia402" family
(`drivers.registry`): the driver from the `[drive]` options, and the options' checks.

The receive path (frame hand-off, TPDO decoding, heartbeat and EMCY callbacks, the readings'
state fields; `SYNC_RING`, `MAX_ANSWER_DELAY_S`) is in `drivers.cia402.receive`, a mixin of
`CiA402Reels`.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from array import array
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import canopen
from canopen.nmt import NMT_STATES
from canopen.pdo import PdoMap

from drivers.base import ArmRefused, AxisReading, BusError, BusStats
from drivers.bus import echoes_own_frames
from drivers.cia402.profile import (
    CW_FAULT_RESET,
    DriveState,
    Goal,
    controlword_for,
    emcy_text,
    interpolation_period,
)
from drivers.cia402.receive import (
    SYNC_RING,
    CiA402Receive,
    DriveRecord,
)
from drivers.cia402.reconfigure import ConfigJob, PdoMapping
from drivers.cia402.sdo_config import (
    SYNC_COB_ID,
    configure_node,
    pdo_struct,
)
from drivers.registry import LoopSettings
from drivers.socketcan_fast import FastSocketCan, open_fast_path

EDS_PATH = Path(__file__).with_name("cia402.eds")
"""The object dictionary shipped with cablebot (the simulated drive's, standard objects only)."""

DEFAULT_SEND_TIMEOUT_S = 0.005
DEFAULT_SDO_TIMEOUT_S = 0.3
DEFAULT_HEARTBEAT_PERIOD_S = 0.1
MAX_NODE_ID = 127
INT32_MIN = -(2**31)
INT32_MAX = 2**31 - 1


@dataclass(frozen=True, slots=True)
class DriveStatus:
    """What the driver knows of one drive beyond its `AxisReading` (a snapshot)."""

    node_id: int
    configured: bool
    statusword: int | None
    state: DriveState | None
    nmt_state: str | None
    torque_permille: int | None
    """Torque actual (0x6077) in thousandths of the motor's rated torque, if mapped."""
    emcy_code: int | None
    emcy_register: int | None
    emcy_text: str | None


_SYNC_FRAME = (SYNC_COB_ID, b"", False)


def kernel_filters(node_ids: Iterable[int]) -> list[tuple[int, int]]:
    """The fast path's kernel receive filters for drives `node_ids`: (id, mask) pairs passing
    the SYNC (another producer's: the fast path never hears its own frames) and the drives'
    TPDO1, EMCY, SDO answers and heartbeats. Raises nothing."""
    return [(SYNC_COB_ID, 0x7FF)] + [
        (base + n, 0x7FF) for n in node_ids for base in (0x180, 0x080, 0x580, 0x700)
    ]


def send_failure(stats: BusStats, can_id: int, exc: BaseException) -> str:
    """Count one frame `can_id` that could not be sent and name it "send 0x<id>: ..."
    (`BusStats.count_send_failure`). Raises nothing."""
    return stats.count_send_failure(f"0x{can_id:03X}", exc)


class _LoopNetwork(canopen.Network):
    """canopen's network on a bus owned by the loop thread: sends bounded and counted."""

    def __init__(self, bus: can.BusABC, stats: BusStats, send_timeout_s: float) -> None:
        super().__init__(bus)
        self._stats = stats
        self._send_timeout_s = send_timeout_s

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        """Send one frame within the send timeout. Raises BusError (counted) on failure."""
        msg = can.Message(
            arbitration_id=can_id, data=data, is_extended_id=False, is_remote_frame=remote
        )
        try:
            with self.send_lock:
                self.bus.send(msg, timeout=self._send_timeout_s)  # type: ignore[union-attr]
        except Exception as exc:  # CanError, OSError, or anything an interface raises
            raise BusError(send_failure(self._stats, can_id, exc)) from exc
        self._stats.frames_tx += 1


class CiA402Reels(CiA402Receive):
    """Reel motors on CiA 402 servo drives (CANopen node ids `node_ids`) over one bus.

    The bus is owned by the caller (open it with `drivers.bus.open_bus`, shut it down after).
    Not thread-safe: one thread (the control loop) calls every method.
    """

    def __init__(
        self,
        bus: can.BusABC,
        node_ids: Iterable[int],
        *,
        counts_per_rev: float,
        period_s: float,
        eds: str | Path | None = None,
        velocity_units_per_rps: float | None = None,
        velocity_offset: bool = True,
        torque: bool = True,
        heartbeat_period_s: float = DEFAULT_HEARTBEAT_PERIOD_S,
        sdo_timeout_s: float = DEFAULT_SDO_TIMEOUT_S,
        max_frames_per_poll: int = 256,
        send_timeout_s: float = DEFAULT_SEND_TIMEOUT_S,
        clock: Callable[[], float] = time.monotonic,
        wall_clock_ns: Callable[[], int] = time.time_ns,
        fast_path: bool | FastSocketCan = True,
    ) -> None:
        """Set up the drives `node_ids` (1..127, unique, at least one); nothing is sent yet.

        `counts_per_rev`: position units (0x6064/0x607A, encoder increments unless the drive
        scales them) per motor turn. `period_s`: the loop period, written as the drives'
        interpolation period. `eds`: the drives' EDS file (default: the one shipped with
        cablebot). `velocity_units_per_rps`: velocity offset (0x60B1) units per rev/s
        (default: `counts_per_rev`, i.e. increments per second). `velocity_offset`: map the
        feed-forward (RPDO2); `torque`: map torque actual into TPDO1. `heartbeat_period_s`:
        each drive's heartbeat producer time. `sdo_timeout_s`: wait for each SDO answer.
        `fast_path`: on a python-can SocketCAN bus, receive and send the cyclic traffic through
        the bus's kernel socket directly (module docstring; kernel filters set at once); False
        keeps python-can's path (every other interface always does); a `FastSocketCan` is used
        as given (tests, the benchmark).
        Raises ValueError on bad node ids or a non-finite or non-positive number, and on a
        period or heartbeat the drives cannot represent; OSError if the EDS cannot be read or
        a SocketCAN socket refuses the fast path's options.
        """
        ids = tuple(int(n) for n in node_ids)
        if not ids:
            raise ValueError("CiA402Reels needs at least one node id")
        if len(set(ids)) != len(ids):
            raise ValueError(f"duplicate node ids in {ids}")
        for n in ids:
            if not 1 <= n <= MAX_NODE_ID:
                raise ValueError(f"CANopen node id {n} is outside 1..127")
        for name, value in (
            ("counts_per_rev", counts_per_rev),
            ("heartbeat_period_s", heartbeat_period_s),
            ("sdo_timeout_s", sdo_timeout_s),
            ("send_timeout_s", send_timeout_s),
        ):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        vel_units = counts_per_rev if velocity_units_per_rps is None else velocity_units_per_rps
        if not (math.isfinite(vel_units) and vel_units > 0.0):
            raise ValueError(f"velocity_units_per_rps must be finite and > 0, got {vel_units!r}")
        if max_frames_per_poll <= 0:
            raise ValueError("max_frames_per_poll must be > 0")
        self._interp = interpolation_period(period_s)
        heartbeat_ms = round(heartbeat_period_s * 1000.0)
        if not 1 <= heartbeat_ms <= 0xFFFF:
            raise ValueError(f"heartbeat_period_s {heartbeat_period_s!r} is not 1..65535 ms")
        self.node_ids: tuple[int, ...] = ids
        self.counts_per_rev = float(counts_per_rev)
        self.period_s = float(period_s)
        self._velocity_units_per_rps = float(vel_units)
        self._velocity_offset = velocity_offset
        self._torque = torque
        self._heartbeat_ms = heartbeat_ms
        self._sdo_timeout_s = sdo_timeout_s
        self._max_frames = max_frames_per_poll
        self._clock = clock
        self._wall_ns = wall_clock_ns
        self._bus = bus
        self._stats = BusStats()
        self._network = _LoopNetwork(bus, self._stats, send_timeout_s)
        # One dictionary for every drive: the driver reads data types and mappability from
        # it, never the node-relative defaults (parsing an EDS takes tens of milliseconds).
        od = canopen.import_od(str(EDS_PATH if eds is None else eds), ids[0])
        self._drives: tuple[DriveRecord, ...] = ()
        drives = []
        for n in ids:
            node = canopen.RemoteNode(n, od)
            node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
            self._network.add_node(node)
            d = DriveRecord(n, node)
            node.nmt.add_heartbeat_callback(self._heartbeat_handler(d))
            node.emcy.add_callback(self._emcy_handler(d))
            drives.append(d)
        self._drives = tuple(drives)
        self._by_node = {d.node_id: d for d in self._drives}
        self._readings: tuple[AxisReading, ...] = tuple(d.reading for d in self._drives)
        self._tpdo_by_cob: dict[int, DriveRecord] = {}
        # Frames a host sends (ours echoed back, or another master's): never for us.
        self._host_cob_ids: set[int] = {0x000} | {0x600 + n for n in ids}
        # What canopen gets: our drives' heartbeats and EMCY (SDO answers while configuring).
        self._canopen_cob_ids = frozenset({0x700 + n for n in ids} | {0x080 + n for n in ids})
        self._sdo_answer_ids = frozenset(0x580 + n for n in ids)
        self._goal = Goal.DISABLED
        self._last_sync_s = -math.inf
        self._syncs_sent = 0
        self._sync_times = array("d", [-math.inf]) * SYNC_RING
        self._syncs_heard = 0
        """SYNCs heard on a bus that echoes this host's own frames and taken as ours."""
        self._sync_echoes = echoes_own_frames(bus)
        self._command_sync = 0
        """Index of the first SYNC after the last state-changing command (`arm`, `disarm`,
        `estop`): only statuswords answering it or a later one tell the drives' state since."""
        self._cycled_since_poll = False
        self._configuring = False
        """True while the blocking `configure` runs (its pump is the bus's only reader)."""
        self._sdo_expected = False
        """True while SDO answers are awaited (`configure`, or a `ConfigJob`)."""
        self._config_job: ConfigJob | None = None
        self._config_failure: str | None = None
        self._tx_frames: list[tuple[int, bytes, bool]] = []
        self._fast = open_fast_path(
            bus, kernel_filters(ids), fast_path=fast_path, send_timeout_s=send_timeout_s
        )

    @property
    def fast_path(self) -> bool:
        """True when this driver uses the SocketCAN fast path (`drivers.socketcan_fast`)."""
        return self._fast is not None

    # --- start-up ---------------------------------------------------------------------------

    def configure(self, node_ids: Iterable[int] | None = None) -> None:
        """Configure the drives `node_ids` (default: all) by SDO and start them (NMT).

        Blocks: about 36 SDO exchanges per drive, each waiting at most `sdo_timeout_s` for its
        answer (a drive that does not answer fails at its first). Call it before cyclic
        operation, never from the loop (`arm` configures drives not yet configured or restarted
        since beside the loop, `ConfigJob`; a job under way is waited for first). Raises
        ConfigureError naming the first drive and step that failed (the drives before it stay
        configured), KeyError for a node not ours.
        """
        todo = [self._by_node[n] for n in (self.node_ids if node_ids is None else node_ids)]
        if not todo:
            return
        job = self._config_job
        if job is not None:  # one SDO client per drive at a time: let the job end first
            job.join(len(job.drives) * 40 * self._sdo_timeout_s)
            self._take_config_job()
        stop = threading.Event()
        pump = threading.Thread(target=self._pump, args=(stop,), name="cia402-sdo", daemon=True)
        self._configuring = self._sdo_expected = True
        pump.start()
        try:
            for d in todo:
                self._forget_tpdo(d)
                self._use_mapping(d, *self._configure_mapping(d))
        finally:
            stop.set()
            pump.join(5.0)
            self._configuring = self._sdo_expected = False

    def _pump(self, stop: threading.Event) -> None:
        """While `configure` runs: the bus's only reader (python-can's `recv`, on either path),
        feeding every frame to `_handle`."""
        recv = self._bus.recv
        while not stop.is_set():
            try:
                msg = recv(0.002)
            except Exception as exc:
                self._stats.count_bus_error(f"receive: {type(exc).__name__}: {exc}")
                stop.wait(0.01)
                continue
            if msg is not None:
                self._stats.frames_rx += 1
                self._handle(msg)

    def _forget_tpdo(self, d: DriveRecord) -> None:
        """Drive `d` is about to be configured: out of the cycle, its TPDOs no longer decoded."""
        d.configured = False
        self._tpdo_by_cob = {c: x for c, x in self._tpdo_by_cob.items() if x is not d}

    def _configure_mapping(self, d: DriveRecord) -> PdoMapping:
        """Configure drive `d` by SDO (blocking; any thread: it touches only canopen's node);
        its PDO mappings. Raises ConfigureError naming the node and step."""
        return configure_node(
            d.node,
            d.node_id,
            heartbeat_ms=self._heartbeat_ms,
            interp=self._interp,
            velocity_offset=self._velocity_offset,
            torque=self._torque,
        )

    def _take_config_job(self) -> None:
        """The loop's thread takes over a finished `ConfigJob`: its drives configured (but one
        that restarted again meanwhile), its failure kept for the next `arm`'s refusal."""
        job = self._config_job
        if job is None or not job.done():
            return
        self._config_job = None
        self._sdo_expected = False
        for d, mapping in job.results:
            if not job.restarted_since(d):
                self._use_mapping(d, *mapping)
        self._config_failure = job.error

    @property
    def configuring(self) -> tuple[int, ...]:
        """Node ids being configured beside the loop (after a restart) now; () if none."""
        job = self._config_job
        return () if job is None or job.done() else tuple(job.node_ids)

    def _use_mapping(
        self, d: DriveRecord, rpdo1: PdoMap, rpdo2: PdoMap | None, tpdo1: PdoMap
    ) -> None:
        """Take drive `d` as configured with these PDOs: precompile their structs."""
        d.rpdo1, d.rpdo1_cob = pdo_struct(rpdo1), rpdo1.cob_id or 0
        if rpdo2 is not None:
            d.rpdo2, d.rpdo2_cob = pdo_struct(rpdo2), rpdo2.cob_id or 0
        else:
            d.rpdo2 = None
        d.tpdo1 = pdo_struct(tpdo1)
        self._host_cob_ids.update(c for c in (d.rpdo1_cob, d.rpdo2_cob) if c)
        d.restarted = False
        d.configured = True
        d.next_answer = self._syncs_sent  # its TPDOs answer the SYNCs from now on
        d.nmt_state = None  # until its next heartbeat says OPERATIONAL
        self._tpdo_by_cob = {**self._tpdo_by_cob, tpdo1.cob_id or 0: d}
        self._refresh(d)

    # --- receive ----------------------------------------------------------------------------

    def poll(self) -> int:
        """Drain up to `max_frames_per_poll` received frames without blocking; update readings.

        When no cycle was sent since the previous poll (the loop sent no set-points), also
        sends one (held set-points and SYNC), at most every half period. Returns the number of
        frames taken off the bus (0, reading nothing, if called while `configure` is under way:
        its SDO pump is the bus's only reader until it returns). Never raises: bad frames,
        unknown senders and bus errors are counted in `stats`.
        """
        if self._configuring:
            return 0  # the `configure` pump is the bus's only reader meanwhile
        if self._config_job is not None and self._config_job.done():
            self._take_config_job()
        fast = self._fast
        handled = self._drain_bus() if fast is None else self._drain_fast(fast)
        self._stats.frames_rx += handled
        if (
            not self._cycled_since_poll
            and self._tpdo_by_cob
            and self._clock() - self._last_sync_s >= 0.5 * self.period_s
        ):
            with contextlib.suppress(BusError):  # counted in stats; poll never raises
                self._cycle()
        self._cycled_since_poll = False
        return handled

    def read(self) -> Sequence[AxisReading]:
        """Latest reading per axis, in `node_ids` order (live objects updated by `poll`)."""
        return self._readings

    def reading(self, node_id: int) -> AxisReading:
        """The live reading of drive `node_id`. Raises KeyError if it is not one of ours."""
        return self._by_node[node_id].reading

    def drive_status(self, node_id: int) -> DriveStatus:
        """A snapshot of drive `node_id`'s CiA 402 details. Raises KeyError if not ours."""
        d = self._by_node[node_id]
        emcy = d.emcy
        return DriveStatus(
            node_id,
            d.configured,
            d.statusword,
            d.state,
            None if d.nmt_state is None else NMT_STATES.get(d.nmt_state, str(d.nmt_state)),
            d.torque,
            None if emcy is None else emcy.code,
            None if emcy is None else emcy.register,
            None if emcy is None else emcy_text(emcy.code),
        )

    def bad_frames(self, node_id: int) -> int:
        """Undecodable frames that came from drive `node_id` so far. Raises KeyError."""
        return self._by_node[node_id].bad_frames

    @property
    def stats(self) -> BusStats:
        """Traffic counters (live; copy with `snapshot()`)."""
        return self._stats

    # --- transmit ---------------------------------------------------------------------------

    def _cycle(self) -> None:
        """Write every configured drive's RPDOs, then produce one SYNC (on the fast path one
        system call per 64 frames).

        Raises BusError naming every failed frame, after trying all of them.
        """
        frames = self._tx_frames
        frames.clear()
        goal = self._goal
        enabled = DriveState.OPERATION_ENABLED
        for d in self._drives:
            if not d.configured:
                continue
            state = d.state
            cw = controlword_for(goal, state, d.fault_reset)
            if cw == CW_FAULT_RESET:
                d.fault_reset = False  # one edge per arm
            if state is not enabled:
                # Not following set-points: hold where the reel is when it starts to.
                if d.actual_counts is not None:
                    d.target_counts = d.actual_counts
                d.ff_units = 0
            frames.append((d.rpdo1_cob, d.rpdo1.pack(cw, d.target_counts), False))
            rpdo2 = d.rpdo2
            if rpdo2 is not None:
                frames.append((d.rpdo2_cob, rpdo2.pack(d.ff_units), False))
        frames.append(_SYNC_FRAME)
        failed = self._send_frames(frames)
        self._last_sync_s = sent_s = self._clock()
        if not failed or failed[-1][0] != len(frames) - 1:  # the SYNC went out
            self._sync_times[self._syncs_sent % SYNC_RING] = sent_s
            self._syncs_sent += 1
        self._cycled_since_poll = True
        if failed:
            raise BusError("; ".join(f"{self._frame_name(frames[i][0])}: {t}" for i, t in failed))

    def _send_frames(self, frames: Sequence[tuple[int, bytes, bool]]) -> list[tuple[int, str]]:
        """Send `frames` in order, every one tried; (index, failure text) of those that failed
        (counted in `stats` by `send_failure`). Raises nothing."""
        fast = self._fast
        if fast is None:
            failed: list[tuple[int, str]] = []
            send = self._network.send_message
            for i, (can_id, data, _remote) in enumerate(frames):
                try:
                    send(can_id, data)
                except BusError as exc:
                    failed.append((i, str(exc)))
            return failed
        try:
            errors = fast.send_frames(frames)
        except Exception as exc:  # not a frame's failure: none of them is known to be sent
            return [(i, send_failure(self._stats, f[0], exc)) for i, f in enumerate(frames)]
        if errors is None:
            self._stats.frames_tx += len(frames)
            return []
        self._stats.frames_tx += len(frames) - len(errors)
        return [(i, send_failure(self._stats, frames[i][0], exc)) for i, exc in errors]

    def _frame_name(self, can_id: int) -> str:
        """What a cycle's frame `can_id` is, for a failure message: "node 3 RPDO1", "SYNC"."""
        for d in self._drives:
            if can_id == d.rpdo1_cob:
                return f"node {d.node_id} RPDO1"
            if d.rpdo2 is not None and can_id == d.rpdo2_cob:
                return f"node {d.node_id} RPDO2"
        return "SYNC" if can_id == SYNC_COB_ID else f"0x{can_id:03X}"

    def command(
        self, positions_rev: Sequence[float], velocity_ff_rps: Sequence[float] | None = None
    ) -> None:
        """Set every drive's target position (motor turns, `node_ids` order) and velocity
        offset, write the RPDOs and produce a SYNC.

        Raises ValueError, sending nothing, if a sequence has the wrong length, a value is not
        finite or a position does not fit the drive's 32-bit position. A feed-forward beyond
        the 32-bit velocity offset is clamped (counted in `stats.ff_clamped`). Raises BusError
        if a send fails (after trying every frame).
        """
        ids = self.node_ids
        n = len(ids)
        if len(positions_rev) != n:
            raise ValueError(f"command needs {n} positions, got {len(positions_rev)}")
        if velocity_ff_rps is not None and len(velocity_ff_rps) != n:
            raise ValueError(
                f"command needs {n} velocity feed-forwards, got {len(velocity_ff_rps)}"
            )
        cpr = self.counts_per_rev
        vu = self._velocity_units_per_rps
        targets = [0] * n
        ffs = [0] * n
        for i in range(n):
            p = positions_rev[i]
            counts = p * cpr
            if not (math.isfinite(counts) and INT32_MIN <= counts <= INT32_MAX):
                raise ValueError(
                    f"position for node {ids[i]} does not fit the drive's 32-bit position: {p!r}"
                )
            targets[i] = round(counts)
            if velocity_ff_rps is not None:
                v = velocity_ff_rps[i]
                if not math.isfinite(v):
                    raise ValueError(
                        f"velocity feed-forward for node {ids[i]} is not finite: {v!r}"
                    )
                units = v * vu
                if not INT32_MIN <= units <= INT32_MAX:
                    units = INT32_MAX if units > 0.0 else INT32_MIN
                    self._stats.ff_clamped += 1
                ffs[i] = round(units)
        for d, t, f in zip(self._drives, targets, ffs, strict=True):
            d.target_counts = t
            d.ff_units = f
        self._cycle()

    def _commanded(self) -> None:
        """A state-changing command goes out with the next cycle: the drives' status is judged
        again only on statuswords answering that cycle's SYNC or a later one
        (`AxisReading.status_fresh`); a drive that is not configured is judged on its NMT
        heartbeats."""
        self._command_sync = self._syncs_sent
        now_s = self._clock()
        for r in self._readings:
            r.command_stamp_s = now_s

    def arm(self) -> None:
        """Bring every drive to Operation enabled, holding where its reel is.

        Sends a fault reset edge to a faulted drive; the state machine then advances one
        transition per cycle (confirmation: `ready`, axis_state 8). A drive not configured
        (restarted since it was) is first configured again by SDO beside the loop (a
        `ConfigJob` on a worker thread; `poll` keeps cycling the other drives meanwhile and
        takes the job over when it is done): the arm is refused until then.

        Raises ArmRefused, changing nothing else, while a drive is not configured (naming the
        drives, and why the last try failed if it did); BusError if a send fails.
        """
        self._take_config_job()
        job = self._config_job
        if job is not None:
            raise ArmRefused(
                f"node{'s' if len(job.drives) > 1 else ''} {_ids(job.node_ids)} still being "
                "configured by SDO after a restart; arm again in a moment"
            )
        pending = [d for d in self._drives if not d.configured]
        if pending:
            for d in pending:
                self._forget_tpdo(d)
            self._sdo_expected = True
            self._config_job = ConfigJob(pending, self._configure_mapping).start()
            failed = self._config_failure
            self._config_failure = None
            why = (
                "restarted (NMT boot-up) and lost its set-up"
                if all(d.restarted for d in pending)
                else "not configured yet"
            )
            raise ArmRefused(
                f"node{'s' if len(pending) > 1 else ''} {_ids(d.node_id for d in pending)} "
                f"{why}: being configured by SDO beside the loop; arm again in a moment"
                + ("" if failed is None else f" (the last try failed: {failed})")
            )
        fault_states = (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)
        for d in self._drives:
            d.fault_reset = d.state in fault_states
        self._goal = Goal.ENABLED
        self._commanded()
        self._cycle()

    def disarm(self) -> None:
        """Disable voltage on every drive (Switch on disabled). Raises BusError on failure."""
        self._goal = Goal.DISABLED
        for d in self._drives:
            d.fault_reset = False
        self._commanded()
        self._cycle()

    def estop(self) -> None:
        """Quick stop on every drive at once: the controlword of every RPDO in one cycle.

        A drive not configured (never, or restarted) gets NMT Stop instead. Raises BusError
        if a send fails (after trying every frame).
        """
        self._goal = Goal.QUICK_STOP
        self._commanded()
        failures: list[str] = []
        for d in self._drives:
            d.fault_reset = False
            if not d.configured:
                try:
                    d.node.nmt.state = "STOPPED"
                except BusError as exc:
                    failures.append(f"node {d.node_id} NMT Stop: {exc}")
        try:
            self._cycle()
        except BusError as exc:
            failures.append(str(exc))
        if failures:
            raise BusError("; ".join(failures))

    def request_encoders(self) -> None:
        """Run one cycle (held set-points, SYNC): every drive answers with its TPDO, read by
        the next `poll()`. Raises BusError if a send fails."""
        self._cycle()


def _ids(node_ids: Iterable[int]) -> str:
    """ "1, 3" for node ids 1 and 3."""
    return ", ".join(str(n) for n in node_ids)


_DRIVER_OPTIONS = frozenset(
    {
        "counts_per_rev",
        "velocity_units_per_rps",
        "eds",
        "velocity_offset",
        "torque",
        "heartbeat_period_s",
        "sdo_timeout_s",
    }
)
_USED_OBJECTS = (
    *(0x1005, 0x1017, 0x6040, 0x6041, 0x6060, 0x6061, 0x6064, 0x607A, 0x60C2),
    *range(0x1400, 0x1404),
    *range(0x1600, 0x1604),
    *range(0x1800, 0x1804),
    *range(0x1A00, 0x1A04),
)
"""Objects `configure` writes or reads on every drive (0x60B1 and 0x6077 besides, if used)."""


def open_driver(
    bus: can.BusABC, node_ids: Sequence[int], options: Mapping[str, Any], loop: LoopSettings
) -> CiA402Reels:
    """The registry's factory (`drivers.registry`, family "cia402"): `CiA402Reels` with the
    `[drive]` options, the loop's period as the drives' interpolation period.

    Raises ValueError on bad node ids, an unknown or bad option, or a period the drives cannot
    represent; OSError if the EDS cannot be read.
    """
    unknown = sorted(set(options) - _DRIVER_OPTIONS)
    if unknown:
        raise ValueError(f"unknown CiA 402 [drive] options {unknown}")
    if "counts_per_rev" not in options:
        raise ValueError("CiA 402 drives need counts_per_rev")
    return CiA402Reels(bus, node_ids, period_s=loop.period_s, **options)


def check_options(options: Mapping[str, Any], period_s: float) -> list[tuple[str, str]]:
    """The registry's checks of CiA 402 options (family "cia402"): the loop period has an exact
    interpolation period (0x60C2), and a configured EDS loads and has every object the driver
    uses. Returns (key path, problem) pairs; empty if none. Raises nothing."""
    problems: list[tuple[str, str]] = []
    try:
        interpolation_period(period_s)
    except ValueError as exc:
        problems.append(("loop.rate_hz", f"{exc}: CiA 402 drives need a period like 1, 2 or 4 ms"))
    eds = options.get("eds")
    if eds is not None:
        try:
            od = canopen.import_od(str(eds))
        except Exception as exc:  # canopen raises many kinds on a malformed file
            problems.append(("drive.eds", f"not a usable EDS: {type(exc).__name__}: {exc}"))
        else:
            needed = list(_USED_OBJECTS)
            if options.get("velocity_offset", True):
                needed.append(0x60B1)
            if options.get("torque", True):
                needed.append(0x6077)
            missing = [f"0x{i:04X}" for i in needed if i not in od]
            if missing:
                problems.append(
                    ("drive.eds", f"lacks objects the driver uses: {', '.join(missing)}")
                )
    return problems
