"""CANSimple codec: golden bytes for every message, cross-check against ODrive's 0.6 DBC."""

from __future__ import annotations

import math
import struct
import time
from pathlib import Path
from typing import Any

import cantools
import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.odrive import cansimple as cs

DBC_PATH = Path(__file__).resolve().parents[1] / "data" / "odrive-cansimple-0.6.dbc"


@pytest.fixture(scope="module")
def db() -> Any:
    return cantools.database.load_file(str(DBC_PATH))


# (encoded frame, expected arbitration id, expected bytes, expected decoded message)
GOLDEN: list[tuple[cs.Frame, int, bytes, cs.Message]] = [
    (
        cs.encode_heartbeat(1, 0x2000000, 8, 0, True),
        0x021,
        bytes.fromhex("0000000208000100"),
        cs.Heartbeat(1, 0x2000000, 8, 0, True),
    ),
    (
        cs.encode_heartbeat(6, 0x20, 1, 13, False),
        0x0C1,
        bytes.fromhex("200000000" + "10d0000"),
        cs.Heartbeat(6, 0x20, 1, 13, False),
    ),
    (cs.encode_estop(3), 0x062, b"", cs.Estop(3)),
    (
        cs.encode_get_error(2, 0x20, 0x2000000),
        0x043,
        bytes.fromhex("2000000000000002"),
        cs.GetError(2, 0x20, 0x2000000),
    ),
    (
        cs.encode_set_axis_state(0, 8),
        0x007,
        bytes.fromhex("0800000000000000"),
        cs.SetAxisState(0, 8),
    ),
    (
        cs.encode_encoder_estimates(1, 1.0, -2.5),
        0x029,
        bytes.fromhex("0000803f000020c0"),
        cs.EncoderEstimates(1, 1.0, -2.5),
    ),
    (
        cs.encode_set_controller_mode(5, 3, 1),
        0x0AB,
        bytes.fromhex("0300000001000000"),
        cs.SetControllerMode(5, 3, 1),
    ),
    (
        cs.encode_set_input_pos(3, 1.5, 2.0, -0.5),
        0x06C,
        bytes.fromhex("0000c03fd0070cfe"),
        cs.SetInputPos(3, 1.5, 2.0, -0.5),
    ),
    (
        cs.encode_set_input_vel(4, 10.0, 0.25),
        0x08D,
        bytes.fromhex("000020410000803e"),
        cs.SetInputVel(4, 10.0, 0.25),
    ),
    (
        cs.encode_set_input_torque(2, -0.75),
        0x04E,
        bytes.fromhex("000040bf00000000"),
        cs.SetInputTorque(2, -0.75),
    ),
    (
        cs.encode_set_limits(63, 20.0, 10.5),
        0x7EF,
        bytes.fromhex("0000a04100002841"),
        cs.SetLimits(63, 20.0, 10.5),
    ),
    (cs.encode_clear_errors(7), 0x0F8, b"\x00", cs.ClearErrors(7, 0)),
    (
        cs.encode_torques(2, -0.25, -0.2),
        0x05C,
        bytes.fromhex("000080becdcc4cbe"),
        cs.Torques(2, -0.25, -0.20000000298023224),  # float32 of -0.2
    ),
    (cs.encode_clear_errors(7, identify=1), 0x0F8, b"\x01", cs.ClearErrors(7, 1)),
]


@pytest.mark.parametrize(("frame", "arb_id", "data", "message"), GOLDEN)
def test_golden_bytes(frame: cs.Frame, arb_id: int, data: bytes, message: cs.Message) -> None:
    assert frame == (arb_id, data, False)
    assert cs.decode(arb_id, data) == message


def test_golden_rtr() -> None:
    assert cs.encode_rtr(2, cs.GET_TORQUES) == (0x05C, b"", True)
    assert cs.decode(0x05C, b"", is_remote=True) == cs.RemoteRequest(2, 0x1C)
    assert cs.encode_rtr(2, cs.GET_ENCODER_ESTIMATES) == (0x049, b"", True)
    assert cs.encode_rtr(2, cs.GET_ERROR) == (0x043, b"", True)
    assert cs.decode(0x049, b"", is_remote=True) == cs.RemoteRequest(2, 0x09)
    assert cs.decode(0x041, b"", is_remote=True) == cs.RemoteRequest(2, 0x01)
    bad = cs.decode(0x04C, b"", is_remote=True)  # RTR for Set_Input_Pos makes no sense
    assert isinstance(bad, cs.DecodeError)
    assert bad.kind is cs.DecodeErrorKind.BAD_REMOTE


def test_arbitration_id_layout() -> None:
    assert cs.arbitration_id(0, 0x09) == 0x009
    assert cs.arbitration_id(63, 0x1F) == 0x7FF
    assert cs.split_id(0x7EF) == (63, 0x0F)
    with pytest.raises(ValueError, match="node_id"):
        cs.arbitration_id(64, 1)
    with pytest.raises(ValueError, match="cmd_id"):
        cs.arbitration_id(1, 32)


def _dbc_message(db: Any, arb_id: int) -> Any:
    return db.get_message_by_frame_id(arb_id)


# --- DBC cross-check: our bytes decoded by cantools, cantools' bytes decoded by us ----------

DBC_SIGNALS: list[tuple[cs.Frame, dict[str, float]]] = [
    (
        cs.encode_heartbeat(1, 0x2000020, 8, 3, True),
        {
            "Axis_Error": 0x2000020,
            "Axis_State": 8,
            "Procedure_Result": 3,
            "Trajectory_Done_Flag": 1,
        },
    ),
    (
        cs.encode_heartbeat(7, 0, 1, 0, False),
        {"Axis_Error": 0, "Axis_State": 1, "Procedure_Result": 0, "Trajectory_Done_Flag": 0},
    ),
    (cs.encode_estop(4), {}),
    (
        cs.encode_get_error(0, 0x1000, 0x2000000),
        {"Active_Errors": 0x1000, "Disarm_Reason": 0x2000000},
    ),
    (cs.encode_set_axis_state(2, 8), {"Axis_Requested_State": 8}),
    (cs.encode_set_axis_state(2, 1), {"Axis_Requested_State": 1}),
    (cs.encode_encoder_estimates(3, 123.25, -7.5), {"Pos_Estimate": 123.25, "Vel_Estimate": -7.5}),
    (cs.encode_set_controller_mode(5, 3, 1), {"Control_Mode": 3, "Input_Mode": 1}),
    (
        cs.encode_set_input_pos(6, -42.5, 12.345, -1.5),
        {"Input_Pos": -42.5, "Vel_FF": 12.345, "Torque_FF": -1.5},
    ),
    (
        cs.encode_set_input_pos(1, 0.125, -32.768, 32.767),
        {"Input_Pos": 0.125, "Vel_FF": -32.768, "Torque_FF": 32.767},
    ),
    (cs.encode_set_input_vel(7, -3.0, 0.5), {"Input_Vel": -3.0, "Input_Torque_FF": 0.5}),
    (cs.encode_set_input_torque(5, 0.125), {"Input_Torque": 0.125}),
    (cs.encode_set_input_torque(0, -2.5), {"Input_Torque": -2.5}),
    (cs.encode_set_limits(0, 25.0, 12.0), {"Velocity_Limit": 25.0, "Current_Limit": 12.0}),
    (cs.encode_clear_errors(3, 1), {"Identify": 1}),
    (cs.encode_torques(1, 1.5, -0.75), {"Torque_Target": 1.5, "Torque_Estimate": -0.75}),
    (cs.encode_torques(7, 0.0, 12.25), {"Torque_Target": 0.0, "Torque_Estimate": 12.25}),
]


@pytest.mark.parametrize(("frame", "signals"), DBC_SIGNALS)
def test_our_frames_decode_with_dbc(db: Any, frame: cs.Frame, signals: dict[str, float]) -> None:
    arb_id, data, _ = frame
    msg = _dbc_message(db, arb_id)
    node, _cmd = cs.split_id(arb_id)
    assert msg.name.startswith(f"Axis{node}_")
    assert len(data) == msg.length, f"{msg.name}: DLC {len(data)} vs DBC {msg.length}"
    decoded = msg.decode(data, decode_choices=False, scaling=True) if msg.length else {}
    assert set(decoded) == set(signals)
    for name, value in signals.items():
        assert decoded[name] == pytest.approx(value, abs=1e-9), name


@pytest.mark.parametrize(("frame", "signals"), DBC_SIGNALS)
def test_dbc_frames_decode_with_ours(db: Any, frame: cs.Frame, signals: dict[str, float]) -> None:
    arb_id, data, _ = frame
    msg = _dbc_message(db, arb_id)
    dbc_bytes = bytes(msg.encode(signals, scaling=True)) if msg.length else b""
    # The DBC encoder produces exactly our bytes (byte-for-byte agreement, both directions) ...
    assert dbc_bytes == data, msg.name
    # ... and our decoder reads the DBC's bytes back to the same values.
    ours = cs.decode(arb_id, dbc_bytes)
    assert not isinstance(ours, cs.DecodeError), ours
    assert cs.decode(arb_id, data) == ours


def test_dbc_layout_matches_codec_for_every_supported_message(db: Any) -> None:
    """Every command the codec supports exists in the DBC with the DLC the codec uses."""
    expected_dlc = {
        cs.HEARTBEAT: 8,
        cs.ESTOP: 0,
        cs.GET_ERROR: 8,
        cs.SET_AXIS_STATE: 8,
        cs.GET_ENCODER_ESTIMATES: 8,
        cs.SET_CONTROLLER_MODE: 8,
        cs.SET_INPUT_POS: 8,
        cs.SET_INPUT_VEL: 8,
        cs.SET_INPUT_TORQUE: 8,
        cs.SET_LIMITS: 8,
        cs.CLEAR_ERRORS: 1,
        cs.GET_TORQUES: 8,
    }
    for cmd, dlc in expected_dlc.items():
        for node in range(8):
            msg = db.get_message_by_frame_id(node << 5 | cmd)
            assert msg.length == dlc, msg.name
    # Set_Input_Pos feed-forward scales as documented
    sip = {s.name: s for s in db.get_message_by_frame_id(cs.SET_INPUT_POS).signals}
    assert sip["Vel_FF"].scale == cs.VEL_FF_SCALE_RPS and sip["Vel_FF"].is_signed
    assert sip["Torque_FF"].scale == cs.TORQUE_FF_SCALE_NM and sip["Torque_FF"].length == 16
    assert sip["Input_Pos"].is_float
    # Get_Torques: two float32, target in the low four bytes, estimate in the high four
    tq = {s.name: s for s in db.get_message_by_frame_id(cs.GET_TORQUES).signals}
    assert (tq["Torque_Target"].start, tq["Torque_Estimate"].start) == (0, 32)
    assert tq["Torque_Target"].is_float and tq["Torque_Estimate"].is_float
    assert tq["Torque_Estimate"].unit == "Nm"
    # Set_Input_Torque: one float32 in the low four bytes (the high four are unused)
    sit = {s.name: s for s in db.get_message_by_frame_id(cs.SET_INPUT_TORQUE).signals}
    assert set(sit) == {"Input_Torque"}
    assert sit["Input_Torque"].start == 0 and sit["Input_Torque"].length == 32
    assert sit["Input_Torque"].is_float and sit["Input_Torque"].unit == "Nm"


def test_enums_match_dbc_value_tables(db: Any) -> None:
    hb = {s.name: s for s in db.get_message_by_frame_id(cs.HEARTBEAT).signals}
    states = {int(k): str(v) for k, v in hb["Axis_State"].choices.items()}
    assert states == {s.value: s.name for s in cs.AxisState}
    errors = {int(k): str(v) for k, v in hb["Axis_Error"].choices.items()}
    assert errors == {e.value: name for name, e in cs.ODriveError.__members__.items()}
    mode = {s.name: s for s in db.get_message_by_frame_id(cs.SET_CONTROLLER_MODE).signals}
    assert {int(k): str(v) for k, v in mode["Control_Mode"].choices.items()} == {
        m.value: m.name for m in cs.ControlMode
    }
    assert {int(k): str(v) for k, v in mode["Input_Mode"].choices.items()} == {
        m.value: m.name for m in cs.InputMode
    }


# --- bad frames: typed errors, never exceptions, never NaN -----------------------------------


@pytest.mark.parametrize("length", [0, 1, 4, 7])
def test_wrong_length_is_a_length_error(length: int) -> None:
    for cmd in (
        cs.HEARTBEAT,
        cs.GET_ENCODER_ESTIMATES,
        cs.GET_ERROR,
        cs.SET_INPUT_POS,
        cs.GET_TORQUES,
    ):
        err = cs.decode(2 << 5 | cmd, bytes(length))
        assert isinstance(err, cs.DecodeError)
        assert err.kind is cs.DecodeErrorKind.LENGTH
        assert err.node_id == 2


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_encoder_values_are_rejected(bad: float) -> None:
    for data in (struct.pack("<ff", bad, 0.0), struct.pack("<ff", 0.0, bad)):
        err = cs.decode(0x029, data)
        assert isinstance(err, cs.DecodeError)
        assert err.kind is cs.DecodeErrorKind.NON_FINITE
    for cmd in (cs.SET_INPUT_VEL, cs.SET_LIMITS, cs.GET_TORQUES):
        assert isinstance(cs.decode(cmd, struct.pack("<ff", bad, 1.0)), cs.DecodeError)
    assert isinstance(cs.decode(cs.SET_INPUT_POS, struct.pack("<fhh", bad, 0, 0)), cs.DecodeError)
    for data in (struct.pack("<f", bad) + bytes(4), struct.pack("<f", bad)):
        err = cs.decode(3 << 5 | cs.SET_INPUT_TORQUE, data)
        assert isinstance(err, cs.DecodeError)
        assert err.kind is cs.DecodeErrorKind.NON_FINITE
        assert err.node_id == 3


def test_set_input_torque_accepts_four_bytes_and_refuses_other_lengths() -> None:
    # Some hosts send only the float (the DBC's DLC is 8): both decode to the same message.
    assert cs.decode(0x04E, struct.pack("<f", 1.5)) == cs.SetInputTorque(2, 1.5)
    assert cs.decode(0x04E, struct.pack("<f", 1.5) + bytes(4)) == cs.SetInputTorque(2, 1.5)
    for length in (0, 3, 5, 7):
        err = cs.decode(0x04E, bytes(length))
        assert isinstance(err, cs.DecodeError)
        assert err.kind is cs.DecodeErrorKind.LENGTH


def test_unknown_command_and_extended_id() -> None:
    err = cs.decode(1 << 5 | 0x14, bytes(8))  # Get_Iq: not supported by this codec
    assert isinstance(err, cs.DecodeError)
    assert err.kind is cs.DecodeErrorKind.UNKNOWN_COMMAND
    err = cs.decode(0x029, bytes(8), is_extended_id=True)
    assert isinstance(err, cs.DecodeError)
    assert err.kind is cs.DecodeErrorKind.EXTENDED_ID
    assert isinstance(cs.decode(0x800, bytes(8)), cs.DecodeError)


@given(st.integers(0, 0x7FF), st.binary(max_size=8), st.booleans())
def test_decode_never_raises_and_never_returns_nan(arb_id: int, data: bytes, remote: bool) -> None:
    m = cs.decode(arb_id, data, remote)
    for value in getattr(m, "__slots__", ()):
        v = getattr(m, value)
        if isinstance(v, float):
            assert math.isfinite(v)


def test_encoders_refuse_unsendable_values() -> None:
    with pytest.raises(ValueError, match="finite"):
        cs.encode_set_input_pos(0, math.nan)
    with pytest.raises(ValueError, match="finite"):
        cs.encode_set_input_pos(0, 1e39)  # beyond float32
    with pytest.raises(ValueError, match="int16"):
        cs.encode_set_input_pos(0, 0.0, vel_ff_rps=32.8)
    with pytest.raises(ValueError, match="finite"):
        cs.encode_set_limits(0, math.inf, 1.0)
    with pytest.raises(ValueError, match="torque_estimate_nm"):
        cs.encode_torques(0, 0.0, math.nan)
    for bad in (math.nan, math.inf, -math.inf, 1e39):
        with pytest.raises(ValueError, match="input_torque_nm"):
            cs.encode_set_input_torque(0, bad)
    with pytest.raises(ValueError, match="node_id"):
        cs.encode_set_input_torque(64, 0.0)
    with pytest.raises(ValueError):
        cs.encode_set_axis_state(0, -1)
    with pytest.raises(ValueError):
        cs.encode_heartbeat(0, 0, 256)


@given(
    st.integers(0, 63),
    st.floats(width=32, allow_nan=False, allow_infinity=False),
    st.floats(-32.768, 32.767),
    st.floats(-32.768, 32.767),
)
def test_set_input_pos_round_trip(node: int, pos: float, vel_ff: float, torque_ff: float) -> None:
    arb_id, data, _ = cs.encode_set_input_pos(node, pos, vel_ff, torque_ff)
    m = cs.decode(arb_id, data)
    assert isinstance(m, cs.SetInputPos)
    assert m.node_id == node
    assert m.input_pos_rev == pos  # float32 values are exact
    assert abs(m.vel_ff_rps - vel_ff) <= 0.0005 + 1e-12
    assert abs(m.torque_ff_nm - torque_ff) <= 0.0005 + 1e-12


def test_error_names() -> None:
    assert cs.error_names(0) == "NONE"
    assert cs.error_names(0x2000020) == "DRV_FAULT|ESTOP_REQUESTED"
    assert cs.error_names(0x80) == "0x80"


def test_pure_decode_throughput() -> None:
    """Pure decode of encoder frames: must be far above a 1 Mbit/s bus (~8,000 frames/s)."""
    frames = [cs.encode_encoder_estimates(n % 4, n * 0.001, 1.0)[:2] for n in range(1000)]
    n_total = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < 0.3:
        for arb_id, data in frames:
            cs.decode(arb_id, data)
        n_total += len(frames)
    rate = n_total / (time.perf_counter() - t0)
    print(f"pure decode: {rate:,.0f} frames/s")
    assert rate > 20_000
