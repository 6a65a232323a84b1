"""Simulated CiA 402 servo drives on canopen `LocalNode`s, on any python-can bus.

`SimCiA402Drive` is one drive: a canopen `LocalNode` with the object dictionary shipped in
`cia402.eds` (its SDO server, NMT slave with heartbeat, EMCY producer are canopen's), plus
what canopen leaves to an application: the PDOs as configured in the dictionary (mapping
checked on every SDO write, as a drive does: mapping only while a PDO is disabled and its
count is 0, mappable objects only, at most 64 bits), the CiA 402 state machine, and the
motion. `handle(arb_id, data)` takes one received frame and returns the frames the drive
sends in answer; `step(dt_s)` advances the motion and returns what falls due (heartbeats,
event-timer TPDOs, injected frames). `SimCiA402Bank` serves a set of drives on a bus in a
thread; `main` is the same loop as a process (`python -m drivers.cia402.sim ...`).

Behaviour: NMT boot-up then PRE-OPERATIONAL at power-up (heartbeat per 0x1017, default off);
PDOs only in OPERATIONAL. At each SYNC the drive applies the synchronous RPDOs received since
the previous one, then sends its synchronous TPDOs (so a statusword answers the controlword
of the same cycle). Asynchronous RPDOs (types 254/255) act at once; asynchronous TPDOs go out
on their event timer and when their data changes. State machine per CiA 402 (controlword
command coding, fault reset on the rising edge of bit 7, Quick stop active left to Switch on
disabled after the stop for quick stop option codes 0-3 (0x605A, default 2), kept for 5-8).
Leaving NMT OPERATIONAL while Operation enabled is a quick stop. Power stage off (every state
but Operation enabled and Quick stop active): the reel is braked where it is.

Motion in Operation enabled with cyclic synchronous position (mode 8): as the simulated ODrive,
a position loop with velocity feed-forward, velocity and acceleration limits,

    vel_cmd = clamp(velocity_offset + pos_gain * (target - position), -vmax, +vmax)

the velocity moving toward vel_cmd by at most `max_accel_rps2 * dt` (sub-steps of at most
1 ms). Quick stop brakes at `max_accel_rps2`. Torque actual (0x6077, per mille) is the
acceleration over `max_accel_rps2`. Other modes hold position.

Fault injection: `silence(True)` (no frames in or out), `set_error(code)` (EMCY with that code
and Fault; a fault reset clears it, unless `persistent`), `send_corrupt(n)` (wrong-length
TPDO1 frames), `drift(rate)` (position actual drifts from the true position),
`power_cycle()` (a restart: boot-up, the object dictionary back to its defaults, position
actual from 0 as an incremental encoder does), `hold_sdo(True)` (SDO requests are taken but
answered only once released: a drive busy for a while).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import struct
import sys
import threading
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import canopen
from canopen.objectdictionary import ODVariable
from canopen.sdo.exceptions import SdoAbortedError

from drivers.cia402.profile import DriveState
from drivers.odrive.sim import DEFAULT_POS_GAIN, MAX_SUBSTEP_S
from drivers.registry import SimSettings
from drivers.simbank import (
    SimFrame,
    SimLink,
    ThreadedSimBank,
    add_bus_arguments,
    floats_arg,
    serve_process,
)
from drivers.socketcan_fast import CAN_EFF_FLAG, CAN_ERR_FLAG, CAN_RTR_FLAG, FastSocketCan

EDS_PATH = Path(__file__).with_name("cia402.eds")
DEFAULT_COUNTS_PER_REV = 131072
"""A 17-bit encoder."""
Frame = tuple[int, bytes]
"""(COB-ID, data) of one standard data frame."""
_FLAGGED = CAN_EFF_FLAG | CAN_RTR_FLAG | CAN_ERR_FLAG
"""Frames no drive answers: extended ids, remote frames, error frames."""

_MAX_SUBSTEPS = 10_000
_REST_SNAP_REV = 1e-9
_REST_SNAP_RPS = 1e-6
_ABORT_STATE = 0x08000022  # data cannot be stored because of the present device state
_ABORT_RANGE = 0x06090030  # value range of parameter exceeded
_ABORT_NOT_MAPPABLE = 0x06040041
_ABORT_PDO_LENGTH = 0x06040042
_EMCY_RPDO_LENGTH = 0x8210  # PDO not processed due to length error
_NMT_OPERATIONAL = "OPERATIONAL"

# Statusword per state: the state bits, voltage enabled (bit 4) where the power stage is on,
# remote (bit 9) always.
_STATUSWORD = {
    DriveState.NOT_READY_TO_SWITCH_ON: 0x0200,
    DriveState.SWITCH_ON_DISABLED: 0x0240,
    DriveState.READY_TO_SWITCH_ON: 0x0231,
    DriveState.SWITCHED_ON: 0x0233,
    DriveState.OPERATION_ENABLED: 0x0237,
    DriveState.QUICK_STOP_ACTIVE: 0x0217,
    DriveState.FAULT_REACTION_ACTIVE: 0x021F,
    DriveState.FAULT: 0x0208,
}
_SW_FOLLOWING = 0x1000  # bit 12 in CSP: the drive follows the target
_POWERED = (DriveState.OPERATION_ENABLED, DriveState.QUICK_STOP_ACTIVE)


def _command(cw: int) -> str | None:
    """The CiA 402 command a controlword codes (bit 7 set: none, it is the fault reset)."""
    if cw & 0x80:
        return None
    if not cw & 0x02:
        return "disable voltage"
    if cw & 0x06 == 0x02:
        return "quick stop"
    if cw & 0x07 == 0x06:
        return "shutdown"
    return "enable operation" if cw & 0x0F == 0x0F else "switch on"


_S = DriveState
# (state, command) -> next state, with the transition numbers of CiA 402.
_TRANSITIONS: dict[tuple[DriveState, str], DriveState] = {
    (_S.SWITCH_ON_DISABLED, "shutdown"): _S.READY_TO_SWITCH_ON,  # 2
    (_S.READY_TO_SWITCH_ON, "switch on"): _S.SWITCHED_ON,  # 3
    (_S.READY_TO_SWITCH_ON, "enable operation"): _S.OPERATION_ENABLED,  # 3 + 4
    (_S.SWITCHED_ON, "enable operation"): _S.OPERATION_ENABLED,  # 4
    (_S.OPERATION_ENABLED, "switch on"): _S.SWITCHED_ON,  # 5 (disable operation)
    (_S.SWITCHED_ON, "shutdown"): _S.READY_TO_SWITCH_ON,  # 6
    (_S.READY_TO_SWITCH_ON, "disable voltage"): _S.SWITCH_ON_DISABLED,  # 7
    (_S.READY_TO_SWITCH_ON, "quick stop"): _S.SWITCH_ON_DISABLED,  # 7
    (_S.OPERATION_ENABLED, "shutdown"): _S.READY_TO_SWITCH_ON,  # 8
    (_S.OPERATION_ENABLED, "disable voltage"): _S.SWITCH_ON_DISABLED,  # 9
    (_S.SWITCHED_ON, "disable voltage"): _S.SWITCH_ON_DISABLED,  # 10
    (_S.SWITCHED_ON, "quick stop"): _S.SWITCH_ON_DISABLED,  # 10
    (_S.OPERATION_ENABLED, "quick stop"): _S.QUICK_STOP_ACTIVE,  # 11
    (_S.QUICK_STOP_ACTIVE, "disable voltage"): _S.SWITCH_ON_DISABLED,  # 12
}


def _error_register(code: int) -> int:
    """0x1001 for error `code`: generic, plus current/voltage/temperature/communication."""
    reg = 0x01
    top = code >> 12
    if top == 0x2:
        reg |= 0x02
    elif top == 0x3:
        reg |= 0x04
    elif top == 0x4:
        reg |= 0x08
    elif code >> 8 in (0x81, 0x82):
        reg |= 0x10
    return reg


class _Periodic:
    """A periodic frame canopen asked for (the heartbeat), sent by the drive's `step`."""

    def __init__(self, can_id: int, data: bytes, period_s: float) -> None:
        self.can_id = can_id
        self.data = data
        self.period_s = period_s
        self.due_s = 0.0
        self.stopped = False

    def update(self, data: bytes) -> None:
        self.data = bytes(data)

    def stop(self) -> None:
        self.stopped = True


class _SimNetwork(canopen.Network):
    """canopen's network for one simulated drive: sends go to an outbox the bank sends."""

    def __init__(self) -> None:
        super().__init__(None)
        self.outbox: list[Frame] = []
        self.periodic: list[_Periodic] = []

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self.outbox.append((can_id, bytes(data)))

    def send_periodic(  # type: ignore[override]
        self, can_id: int, data: bytes, period: float, remote: bool = False
    ) -> _Periodic:
        task = _Periodic(can_id, bytes(data or b""), period)
        self.periodic = [p for p in self.periodic if not p.stopped]
        self.periodic.append(task)
        return task


@dataclass(slots=True)
class _Pdo:
    cob_id: int
    trans_type: int
    entries: tuple[tuple[int, int, int], ...]
    """(index, subindex, bytes) per mapped object."""
    size: int
    event_timer_s: float
    due_s: float = 0.0
    syncs: int = 0
    last: bytes | None = None


class _InjectedFaults:
    """The fault injection of `SimCiA402Drive` (a mixin: the drive owns the state below)."""

    _lock: threading.RLock
    _silent: bool
    _sdo_held: list[tuple[int, bytes, float]] | None
    _sdo_released: list[tuple[int, bytes, float]]
    _pending_error: tuple[int, bool] | None
    _pending_corrupt: int
    _drift_rate_rps: float

    def _zero_here(self) -> None:
        raise NotImplementedError

    def _power_up(self) -> None:
        raise NotImplementedError

    def silence(self, silent: bool = True) -> None:
        """Go silent (no frames received or sent), or speak again."""
        with self._lock:
            self._silent = silent

    def hold_sdo(self, hold: bool = True) -> None:
        """Hold SDO requests unanswered (True), or answer the held ones with the next step and
        every later one at once (False)."""
        with self._lock:
            if hold:
                if self._sdo_held is None:
                    self._sdo_held = []
            elif self._sdo_held is not None:
                self._sdo_released.extend(self._sdo_held)
                self._sdo_held = None

    def set_error(self, code: int, *, persistent: bool = False) -> None:
        """Raise error `code` with the next step: EMCY, Fault (power stage off). A fault reset
        clears it unless `persistent`. Raises ValueError unless 0x1000 <= code <= 0xFFFF."""
        if not 0x1000 <= code <= 0xFFFF:
            raise ValueError(f"EMCY error code 0x1000..0xFFFF expected, got 0x{code:x}")
        with self._lock:
            self._pending_error = (code, persistent)

    def send_corrupt(self, count: int = 1) -> None:
        """Emit `count` wrong-length (5 byte) TPDO1 frames with the next step."""
        with self._lock:
            self._pending_corrupt += count

    def drift(self, rate_rev_per_s: float) -> None:
        """Let position actual drift from the true position at this rate."""
        if not math.isfinite(rate_rev_per_s):
            raise ValueError("drift rate must be finite")
        with self._lock:
            self._drift_rate_rps = rate_rev_per_s

    def power_cycle(self) -> None:
        """Restart the drive: boot-up, dictionary defaults, position actual from 0."""
        with self._lock:
            self._zero_here()
            self._power_up()


class SimCiA402Drive(_InjectedFaults):
    """One simulated CiA 402 servo drive; thread-safe (an internal lock guards every method)."""

    def __init__(
        self,
        node_id: int,
        *,
        initial_position_rev: float = 0.0,
        counts_per_rev: float = DEFAULT_COUNTS_PER_REV,
        velocity_units_per_rps: float | None = None,
        max_velocity_rps: float = 20.0,
        max_accel_rps2: float = 200.0,
        pos_gain: float = DEFAULT_POS_GAIN,
        eds: str | Path | None = None,
    ) -> None:
        """Power up a drive (boot-up, PRE-OPERATIONAL, Switch on disabled).

        `counts_per_rev`: position units per motor turn; `velocity_units_per_rps`: velocity
        units per rev/s (default `counts_per_rev`). Raises ValueError on a node id outside
        1..127, a non-finite position, or a non-positive limit or gain.
        """
        if not 1 <= node_id <= 127:
            raise ValueError(f"CANopen node id {node_id} is outside 1..127")
        if not math.isfinite(initial_position_rev):
            raise ValueError("initial_position_rev must be finite")
        vel_units = counts_per_rev if velocity_units_per_rps is None else velocity_units_per_rps
        for name, value in (
            ("counts_per_rev", counts_per_rev),
            ("velocity_units_per_rps", vel_units),
            ("max_velocity_rps", max_velocity_rps),
            ("max_accel_rps2", max_accel_rps2),
            ("pos_gain", pos_gain),
        ):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        self.node_id = node_id
        self.counts_per_rev = float(counts_per_rev)
        self.velocity_units_per_rps = float(vel_units)
        self.max_velocity_rps = max_velocity_rps
        self.max_accel_rps2 = max_accel_rps2
        self.pos_gain = pos_gain
        self.position_rev = float(initial_position_rev)
        self.velocity_rps = 0.0
        self.accel_rps2 = 0.0
        self._lock = threading.RLock()
        self._od = canopen.import_od(str(EDS_PATH if eds is None else eds), node_id)
        self.network = _SimNetwork()
        self.node = canopen.LocalNode(node_id, self._od)
        self.network.add_node(self.node)
        self.node.add_write_callback(self._on_write)  # type: ignore[no-untyped-call]
        self.node.add_read_callback(self._on_read)  # type: ignore[no-untyped-call]
        self.network.subscribe(0, self._on_nmt)
        self.syncs_received = 0
        self.rpdos_applied = 0
        self._silent = False
        self._sdo_held: list[tuple[int, bytes, float]] | None = None
        self._sdo_released: list[tuple[int, bytes, float]] = []
        self._drift_rate_rps = 0.0
        self._pending_corrupt = 0
        self._pending_error: tuple[int, bool] | None = None
        self._drift_rev = 0.0
        self._power_up()

    # --- power, state ---------------------------------------------------------------------

    def _power_up(self) -> None:
        """Reset to power-up: defaults, boot-up message, PRE-OPERATIONAL, Switch on disabled."""
        for task in self.network.periodic:
            task.stop()
        self.network.periodic = []
        self.node.data_store.clear()
        self.state = DriveState.SWITCH_ON_DISABLED
        self.error_code = 0
        self.error_persistent = False
        (self.mode,) = struct.unpack("<b", self.node.get_data(0x6060, 0))
        self.target_counts = round(self.encoder_estimate_rev * self.counts_per_rev)
        self.velocity_offset_units = 0
        self._controlword = 0
        self._sync_cob = 0x80
        self._rpdos: dict[int, _Pdo] = {}
        self._tpdos: list[_Pdo] = []
        self._rpdo_pending: dict[int, bytes] = {}
        self._pdo_dirty = True
        self.node.nmt.send_command(0x81)  # reset: INITIALISING, boot-up message
        self.node.nmt.send_command(0x80)  # PRE-OPERATIONAL: heartbeat per 0x1017

    def _zero_here(self) -> None:
        # An incremental encoder counts from 0 after a restart; the reel stays where it is.
        self._drift_rev = -self.position_rev

    @property
    def encoder_estimate_rev(self) -> float:
        """The position this drive reports (true position plus accumulated drift/offset)."""
        return self.position_rev + self._drift_rev

    @property
    def nmt_state(self) -> str:
        """The NMT state (canopen's name, e.g. "OPERATIONAL")."""
        return self.node.nmt.state

    @property
    def statusword(self) -> int:
        """The statusword (0x6041) for the current state."""
        sw = _STATUSWORD[self.state]
        if self.state is DriveState.OPERATION_ENABLED and self.mode == 8:
            sw |= _SW_FOLLOWING
        return sw

    @property
    def torque_permille(self) -> int:
        """Torque actual (0x6077): the acceleration as thousandths of the limit."""
        return max(-1000, min(1000, round(1000.0 * self.accel_rps2 / self.max_accel_rps2)))

    def _enter(self, state: DriveState) -> None:
        if state not in _POWERED:
            self.velocity_rps = 0.0
            self.accel_rps2 = 0.0
        self.state = state

    def _fault(self, code: int) -> None:
        reg = _error_register(code)
        self.error_code = code
        self._enter(DriveState.FAULT)
        self.node.emcy.send(code, reg)

    def _on_controlword(self, cw: int) -> None:
        prev = self._controlword
        self._controlword = cw
        s = self.state
        if s is DriveState.FAULT:
            if cw & 0x80 and not prev & 0x80 and not self.error_persistent:  # 15
                self.error_code = 0
                self._enter(DriveState.SWITCH_ON_DISABLED)
                self.node.emcy.reset()
            return
        command = _command(cw)
        if command is None:
            return
        new = _TRANSITIONS.get((s, command))
        if (
            s is DriveState.QUICK_STOP_ACTIVE
            and command == "enable operation"
            and 5 <= self._quick_stop_option() <= 8
        ):
            new = DriveState.OPERATION_ENABLED  # transition 16
        if new is not None and new is not s:
            self._enter(new)

    def _quick_stop_option(self) -> int:
        (value,) = struct.unpack("<h", self.node.get_data(0x605A, 0))
        return int(value)

    # --- object dictionary callbacks ------------------------------------------------------

    def _on_read(self, index: int, subindex: int, od: ODVariable) -> int | None:
        if index == 0x6041:
            return self.statusword
        if index == 0x6064:
            return round(self.encoder_estimate_rev * self.counts_per_rev)
        if index == 0x606C:
            return round(self.velocity_rps * self.velocity_units_per_rps)
        if index == 0x6077:
            return self.torque_permille
        if index == 0x6061:
            return int(self.mode)
        if index == 0x603F:
            return self.error_code
        if index == 0x1001:
            return _error_register(self.error_code) if self.error_code else 0
        return None

    def _on_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        if index == 0x6040:
            self._on_controlword(int(od.decode_raw(data)))
        elif index == 0x607A:
            self.target_counts = int(od.decode_raw(data))
        elif index == 0x60B1:
            self.velocity_offset_units = int(od.decode_raw(data))
        elif index == 0x6060:
            mode = int(od.decode_raw(data))
            (supported,) = struct.unpack("<I", self.node.get_data(0x6502, 0))
            if not 1 <= mode <= 10 or not supported >> (mode - 1) & 1:
                raise SdoAbortedError(_ABORT_RANGE)
            self.mode = mode
        elif index == 0x1005:
            cob = int(od.decode_raw(data))
            if cob & 0x40000000 or cob & 0x7FF == 0:  # this drive does not produce SYNC
                raise SdoAbortedError(_ABORT_RANGE)
            self._sync_cob = cob & 0x7FF
        elif 0x1400 <= index <= 0x1BFF:
            self._check_pdo_write(index, subindex, int(od.decode_raw(data)))
            self._pdo_dirty = True

    def _u(self, index: int, subindex: int) -> int:
        return int.from_bytes(self.node.get_data(index, subindex), "little")

    def _check_pdo_write(self, index: int, subindex: int, value: int) -> None:
        """Refuse a PDO parameter write the way a drive does (raises SdoAbortedError)."""
        is_mapping = 0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF
        if not is_mapping:
            if subindex == 1:
                current = self._u(index, 1)
                # A valid PDO keeps its COB-ID: moving it needs disabling it first.
                if (
                    not current & 0x80000000
                    and not value & 0x80000000
                    and value & 0x7FF != current & 0x7FF
                ):
                    raise SdoAbortedError(_ABORT_STATE)
            elif subindex == 2 and 241 <= value <= 253:
                raise SdoAbortedError(_ABORT_RANGE)
            return
        receive = index < 0x1A00
        comm = index - 0x200
        if not self._u(comm, 1) & 0x80000000:  # mapping only while the PDO is disabled
            raise SdoAbortedError(_ABORT_STATE)
        if subindex == 0:
            if value > 8:
                raise SdoAbortedError(_ABORT_PDO_LENGTH)
            bits = sum(self._entry_bits(self._u(index, s), receive) for s in range(1, value + 1))
            if bits > 64:
                raise SdoAbortedError(_ABORT_PDO_LENGTH)
            return
        if self._u(index, 0) != 0:  # entries only while the count is 0
            raise SdoAbortedError(_ABORT_STATE)
        if value:
            self._entry_bits(value, receive)

    def _entry_bits(self, entry: int, receive: bool) -> int:
        """Bits of a mapping entry; raises SdoAbortedError if it cannot be mapped."""
        index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        obj = self._od.get_variable(index, sub)
        if obj is None:
            raise SdoAbortedError(_ABORT_NOT_MAPPABLE)
        usable = obj.writable if receive else obj.readable
        if not (obj.pdo_mappable and usable and bits == len(obj) and bits % 8 == 0):
            raise SdoAbortedError(_ABORT_NOT_MAPPABLE)
        return bits

    def _layout(self, comm: int, mapping: int) -> _Pdo | None:
        cob = self._u(comm, 1)
        if cob & 0x80000000:
            return None
        entries = []
        for s in range(1, self._u(mapping, 0) + 1):
            e = self._u(mapping, s)
            entries.append((e >> 16, (e >> 8) & 0xFF, (e & 0xFF) // 8))
        timer = 0.0
        with contextlib.suppress(SdoAbortedError, KeyError):
            timer = self._u(comm, 5) / 1000.0
        return _Pdo(
            cob & 0x7FF, self._u(comm, 2), tuple(entries), sum(e[2] for e in entries), timer
        )

    def _rebuild_pdos(self) -> None:
        self._rpdos = {}
        self._tpdos = []
        for i in range(4):
            rpdo = self._layout(0x1400 + i, 0x1600 + i)
            if rpdo is not None:
                self._rpdos[rpdo.cob_id] = rpdo
            tpdo = self._layout(0x1800 + i, 0x1A00 + i)
            if tpdo is not None:
                self._tpdos.append(tpdo)
        self._rpdo_pending = {}
        self._pdo_dirty = False

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        # canopen's NMT slave has taken the new state; resets and leaving OPERATIONAL are ours.
        if len(data) < 2 or data[1] not in (0, self.node_id):
            return
        cmd = data[0]
        if cmd in (0x81, 0x82):
            self._power_up() if cmd == 0x81 else self._reset_communication()
        elif cmd in (0x02, 0x80) and self.state is DriveState.OPERATION_ENABLED:
            self._enter(DriveState.QUICK_STOP_ACTIVE)

    def _reset_communication(self) -> None:
        for index in [i for i in self.node.data_store if 0x1000 <= i <= 0x1FFF]:
            del self.node.data_store[index]
        self._pdo_dirty = True
        self._sync_cob = 0x80
        for task in self.network.periodic:
            task.stop()
        self.network.periodic = []
        self.node.nmt.send_command(0x82)
        self.node.nmt.send_command(0x80)

    # --- PDO traffic ----------------------------------------------------------------------

    def _apply_rpdo(self, pdo: _Pdo, data: bytes) -> None:
        if len(data) < pdo.size:
            self.node.emcy.send(_EMCY_RPDO_LENGTH, 0x11)
            return
        offset = 0
        for index, sub, size in pdo.entries:
            with contextlib.suppress(SdoAbortedError):  # a value the object refuses
                self.node.set_data(index, sub, data[offset : offset + size])
            offset += size
        self.rpdos_applied += 1

    def _tpdo_data(self, pdo: _Pdo) -> bytes:
        return b"".join(self.node.get_data(i, s) for i, s, _ in pdo.entries)

    def _on_sync(self) -> None:
        self.syncs_received += 1
        pending = self._rpdo_pending
        self._rpdo_pending = {}
        for cob, data in pending.items():
            self._apply_rpdo(self._rpdos[cob], data)
        out = self.network.outbox
        for pdo in self._tpdos:
            tt = pdo.trans_type
            if tt == 0 or 1 <= tt <= 240:
                pdo.syncs += 1
                if tt and pdo.syncs % tt:
                    continue
                data = self._tpdo_data(pdo)
                if tt == 0 and data == pdo.last:
                    continue
                pdo.last = data
                out.append((pdo.cob_id, data))

    # --- the bus side ---------------------------------------------------------------------

    def hears(self, arb_id: int) -> bool:
        """Whether a frame with standard id `arb_id` concerns this drive (its SYNC, one of its
        RPDOs, what its canopen services listen to: SDO requests, NMT, LSS): a bank passes it
        only the frames it hears, so each frame costs one drive, not all. True while its PDOs
        are being rebuilt. Lock-free (the dictionaries read are replaced, never changed in
        place, by the serving thread). Raises nothing."""
        return (
            arb_id == self._sync_cob
            or arb_id in self._rpdos
            or arb_id in self.network.subscribers
            or self._pdo_dirty
        )

    def handle(self, arb_id: int, data: bytes | bytearray, timestamp: float = 0.0) -> list[Frame]:
        """Take one received standard data frame; return the frames the drive answers with.

        Frames for other nodes are ignored; malformed requests get what the drive's canopen
        services answer (e.g. an SDO abort) or nothing.
        """
        with self._lock:
            if self._silent:
                return []
            if self._pdo_dirty:
                self._rebuild_pdos()
            operational = self.node.nmt.state == _NMT_OPERATIONAL
            if self._sdo_held is not None and arb_id == 0x600 + self.node_id:
                self._sdo_held.append((arb_id, bytes(data), timestamp))
            elif arb_id == self._sync_cob:
                if operational:
                    self._on_sync()
            elif arb_id in self._rpdos:
                if operational:
                    pdo = self._rpdos[arb_id]
                    if pdo.trans_type >= 254:
                        self._apply_rpdo(pdo, bytes(data))
                    else:
                        self._rpdo_pending[arb_id] = bytes(data)
            else:
                # SDO server, NMT slave: canopen's; a malformed frame is dropped.
                with contextlib.suppress(Exception):
                    self.network.notify(arb_id, bytearray(data), timestamp)
            return self._drain()

    def _drain(self) -> list[Frame]:
        out = self.network.outbox
        self.network.outbox = []
        return out

    def step(self, dt_s: float) -> list[Frame]:
        """Advance the drive by `dt_s` seconds; return the frames that fall due."""
        with self._lock:
            if self._pdo_dirty:
                self._rebuild_pdos()
            if self._pending_error is not None:
                code, persistent = self._pending_error
                self._pending_error = None
                self.error_persistent = persistent
                self._fault(code)
            if self._sdo_held is None and self._sdo_released:
                for arb_id, data, stamp in self._sdo_released:
                    with contextlib.suppress(Exception):
                        self.network.notify(arb_id, bytearray(data), stamp)
                self._sdo_released = []
            if dt_s > 0.0:
                self._move(dt_s)
                self._drift_rev = self._drift_rev + self._drift_rate_rps * dt_s
            out = self._drain()
            if self._silent:
                return []
            for task in self.network.periodic:
                if task.stopped:
                    continue
                task.due_s -= dt_s
                if task.due_s <= 0.0:
                    task.due_s = max(task.due_s + task.period_s, 0.0)
                    out.append((task.can_id, task.data))
            if self.node.nmt.state == _NMT_OPERATIONAL:
                for pdo in self._tpdos:
                    if pdo.trans_type < 254:
                        continue
                    data = self._tpdo_data(pdo)
                    pdo.due_s -= dt_s
                    timer_due = pdo.event_timer_s > 0.0 and pdo.due_s <= 0.0
                    if timer_due or data != pdo.last:
                        pdo.due_s = pdo.event_timer_s
                        pdo.last = data
                        out.append((pdo.cob_id, data))
            while self._pending_corrupt:
                self._pending_corrupt -= 1
                cob = self._tpdos[0].cob_id if self._tpdos else 0x180 + self.node_id
                out.append((cob, b"\x37\x02\x00\x00\x00"))
            return out

    # --- motion ---------------------------------------------------------------------------

    def _move(self, dt: float) -> None:
        s = self.state
        if s is DriveState.QUICK_STOP_ACTIVE:
            self._integrate(dt, braking=True)
            if self.velocity_rps == 0.0 and self._quick_stop_option() <= 3:
                self._enter(DriveState.SWITCH_ON_DISABLED)
            return
        if s is not DriveState.OPERATION_ENABLED or self.mode != 8:
            self.accel_rps2 = 0.0
            return
        if (
            self.velocity_rps == 0.0
            and self.velocity_offset_units == 0
            and self.position_rev == self._target_rev()
        ):
            self.accel_rps2 = 0.0
            return
        self._integrate(dt, braking=False)

    def _target_rev(self) -> float:
        return self.target_counts / self.counts_per_rev - self._drift_rev

    def _integrate(self, dt: float, *, braking: bool) -> None:
        n = min(_MAX_SUBSTEPS, math.ceil(dt / MAX_SUBSTEP_S))
        h = dt / n
        vmax = self.max_velocity_rps
        dv_max = self.max_accel_rps2 * h
        # The drive closes its loop on its own position actual (drift included).
        target = self._target_rev()
        ff = self.velocity_offset_units / self.velocity_units_per_rps
        for _ in range(n):
            v = self.velocity_rps
            if braking:
                vel_cmd = 0.0
            else:
                vel_cmd = max(-vmax, min(vmax, ff + self.pos_gain * (target - self.position_rev)))
            v_new = v + max(-dv_max, min(dv_max, vel_cmd - v))
            p_new = self.position_rev + 0.5 * (v + v_new) * h
            if (
                not braking
                and ff == 0.0
                and abs(target - p_new) <= _REST_SNAP_REV
                and abs(v_new) <= _REST_SNAP_RPS
            ):
                p_new = target
                v_new = 0.0
            self.accel_rps2 = (v_new - v) / h
            self.position_rev = p_new
            self.velocity_rps = v_new


class SimCiA402Bank(ThreadedSimBank):
    """Simulated CiA 402 drives served on `bus` by a background thread (a context manager).

    The bank does not own the bus: the caller shuts it down after `stop()`.
    """

    thread_name = "sim-cia402"

    def __init__(
        self,
        bus: can.BusABC,
        node_ids: Iterable[int],
        *,
        initial_position_rev: float | Sequence[float] = 0.0,
        tick_s: float = 0.001,
        **drive_options: Any,
    ) -> None:
        """Power up one `SimCiA402Drive` per node id (not served until `start`).

        `initial_position_rev`: one value or one per node; `drive_options` go to every drive.
        Raises ValueError on duplicate node ids, a wrong number of positions or tick_s <= 0.
        """
        ids = tuple(node_ids)
        if len(set(ids)) != len(ids):
            raise ValueError(f"duplicate node ids in {ids}")
        if not (math.isfinite(tick_s) and tick_s > 0.0):
            raise ValueError("tick_s must be finite and > 0")
        if isinstance(initial_position_rev, int | float):
            initial = [float(initial_position_rev)] * len(ids)
        else:
            initial = [float(x) for x in initial_position_rev]
            if len(initial) != len(ids):
                raise ValueError(f"{len(ids)} initial positions needed, got {len(initial)}")
        super().__init__()
        self.bus = bus
        self.drives: tuple[SimCiA402Drive, ...] = tuple(
            SimCiA402Drive(n, initial_position_rev=x, **drive_options)
            for n, x in zip(ids, initial, strict=True)
        )
        self.tick_s = tick_s

    def axis(self, node_id: int) -> SimCiA402Drive:
        """The simulated drive with this node id. Raises KeyError if there is none."""
        for d in self.drives:
            if d.node_id == node_id:
                return d
        raise KeyError(node_id)

    def _serve(self, stop: threading.Event) -> None:
        run_sim(self.bus, self.drives, stop, tick_s=self.tick_s)


def open_sim_bank(
    bus: can.BusABC, node_ids: Sequence[int], options: Mapping[str, Any], sim: SimSettings
) -> SimCiA402Bank:
    """The registry's simulator factory (`drivers.registry`, family "cia402"): simulated drives
    with the `[drive]` options' scaling and EDS and the `[sim]` limits (not started). The
    drives' heartbeat is what the driver sets at start-up; they answer every SYNC, so the
    `[sim]` encoder and heartbeat periods and the watchdog do not apply.

    Raises ValueError on bad node ids or settings, or a position per node missing.
    """
    return SimCiA402Bank(
        bus,
        node_ids,
        initial_position_rev=sim.initial_positions_rev,
        tick_s=sim.tick_s,
        counts_per_rev=float(options.get("counts_per_rev", DEFAULT_COUNTS_PER_REV)),
        velocity_units_per_rps=options.get("velocity_units_per_rps"),
        max_velocity_rps=sim.max_velocity_rps,
        max_accel_rps2=sim.max_accel_rps2,
        eds=options.get("eds"),
    )


def run_sim(
    bus: can.BusABC,
    drives: Sequence[SimCiA402Drive],
    stop_event: threading.Event,
    *,
    tick_s: float = 0.001,
    fast_path: bool | FastSocketCan = True,
) -> None:
    """Serve `drives` on `bus` until `stop_event` is set: answer frames, step every tick.

    The bus is met through a `drivers.simbank.SimLink` (on SocketCAN, with `fast_path`, the fast
    path's batches); each frame goes only to the drives that hear it (`SimCiA402Drive.hears`),
    and the answers to what was received together leave together. A tick that falls due late
    first takes the frames already received, for at most one tick's time. Receive and send
    errors are swallowed (a simulated drive keeps running). Returns within about one tick
    after `stop_event` is set.
    """
    link = SimLink(bus, fast_path=fast_path)
    out: list[SimFrame] = []

    def handle(can_id: int, data: bytes | bytearray, stamp: float) -> None:
        if can_id & _FLAGGED:
            return  # extended, remote and error frames: no drive answers them
        for d in drives:
            if d.hears(can_id):
                out.extend((c, f, False) for c, f in d.handle(can_id, data, stamp))

    clock = time.monotonic
    last = clock()
    next_tick = last
    while not stop_event.is_set():
        now = clock()
        remaining = next_tick - now
        if remaining > 0.0:
            link.serve(handle, remaining, remaining)
            link.send(out)
            out.clear()
            continue
        link.serve(handle, 0.0, tick_s)  # a late tick still hears the host first
        dt = now - last
        last = now
        next_tick = next_tick + tick_s if remaining > -tick_s else now + tick_s
        for d in drives:
            out.extend((c, f, False) for c, f in d.step(dt))
        link.send(out)
        out.clear()


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m drivers.cia402.sim`: serve simulated drives on a bus until SIGTERM/SIGINT.

    Prints "READY <nodes>" on stdout once the bus is open and the drives are served.
    """
    p = argparse.ArgumentParser(prog="python -m drivers.cia402.sim", description=__doc__)
    add_bus_arguments(p)
    p.add_argument("--nodes", default="1,2,3,4", help="comma-separated CANopen node ids")
    p.add_argument("--initial-rev", default="0", help="one value, or one per node")
    p.add_argument("--counts-per-rev", type=float, default=DEFAULT_COUNTS_PER_REV)
    p.add_argument("--max-velocity-rps", type=float, default=20.0)
    p.add_argument("--max-accel-rps2", type=float, default=200.0)
    p.add_argument(
        "--pos-gain", type=float, default=DEFAULT_POS_GAIN, help="position gain, (rev/s)/rev"
    )
    args = p.parse_args(argv)
    nodes = [int(n) for n in args.nodes.split(",")]
    initial = floats_arg(args.initial_rev, len(nodes))

    def serve(bus: can.BusABC, stop: threading.Event) -> None:
        bank = SimCiA402Bank(
            bus,
            nodes,
            initial_position_rev=initial,
            tick_s=args.tick_s,
            counts_per_rev=args.counts_per_rev,
            max_velocity_rps=args.max_velocity_rps,
            max_accel_rps2=args.max_accel_rps2,
            pos_gain=args.pos_gain,
        )
        run_sim(bus, bank.drives, stop, tick_s=args.tick_s)

    return serve_process(args, nodes, serve)


if __name__ == "__main__":
    sys.exit(main())
