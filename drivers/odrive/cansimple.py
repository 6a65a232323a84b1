"""ODrive CANSimple (firmware 0.6) codec: pure encode/decode functions, no I/O.

Frames use 11-bit ids ``node_id << 5 | cmd_id`` (node 0..63, command 0..31) and little-endian
payloads; the layouts below follow ODrive's published DBC for firmware 0.6.10 (a copy lives in
tests/data/odrive-cansimple-0.6.dbc and the tests cross-check every message with cantools).

    0x01 Heartbeat            axis_error u32 | axis_state u8 | procedure_result u8 |
                              trajectory_done bit 48                          (ODrive -> host, 8)
    0x02 Estop                no data                                          (host -> ODrive, 0)
    0x03 Get_Error            active_errors u32 | disarm_reason u32  (RTR request, reply 8)
    0x07 Set_Axis_State       axis_requested_state u32                         (8; 4 accepted)
    0x09 Get_Encoder_Estimates pos_estimate f32 [rev] | vel_estimate f32 [rev/s]  (cyclic or RTR, 8)
    0x0B Set_Controller_Mode  control_mode u32 | input_mode u32                (8)
    0x0C Set_Input_Pos        input_pos f32 [rev] | vel_ff i16 [0.001 rev/s] |
                              torque_ff i16 [0.001 Nm]                         (8)
    0x0D Set_Input_Vel        input_vel f32 [rev/s] | input_torque_ff f32 [Nm] (8)
    0x0E Set_Input_Torque     input_torque f32 [Nm]                            (8; 4 accepted)
    0x0F Set_Limits           velocity_limit f32 [rev/s] | current_limit f32 [A] (8)
    0x18 Clear_Errors         identify u8                                      (1; 0 accepted)
    0x1C Get_Torques          torque_target f32 [Nm] | torque_estimate f32 [Nm] (cyclic or RTR, 8)

Encoders return a `Frame` ``(arbitration_id, data, is_remote)`` and raise ValueError on a value
that cannot be sent (out-of-range id, NaN/inf, integer overflow). `decode` never raises: it
returns a message dataclass, or a `DecodeError` naming what was wrong, so a receive path is
branch-only. No message it returns carries a NaN or inf.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

# --- command ids -----------------------------------------------------------------------------

HEARTBEAT: Final = 0x01
ESTOP: Final = 0x02
GET_ERROR: Final = 0x03
SET_AXIS_STATE: Final = 0x07
GET_ENCODER_ESTIMATES: Final = 0x09
SET_CONTROLLER_MODE: Final = 0x0B
SET_INPUT_POS: Final = 0x0C
SET_INPUT_VEL: Final = 0x0D
SET_INPUT_TORQUE: Final = 0x0E
SET_LIMITS: Final = 0x0F
CLEAR_ERRORS: Final = 0x18
GET_TORQUES: Final = 0x1C

MAX_NODE_ID: Final = 0x3F
VEL_FF_SCALE_RPS: Final = 0.001
"""Set_Input_Pos Vel_FF wire unit: one int16 count is 0.001 rev/s (range ±32.767 rev/s)."""
TORQUE_FF_SCALE_NM: Final = 0.001
"""Set_Input_Pos Torque_FF wire unit: one int16 count is 0.001 Nm."""
VEL_FF_MAX_RPS: Final = 32767 * VEL_FF_SCALE_RPS
TORQUE_FF_MAX_NM: Final = 32767 * TORQUE_FF_SCALE_NM


class AxisState(enum.IntEnum):
    """ODrive AxisState (firmware 0.6)."""

    UNDEFINED = 0
    IDLE = 1
    STARTUP_SEQUENCE = 2
    FULL_CALIBRATION_SEQUENCE = 3
    MOTOR_CALIBRATION = 4
    SENSORLESS_CONTROL = 5
    ENCODER_INDEX_SEARCH = 6
    ENCODER_OFFSET_CALIBRATION = 7
    CLOSED_LOOP_CONTROL = 8
    LOCKIN_SPIN = 9
    ENCODER_DIR_FIND = 10
    HOMING = 11
    ENCODER_HALL_POLARITY_CALIBRATION = 12
    ENCODER_HALL_PHASE_CALIBRATION = 13
    ANTICOGGING_CALIBRATION = 14


class ControlMode(enum.IntEnum):
    """ODrive ControlMode."""

    VOLTAGE_CONTROL = 0
    TORQUE_CONTROL = 1
    VELOCITY_CONTROL = 2
    POSITION_CONTROL = 3


class InputMode(enum.IntEnum):
    """ODrive InputMode."""

    INACTIVE = 0
    PASSTHROUGH = 1
    VEL_RAMP = 2
    POS_FILTER = 3
    MIX_CHANNELS = 4
    TRAP_TRAJ = 5
    TORQUE_RAMP = 6
    MIRROR = 7
    TUNING = 8


class ODriveError(enum.IntFlag):
    """ODrive 0.6 axis error bits (Heartbeat Axis_Error, Get_Error Active_Errors)."""

    NONE = 0
    INITIALIZING = 0x1
    SYSTEM_LEVEL = 0x2
    TIMING_ERROR = 0x4
    MISSING_ESTIMATE = 0x8
    BAD_CONFIG = 0x10
    DRV_FAULT = 0x20
    MISSING_INPUT = 0x40
    DC_BUS_OVER_VOLTAGE = 0x100
    DC_BUS_UNDER_VOLTAGE = 0x200
    DC_BUS_OVER_CURRENT = 0x400
    DC_BUS_OVER_REGEN_CURRENT = 0x800
    CURRENT_LIMIT_VIOLATION = 0x1000
    MOTOR_OVER_TEMP = 0x2000
    INVERTER_OVER_TEMP = 0x4000
    VELOCITY_LIMIT_VIOLATION = 0x8000
    POSITION_LIMIT_VIOLATION = 0x10000
    WATCHDOG_TIMER_EXPIRED = 0x1000000
    ESTOP_REQUESTED = 0x2000000
    SPINOUT_DETECTED = 0x4000000
    BRAKE_RESISTOR_DISARMED = 0x8000000
    THERMISTOR_DISCONNECTED = 0x10000000
    CALIBRATION_ERROR = 0x40000000


def error_names(axis_error: int) -> str:
    """Human-readable names of the bits set in `axis_error`, e.g. "ESTOP_REQUESTED|DRV_FAULT"."""
    if axis_error == 0:
        return "NONE"
    names = [e.name for e in ODriveError if e.value and axis_error & e.value and e.name]
    unknown = axis_error & ~sum(e.value for e in ODriveError)
    if unknown:
        names.append(f"0x{unknown:x}")
    return "|".join(names)


_STATE_NAMES: Final = {s.value: s.name for s in AxisState}


def axis_state_name(axis_state: int) -> str:
    """The name of an AxisState value, e.g. "CLOSED_LOOP_CONTROL"; "state N" if unknown."""
    name = _STATE_NAMES.get(axis_state)
    return name if name is not None else f"state {axis_state}"


def fault_text(axis_error: int) -> str | None:
    """The axis error bits by name with the raw value, e.g. "ESTOP_REQUESTED (0x2000000)";
    None for no error."""
    if axis_error == 0:
        return None
    return f"{error_names(axis_error)} (0x{axis_error:x})"


# --- messages --------------------------------------------------------------------------------

Frame = tuple[int, bytes, bool]
"""An encoded frame: (11-bit arbitration id, payload bytes, is_remote)."""


@dataclass(frozen=True, slots=True)
class Heartbeat:
    """0x01: axis error bits, axis state, procedure result and trajectory-done flag."""

    node_id: int
    axis_error: int
    axis_state: int
    procedure_result: int
    trajectory_done: bool


@dataclass(frozen=True, slots=True)
class Estop:
    """0x02: emergency stop request (no payload)."""

    node_id: int


@dataclass(frozen=True, slots=True)
class GetError:
    """0x03 reply: active error bits and the reason of the last disarm."""

    node_id: int
    active_errors: int
    disarm_reason: int


@dataclass(frozen=True, slots=True)
class SetAxisState:
    """0x07: request an axis state."""

    node_id: int
    requested_state: int


@dataclass(frozen=True, slots=True)
class EncoderEstimates:
    """0x09: position (rev) and velocity (rev/s) estimates, both finite."""

    node_id: int
    pos_estimate_rev: float
    vel_estimate_rps: float


@dataclass(frozen=True, slots=True)
class SetControllerMode:
    """0x0B: control mode and input mode."""

    node_id: int
    control_mode: int
    input_mode: int


@dataclass(frozen=True, slots=True)
class SetInputPos:
    """0x0C: position set-point with velocity and torque feed-forward (as decoded, quantised)."""

    node_id: int
    input_pos_rev: float
    vel_ff_rps: float
    torque_ff_nm: float


@dataclass(frozen=True, slots=True)
class SetInputVel:
    """0x0D: velocity set-point with torque feed-forward."""

    node_id: int
    input_vel_rps: float
    torque_ff_nm: float


@dataclass(frozen=True, slots=True)
class SetInputTorque:
    """0x0E: torque set-point (N m, motor's positive direction) for TORQUE_CONTROL, finite."""

    node_id: int
    input_torque_nm: float


@dataclass(frozen=True, slots=True)
class SetLimits:
    """0x0F: velocity limit (rev/s) and current limit (A)."""

    node_id: int
    velocity_limit_rps: float
    current_limit_a: float


@dataclass(frozen=True, slots=True)
class ClearErrors:
    """0x18: clear errors; identify=1 also blinks the LED."""

    node_id: int
    identify: int


@dataclass(frozen=True, slots=True)
class Torques:
    """0x1C: the torque the controller asks of the motor and the torque it estimates (N m,
    motor's positive direction), both finite."""

    node_id: int
    torque_target_nm: float
    torque_estimate_nm: float


@dataclass(frozen=True, slots=True)
class RemoteRequest:
    """An RTR frame asking node `node_id` for message `cmd_id` (e.g. 0x09, 0x03)."""

    node_id: int
    cmd_id: int


HOST_MESSAGES: Final = (
    Estop,
    SetAxisState,
    SetControllerMode,
    SetInputPos,
    SetInputVel,
    SetInputTorque,
    SetLimits,
    ClearErrors,
    RemoteRequest,
)
"""The messages a host sends to an axis (commands and RTR requests); the others (Heartbeat,
GetError, EncoderEstimates, Torques) are what an axis sends."""


class DecodeErrorKind(enum.Enum):
    """Why a frame could not be decoded."""

    LENGTH = "length"
    NON_FINITE = "non_finite"
    UNKNOWN_COMMAND = "unknown_command"
    EXTENDED_ID = "extended_id"
    BAD_REMOTE = "bad_remote"


@dataclass(frozen=True, slots=True)
class DecodeError:
    """A frame that could not be decoded: which frame, what kind of error, details."""

    arbitration_id: int
    kind: DecodeErrorKind
    detail: str

    @property
    def node_id(self) -> int:
        """Node id the bad frame claims to come from (or go to)."""
        return (self.arbitration_id >> 5) & MAX_NODE_ID


Message = (
    Heartbeat
    | Estop
    | GetError
    | SetAxisState
    | EncoderEstimates
    | SetControllerMode
    | SetInputPos
    | SetInputVel
    | SetInputTorque
    | SetLimits
    | ClearErrors
    | Torques
    | RemoteRequest
)

# --- encoding --------------------------------------------------------------------------------

_U32 = struct.Struct("<I")
_U32U32 = struct.Struct("<II")
_HEARTBEAT = struct.Struct("<IBBBx")
_F32F32 = struct.Struct("<ff")
_INPUT_POS = struct.Struct("<fhh")
_U8 = struct.Struct("<B")
_F32 = struct.Struct("<f")
_PAD4 = b"\x00\x00\x00\x00"
_F32_MAX = 3.4028234663852886e38
_EMPTY = b""


def arbitration_id(node_id: int, cmd_id: int) -> int:
    """CANSimple 11-bit id ``node_id << 5 | cmd_id``. Raises ValueError out of range."""
    if not 0 <= node_id <= MAX_NODE_ID:
        raise ValueError(f"node_id must be 0..63, got {node_id!r}")
    if not 0 <= cmd_id <= 0x1F:
        raise ValueError(f"cmd_id must be 0..31, got {cmd_id!r}")
    return node_id << 5 | cmd_id


def split_id(arb_id: int) -> tuple[int, int]:
    """(node_id, cmd_id) of an 11-bit CANSimple arbitration id."""
    return (arb_id >> 5) & MAX_NODE_ID, arb_id & 0x1F


def _f32(name: str, value: float) -> float:
    # finite and representable as float32 (struct would raise OverflowError past the max)
    if not (value - value == 0.0 and -_F32_MAX <= value <= _F32_MAX):
        raise ValueError(f"{name} must be a finite float32, got {value!r}")
    return value


def _u32(name: str, value: int) -> int:
    if not 0 <= value <= 0xFFFFFFFF:
        raise ValueError(f"{name} must be 0..2**32-1, got {value!r}")
    return value


def _scaled_i16(name: str, value: float, scale: float) -> int:
    if value - value != 0.0:
        raise ValueError(f"{name} must be finite, got {value!r}")
    counts = round(value / scale)
    if not -32768 <= counts <= 32767:
        raise ValueError(f"{name}={value!r} is out of the int16 range at scale {scale}")
    return counts


def encode_heartbeat(
    node_id: int,
    axis_error: int,
    axis_state: int,
    procedure_result: int = 0,
    trajectory_done: bool = False,
) -> Frame:
    """Heartbeat (0x01), as an ODrive (or the simulator) sends it. Raises ValueError."""
    if not (0 <= axis_state <= 0xFF and 0 <= procedure_result <= 0xFF):
        raise ValueError("axis_state and procedure_result must be 0..255")
    data = _HEARTBEAT.pack(
        _u32("axis_error", axis_error), axis_state, procedure_result, 1 if trajectory_done else 0
    )
    return arbitration_id(node_id, HEARTBEAT), data, False


def encode_estop(node_id: int) -> Frame:
    """Estop (0x02): the axis disarms and latches ESTOP_REQUESTED. Raises ValueError."""
    return arbitration_id(node_id, ESTOP), _EMPTY, False


def encode_get_error(node_id: int, active_errors: int, disarm_reason: int) -> Frame:
    """Get_Error reply (0x03), as an ODrive sends it. Raises ValueError."""
    data = _U32U32.pack(_u32("active_errors", active_errors), _u32("disarm_reason", disarm_reason))
    return arbitration_id(node_id, GET_ERROR), data, False


def encode_set_axis_state(node_id: int, requested_state: int) -> Frame:
    """Set_Axis_State (0x07), 8 bytes as in the DBC. Raises ValueError."""
    data = _U32.pack(_u32("requested_state", requested_state)) + _PAD4
    return arbitration_id(node_id, SET_AXIS_STATE), data, False


def encode_encoder_estimates(
    node_id: int, pos_estimate_rev: float, vel_estimate_rps: float
) -> Frame:
    """Get_Encoder_Estimates data frame (0x09), as an ODrive sends it. Raises ValueError."""
    data = _F32F32.pack(
        _f32("pos_estimate_rev", pos_estimate_rev), _f32("vel_estimate_rps", vel_estimate_rps)
    )
    return arbitration_id(node_id, GET_ENCODER_ESTIMATES), data, False


def encode_set_controller_mode(node_id: int, control_mode: int, input_mode: int) -> Frame:
    """Set_Controller_Mode (0x0B). Raises ValueError."""
    data = _U32U32.pack(_u32("control_mode", control_mode), _u32("input_mode", input_mode))
    return arbitration_id(node_id, SET_CONTROLLER_MODE), data, False


def encode_set_input_pos(
    node_id: int, input_pos_rev: float, vel_ff_rps: float = 0.0, torque_ff_nm: float = 0.0
) -> Frame:
    """Set_Input_Pos (0x0C): float32 position, int16 feed-forwards at 0.001 rev/s and 0.001 Nm.

    Raises ValueError on a non-finite value or a feed-forward outside ±32.767 (int16 range).
    """
    data = _INPUT_POS.pack(
        _f32("input_pos_rev", input_pos_rev),
        _scaled_i16("vel_ff_rps", vel_ff_rps, VEL_FF_SCALE_RPS),
        _scaled_i16("torque_ff_nm", torque_ff_nm, TORQUE_FF_SCALE_NM),
    )
    return arbitration_id(node_id, SET_INPUT_POS), data, False


def encode_set_input_vel(node_id: int, input_vel_rps: float, torque_ff_nm: float = 0.0) -> Frame:
    """Set_Input_Vel (0x0D). Raises ValueError on a non-finite value."""
    data = _F32F32.pack(_f32("input_vel_rps", input_vel_rps), _f32("torque_ff_nm", torque_ff_nm))
    return arbitration_id(node_id, SET_INPUT_VEL), data, False


def encode_set_input_torque(node_id: int, input_torque_nm: float) -> Frame:
    """Set_Input_Torque (0x0E), 8 bytes as in the DBC (float32 torque, 4 zero bytes).

    Raises ValueError on a non-finite torque (or one beyond float32) or a bad node id.
    """
    data = _F32.pack(_f32("input_torque_nm", input_torque_nm)) + _PAD4
    return arbitration_id(node_id, SET_INPUT_TORQUE), data, False


def encode_set_limits(node_id: int, velocity_limit_rps: float, current_limit_a: float) -> Frame:
    """Set_Limits (0x0F). Raises ValueError on a non-finite value."""
    data = _F32F32.pack(
        _f32("velocity_limit_rps", velocity_limit_rps), _f32("current_limit_a", current_limit_a)
    )
    return arbitration_id(node_id, SET_LIMITS), data, False


def encode_clear_errors(node_id: int, identify: int = 0) -> Frame:
    """Clear_Errors (0x18) with its 1-byte Identify field. Raises ValueError."""
    if identify not in (0, 1):
        raise ValueError(f"identify must be 0 or 1, got {identify!r}")
    return arbitration_id(node_id, CLEAR_ERRORS), _U8.pack(identify), False


def encode_torques(node_id: int, torque_target_nm: float, torque_estimate_nm: float) -> Frame:
    """Get_Torques data frame (0x1C), as an ODrive sends it. Raises ValueError."""
    data = _F32F32.pack(
        _f32("torque_target_nm", torque_target_nm), _f32("torque_estimate_nm", torque_estimate_nm)
    )
    return arbitration_id(node_id, GET_TORQUES), data, False


def encode_rtr(node_id: int, cmd_id: int) -> Frame:
    """An RTR request for message `cmd_id` from `node_id` (e.g. 0x09 or 0x03). Raises ValueError."""
    return arbitration_id(node_id, cmd_id), _EMPTY, True


# --- decoding --------------------------------------------------------------------------------


def _length_error(arb_id: int, data: bytes | bytearray, name: str, want: str) -> DecodeError:
    return DecodeError(arb_id, DecodeErrorKind.LENGTH, f"{name}: {len(data)} bytes, want {want}")


def _dec_heartbeat(arb_id: int, data: bytes | bytearray) -> Message | DecodeError:
    if len(data) != 8:
        return _length_error(arb_id, data, "Heartbeat", "8")
    err, state, proc, flags = _HEARTBEAT.unpack(data)
    return Heartbeat(arb_id >> 5, err, state, proc, bool(flags & 1))


def _dec_estop(arb_id: int, data: bytes | bytearray) -> Message | DecodeError:
    return Estop(arb_id >> 5)


def _dec_get_error(arb_id: int, data: bytes | bytearray) -> Message | DecodeError:
    if len(data) != 8:
        return _length_error(arb_id, data, "Get_Error", "8")
    active, reason = _U32U32.unpack(data)
    return GetError(arb_id >> 5, active, reason)


def _dec_set_axis_state(arb_id: int, data: bytes | bytearray) -> Message | DecodeError:
    n = len(data)
    if n != 8 and n != 4:
        return _length_error(arb_id, data, "Set_Axis_State", "8 (or 4)")
    return SetAxisState(arb_id >> 5, _U32.unpack_from(data)[0])


def _non_finite(arb_id: int, name: str, a: float, b: float) -> DecodeError:
    return DecodeError(arb_id, DecodeErrorKind.NON_FINITE, f"{name}: ({a!r}, {b!r})")


def _dec_encoder_estimates(arb_id: int, data: bytes | bytearray) -> Message | DecodeError:
    if len(data) != 8:
        return _length_error(arb_id, data, "Get_Encoder_Estimates", "8")
    pos, vel = _F32F32.unpack(data)
    if pos - pos != 0.0 or vel - vel != 0.0:  # NaN or inf
        return _non_finite(arb_id, "Get_Encoder_Estimates", pos, vel)
    return EncoderEstimates(arb_id >> 5, pos, vel)


def _dec_set_controller_mode(arb_id: int, data: bytes | bytearray) -> Message | DecodeError:
    if len(data) != 8:
        return _length_error(arb_id, data, "Set_Controller_Mode", "8")
    control, inp = _U32U32.unpack(data)
    return SetControllerMode(arb_id >> 5, control, inp)


def _dec_set_input_pos(arb_id: int, data: bytes | bytearray) -> Message | DecodeError:
    if len(data) != 8:
        return _length_error(arb_id, data, "Set_Input_Pos", "8")
    pos, vel_ff, torque_ff = _INPUT_POS.unpack(data)
    if pos - pos != 0.0:
        return _non_finite(arb_id, "Set_Input_Pos", pos, 0.0)
    return SetInputPos(arb_id >> 5, pos, vel_ff * VEL_FF_SCALE_RPS, torque_ff * TORQUE_FF_SCALE_NM)


def _dec_set_input_vel(arb_id: int, data: bytes | bytearray) -> Message | DecodeError:
    if len(data) != 8:
        return _length_error(arb_id, data, "Set_Input_Vel", "8")
    vel, torque = _F32F32.unpack(data)
    if vel - vel != 0.0 or torque - torque != 0.0:
        return _non_finite(arb_id, "Set_Input_Vel", vel, torque)
    return SetInputVel(arb_id >> 5, vel, torque)


def _dec_set_input_torque(arb_id: int, data: bytes | bytearray) -> Message | DecodeError:
    n = len(data)
    if n != 8 and n != 4:
        return _length_error(arb_id, data, "Set_Input_Torque", "8 (or 4)")
    torque = _F32.unpack_from(data)[0]
    if torque - torque != 0.0:
        return _non_finite(arb_id, "Set_Input_Torque", torque, 0.0)
    return SetInputTorque(arb_id >> 5, torque)


def _dec_set_limits(arb_id: int, data: bytes | bytearray) -> Message | DecodeError:
    if len(data) != 8:
        return _length_error(arb_id, data, "Set_Limits", "8")
    vel, cur = _F32F32.unpack(data)
    if vel - vel != 0.0 or cur - cur != 0.0:
        return _non_finite(arb_id, "Set_Limits", vel, cur)
    return SetLimits(arb_id >> 5, vel, cur)


def _dec_clear_errors(arb_id: int, data: bytes | bytearray) -> Message | DecodeError:
    n = len(data)
    if n > 1:
        return _length_error(arb_id, data, "Clear_Errors", "1 (or 0)")
    return ClearErrors(arb_id >> 5, data[0] if n else 0)


def _dec_torques(arb_id: int, data: bytes | bytearray) -> Message | DecodeError:
    if len(data) != 8:
        return _length_error(arb_id, data, "Get_Torques", "8")
    target, estimate = _F32F32.unpack(data)
    if target - target != 0.0 or estimate - estimate != 0.0:
        return _non_finite(arb_id, "Get_Torques", target, estimate)
    return Torques(arb_id >> 5, target, estimate)


_Decoder = Callable[[int, bytes | bytearray], "Message | DecodeError"]
_DECODERS: dict[int, _Decoder] = {
    HEARTBEAT: _dec_heartbeat,
    ESTOP: _dec_estop,
    GET_ERROR: _dec_get_error,
    SET_AXIS_STATE: _dec_set_axis_state,
    GET_ENCODER_ESTIMATES: _dec_encoder_estimates,
    SET_CONTROLLER_MODE: _dec_set_controller_mode,
    SET_INPUT_POS: _dec_set_input_pos,
    SET_INPUT_VEL: _dec_set_input_vel,
    SET_INPUT_TORQUE: _dec_set_input_torque,
    SET_LIMITS: _dec_set_limits,
    CLEAR_ERRORS: _dec_clear_errors,
    GET_TORQUES: _dec_torques,
}
# Tuple indexed by cmd_id: one lookup per frame, None for commands this codec does not know.
_DECODE_TABLE: tuple[_Decoder | None, ...] = tuple(_DECODERS.get(i) for i in range(32))

RTR_COMMANDS: Final = frozenset({HEARTBEAT, GET_ERROR, GET_ENCODER_ESTIMATES, GET_TORQUES})
"""Commands a host may request by RTR (the ODrive answers with the data frame)."""


def decode(
    arb_id: int, data: bytes | bytearray, is_remote: bool = False, is_extended_id: bool = False
) -> Message | DecodeError:
    """Decode one CANSimple frame into a message dataclass, or a `DecodeError` saying why not.

    Never raises for any frame content: wrong length, NaN/inf floats, unknown commands,
    extended (29-bit) ids and RTR frames for non-requestable messages all give a DecodeError.
    """
    if is_extended_id or not 0 <= arb_id <= 0x7FF:
        return DecodeError(arb_id, DecodeErrorKind.EXTENDED_ID, "not an 11-bit CANSimple id")
    cmd_id = arb_id & 0x1F
    if is_remote:
        if cmd_id in RTR_COMMANDS:
            return RemoteRequest(arb_id >> 5, cmd_id)
        return DecodeError(arb_id, DecodeErrorKind.BAD_REMOTE, f"RTR for command 0x{cmd_id:02x}")
    fn = _DECODE_TABLE[cmd_id]
    if fn is None:
        return DecodeError(arb_id, DecodeErrorKind.UNKNOWN_COMMAND, f"command 0x{cmd_id:02x}")
    return fn(arb_id, data)
