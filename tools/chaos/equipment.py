"""The test equipment of a chaos worker: the simulated drives' faulty link to the bus, the tap that
hears every frame the daemon sends, and what the simulated drives know that the daemon does not
(their true positions, whether they are in closed loop).

Fault injection lives here, in the equipment, never in the product's drivers: `ChaosBus` wraps
the simulated drives' python-can bus (frames lost both ways, corrupted or duplicated on their way
out, a blackout); frames of other nodes, a second SYNC producer and CAN error frames are sent on
the bus by the worker through a bus of its own.
"""

from __future__ import annotations

import math
import random
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import can
import numpy as np

ODRIVE_ESTOP = 0x02
ODRIVE_SET_INPUT_POS = 0x0C
ODRIVE_SET_INPUT_VEL = 0x0D
ODRIVE_SET_INPUT_TORQUE = 0x0E
ODRIVE_CLOSED_LOOP = 8
_F32 = struct.Struct("<f")
_RPDO1 = struct.Struct("<Hi")


class ChaosBus:
    """A python-can bus with faults on it, for the simulated drives' side (`SimLink` calls only
    `recv`, `send` and `shutdown`). Thread-safe counters; the fault settings are plain
    attributes the worker changes between frames."""

    def __init__(self, bus: can.BusABC, rng: random.Random) -> None:
        self.bus = bus
        self._rng = rng
        self.loss = 0.0
        """Probability that a frame is lost (either way)."""
        self.blackout_until_s = 0.0
        """Every frame is lost until this monotonic time (a bus-off or a cut cable)."""
        self.corrupt_left = 0
        """The next this many frames the drives send are cut short (a CAN controller's CRC
        would drop a bit error; a short frame is what reaches software)."""
        self.duplicate_left = 0
        self.lost = 0
        self.corrupted = 0
        self.duplicated = 0

    def _lose(self) -> bool:
        if self.blackout_until_s and time.monotonic() < self.blackout_until_s:
            self.lost += 1
            return True
        if self.loss > 0.0 and self._rng.random() < self.loss:
            self.lost += 1
            return True
        return False

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The next frame that is not lost, within `timeout`."""
        msg = self.bus.recv(timeout)
        while msg is not None and self._lose():
            msg = self.bus.recv(0.0)
        return msg

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send `msg` unless it is lost; cut short or sent twice when asked."""
        if self._lose():
            return
        if self.corrupt_left > 0 and msg.dlc > 0:
            self.corrupt_left -= 1
            self.corrupted += 1
            cut = self._rng.randrange(0, msg.dlc)
            msg = can.Message(
                arbitration_id=msg.arbitration_id,
                data=bytes(msg.data[:cut]),
                is_extended_id=False,
            )
        self.bus.send(msg, timeout)
        if self.duplicate_left > 0:
            self.duplicate_left -= 1
            self.duplicated += 1
            self.bus.send(msg, timeout)

    def shutdown(self) -> None:
        """Shut the wrapped bus down."""
        self.bus.shutdown()


class Drives:
    """The simulated drives of one family: their truth and the faults they can be given."""

    def __init__(self, family: str, bank: Any, cfg: Any) -> None:
        self.family = family
        self.bank = bank
        self.cfg = cfg
        self.node_ids = tuple(cfg.node_ids)
        self.axes = [bank.axis(n) for n in self.node_ids]
        self.reels = [r.reel for r in cfg.reels]
        self.counts_per_rev = float(cfg.drive.options.get("counts_per_rev", 1.0))
        self._frame_offset_rev = [0.0] * len(self.axes)

    def true_turns(self) -> list[float]:
        """Every motor's true position (turns), in node order."""
        return [float(a.position_rev) for a in self.axes]

    def true_lengths_m(self) -> np.ndarray:
        """Every cable's true length from its motor's true position."""
        return np.array([r.length_m(t) for r, t in zip(self.reels, self.true_turns(), strict=True)])

    def encoder_offset_rev(self, i: int) -> float:
        """How far the positions the daemon commands drive `i` are from its true ones: a CiA 402
        drive's incremental encoder counts from 0 after a restart, and the daemon commands in
        that new count once it has set the drive up again (`new_count`); until then, in the
        old one."""
        return self._frame_offset_rev[i]

    def new_count(self, i: int) -> None:
        """The daemon started setting drive `i` up again (its first SDO request): from now on it
        commands in the drive's count since the restart."""
        a = self.axes[i]
        self._frame_offset_rev[i] = float(a.encoder_estimate_rev - a.position_rev)

    def closed_loop(self) -> list[bool]:
        """Whether each drive follows set-points (ODrive closed loop; CiA 402 Operation
        enabled)."""
        if self.family == "odrive":
            return [int(a.axis_state) == ODRIVE_CLOSED_LOOP for a in self.axes]
        return [a.state.value == "Operation enabled" for a in self.axes]

    def silence(self, i: int, silent: bool) -> None:
        """Drive `i` stops (or starts again) sending and receiving."""
        self.axes[i].silence(silent)

    def reboot(self, i: int) -> None:
        """Drive `i` restarts: ODrive comes back IDLE without errors (its position kept);
        CiA 402 sends its boot-up and has lost its set-up (its encoder counts from 0)."""
        a = self.axes[i]
        if self.family == "odrive":
            a.reboot()
        else:
            a.power_cycle()

    def report_error(self, i: int, rng: random.Random) -> str:
        """Drive `i` reports an error (ODrive axis error; CiA 402 EMCY and Fault); its name."""
        a = self.axes[i]
        if self.family == "odrive":
            code = rng.choice((0x800, 0x1000, 0x40))  # overspeed, current limit, motor failed
            a.set_axis_error(code)
            return f"axis error 0x{code:x}"
        code = rng.choice((0x2310, 0x4210, 0x8611, 0x3210))
        a.set_error(code)
        return f"EMCY 0x{code:04X}"


def fpk(anchors: np.ndarray, lengths: np.ndarray, guess: np.ndarray) -> tuple[np.ndarray, float]:
    """The point whose distances to `anchors` best match `lengths` (Gauss-Newton, written here
    and not the product's, so the checks do not take the product's word); and the RMS misfit."""
    p = np.array(guess, dtype=float)
    for _ in range(30):
        d = p - anchors
        r = np.linalg.norm(d, axis=1)
        if not np.all(r > 1e-9):
            break
        f = r - lengths
        jac = d / r[:, None]
        step = np.linalg.lstsq(jac, -f, rcond=None)[0]
        p = p + step
        if float(np.linalg.norm(step)) < 1e-10:
            break
    d = np.linalg.norm(p - anchors, axis=1) - lengths
    return p, float(math.sqrt(float(np.mean(d * d))))


class Tap(threading.Thread):
    """Hears every frame on the bus (a bus of its own on the same group) and keeps what the
    daemon commands: each drive's latest set-point as a cable length, the e-stop's first frame,
    and the violations of the bus invariants (a non-finite value; a set-point outside the
    cable range; a cable commanded faster than the limit)."""

    def __init__(
        self,
        bus: can.BusABC,
        family: str,
        cfg: Any,
        encoder_offset_rev: Callable[[int], float],
        violation: Callable[[str, str], None],
        new_count: Callable[[int], None] = lambda i: None,
    ) -> None:
        super().__init__(name="chaos-tap", daemon=True)
        self.bus = bus
        self.family = family
        self.cfg = cfg
        self.node_ids = tuple(cfg.node_ids)
        self._index = {n: i for i, n in enumerate(self.node_ids)}
        self._reels = [r.reel for r in cfg.reels]
        self._offset = encoder_offset_rev
        self._new_count = new_count
        self._violation = violation
        self._cpr = float(cfg.drive.options.get("counts_per_rev", 1.0))
        lim = cfg.limits
        self._min_l = float(lim.min_cable_m)
        self._max_l = float(lim.max_cable_m)
        self._vmax = float(lim.max_cable_speed_mps)
        self._slack_s = 4.0 / float(cfg.loop.rate_hz)
        self.lengths_m = [math.nan] * len(self.node_ids)
        self.stamps_s = [-math.inf] * len(self.node_ids)
        self._hist: list[deque[tuple[float, float]]] = [deque() for _ in self.node_ids]
        self.estop_stamps: dict[int, float] = {}
        """Each drive's first e-stop frame since `estop_stamps` was cleared (kernel receive
        time, wall clock: the daemon's send time within microseconds on loopback)."""
        self.frames = 0
        self.setpoints = 0
        self.non_finite = 0
        self._halt = threading.Event()

    def stop(self) -> None:
        """Stop the thread and join it."""
        self._halt.set()
        self.join(2.0)

    def forget_history(self) -> None:
        """A new daemon (or a re-homed one): the cable speed check starts afresh."""
        for h in self._hist:
            h.clear()

    def run(self) -> None:
        recv = self.bus.recv
        while not self._halt.is_set():
            try:
                msg = recv(0.05)
            except Exception:  # the bus shut down at the end
                return
            if msg is None or msg.is_error_frame or msg.is_extended_id:
                continue
            self.frames += 1
            stamp = float(msg.timestamp)
            if self.family == "odrive":
                self._odrive(msg.arbitration_id, bytes(msg.data), stamp, msg.is_remote_frame)
            else:
                self._cia402(msg.arbitration_id, bytes(msg.data), stamp)

    def _odrive(self, arb: int, data: bytes, stamp: float, remote: bool) -> None:
        node, cmd = arb >> 5, arb & 0x1F
        i = self._index.get(node)
        if i is None or remote:
            return
        if cmd == ODRIVE_ESTOP:
            self.estop_stamps.setdefault(node, stamp)
        elif cmd in (ODRIVE_SET_INPUT_POS, ODRIVE_SET_INPUT_VEL, ODRIVE_SET_INPUT_TORQUE):
            if len(data) < 4:
                return
            (value,) = _F32.unpack_from(data)
            if (
                cmd == ODRIVE_SET_INPUT_VEL
                and len(data) >= 8
                and not math.isfinite(_F32.unpack_from(data, 4)[0])
            ):
                value = math.nan
            if not math.isfinite(value):
                self.non_finite += 1
                self._violation("nan_on_bus", f"node {node} command 0x{cmd:02x}: {data.hex()}")
                return
            if cmd == ODRIVE_SET_INPUT_POS:
                self._setpoint(i, value, stamp)

    def _cia402(self, arb: int, data: bytes, stamp: float) -> None:
        sdo = self._index.get(arb - 0x600)
        if sdo is not None:  # the daemon sets the drive up: it commands in its new count next
            self._new_count(sdo)
            return
        i = self._index.get(arb - 0x200)
        if i is None or len(data) != _RPDO1.size:
            return
        cw, counts = _RPDO1.unpack(data)
        if cw & 0x86 == 0x02:  # quick stop
            self.estop_stamps.setdefault(self.node_ids[i], stamp)
        if cw & 0x0F == 0x0F:  # enable operation: the drive follows this target
            self._setpoint(i, counts / self._cpr - self._offset(i), stamp)

    def _setpoint(self, i: int, turns: float, stamp: float) -> None:
        """A set-point the daemon sent at `stamp` (wall clock)."""
        now = stamp
        length = self._reels[i].length_m(turns)
        self.setpoints += 1
        self.lengths_m[i] = length
        self.stamps_s[i] = time.monotonic()
        if not self._min_l - 1e-6 <= length <= self._max_l + 1e-6:
            self._violation(
                "setpoint_outside_workspace",
                f"node {self.node_ids[i]} commanded a {length:.4f} m cable "
                f"(allowed {self._min_l}..{self._max_l} m)",
            )
        h = self._hist[i]
        h.append((now, length))
        while len(h) > 2 and now - h[1][0] >= 0.25:
            h.popleft()
        t0, l0 = h[0]
        dt = now - t0
        # Kernel receive stamps: the daemon's send times within microseconds on loopback, however
        # late this thread reads them. A tick's set-point is planned from the tick's own clock,
        # so allow one late tick's worth (the planner's step is capped at 4 periods).
        if dt >= 0.25 and abs(length - l0) > self._vmax * 1.01 * (dt + self._slack_s):
            self._violation(
                "cable_too_fast",
                f"node {self.node_ids[i]}: {abs(length - l0) * 1e3:.1f} mm in {dt:.3f} s "
                f"(limit {self._vmax} m/s)",
            )
            h.clear()

    def commanded_lengths(self, max_age_s: float) -> np.ndarray | None:
        """Every drive's latest commanded length if each is at most `max_age_s` old."""
        now = time.monotonic()
        if any(now - s > max_age_s for s in self.stamps_s):
            return None
        return np.array(self.lengths_m)


def error_frame(kind: str) -> can.Message:
    """A SocketCAN-style error frame: "bus_off" (class 0x40) or "passive" (controller
    problem 0x04, error-passive in data byte 1)."""
    if kind == "bus_off":
        return can.Message(arbitration_id=0x40, is_error_frame=True, data=bytes(8))
    return can.Message(
        arbitration_id=0x04, is_error_frame=True, data=bytes([0, 0x10, 0, 0, 0, 0, 0, 0])
    )


def foreign_frames(family: str, rng: random.Random) -> Sequence[can.Message]:
    """Frames of a node the robot does not have (ODrive node 40; CANopen node 100): its
    heartbeat, encoder or TPDO, and an SDO request to it: traffic, never the robot's."""
    if family == "odrive":
        node = 40
        return [
            can.Message(arbitration_id=node << 5 | 0x01, data=bytes(8), is_extended_id=False),
            can.Message(
                arbitration_id=node << 5 | 0x09,
                data=struct.pack("<ff", rng.uniform(-5, 5), 0.0),
                is_extended_id=False,
            ),
        ]
    node = 100
    return [
        can.Message(arbitration_id=0x700 + node, data=b"\x05", is_extended_id=False),
        can.Message(arbitration_id=0x180 + node, data=bytes(8), is_extended_id=False),
        can.Message(arbitration_id=0x600 + node, data=bytes(8), is_extended_id=False),
    ]
