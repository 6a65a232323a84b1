"""The CiA 402 drive profile as cablebot uses it: states, controlwords, EMCY names. Pure.

The state machine (CiA 402 / IEC 61800-7-201) as read from the statusword (0x6041) and as
driven through the controlword (0x6040). The statusword masks and the controlword command
values are canopen's (`canopen.profiles.p402.State402`); this module names the states the way
people read them and decides, once per SYNC cycle, which controlword moves a drive toward what
the host wants (`controlword_for`). The simulated drive's side of the same state machine lives
in `drivers.cia402.sim`.
"""

from __future__ import annotations

import enum
import math

from canopen.emcy import EmcyError
from canopen.profiles.p402 import OperationMode, State402


class DriveState(enum.Enum):
    """A CiA 402 power drive state; the value is its name as people read it."""

    NOT_READY_TO_SWITCH_ON = "Not ready to switch on"
    SWITCH_ON_DISABLED = "Switch on disabled"
    READY_TO_SWITCH_ON = "Ready to switch on"
    SWITCHED_ON = "Switched on"
    OPERATION_ENABLED = "Operation enabled"
    QUICK_STOP_ACTIVE = "Quick stop active"
    FAULT_REACTION_ACTIVE = "Fault reaction active"
    FAULT = "Fault"


# canopen's statusword masks, keyed by our states (its names are the upper-case ones).
_SW_MASKS: tuple[tuple[int, int, DriveState], ...] = tuple(
    (mask, value, DriveState[name.replace(" ", "_")])
    for name, (mask, value) in State402.SW_MASK.items()
)

CW_DISABLE_VOLTAGE = State402.CW_DISABLE_VOLTAGE
"""0x00: to Switch on disabled from any powered state (cablebot's disarm)."""
CW_SHUTDOWN = State402.CW_SHUTDOWN
"""0x06: Switch on disabled → Ready to switch on."""
CW_SWITCH_ON = State402.CW_SWITCH_ON
"""0x07: Ready to switch on → Switched on."""
CW_ENABLE_OPERATION = State402.CW_OPERATION_ENABLED
"""0x0F: Switched on → Operation enabled (and keeps it there)."""
CW_QUICK_STOP = State402.CW_QUICK_STOP
"""0x02: Operation enabled → Quick stop active (cablebot's e-stop)."""
CW_FAULT_RESET = 0x80
"""Bit 7: a rising edge resets a Fault (to Switch on disabled) once its cause is gone."""

CYCLIC_SYNCHRONOUS_POSITION = OperationMode.CYCLIC_SYNCHRONOUS_POSITION
"""Modes of operation (0x6060) value 8."""

SW_FAULT = 0x0008
"""Statusword bit 3."""
SW_WARNING = 0x0080
"""Statusword bit 7."""


def drive_state(statusword: int) -> DriveState | None:
    """The CiA 402 state a statusword reports, or None if it matches none of them."""
    for mask, value, state in _SW_MASKS:
        if statusword & mask == value:
            return state
    return None


class Goal(enum.Enum):
    """What the host wants of every drive; `controlword_for` turns it into one step."""

    DISABLED = "disabled"
    """Switch on disabled: the power stage off (ODrive IDLE)."""
    ENABLED = "enabled"
    """Operation enabled: following the cyclic set-points (ODrive CLOSED_LOOP_CONTROL)."""
    QUICK_STOP = "quick stop"
    """Quick stop: brake on the drive's quick stop ramp (ODrive Estop)."""


def controlword_for(goal: Goal, state: DriveState | None, fault_reset: bool) -> int:
    """The controlword that moves a drive in `state` one transition toward `goal`.

    Every command is level-triggered (sending it again is harmless) except the fault reset,
    a rising edge of bit 7: it is sent only when `fault_reset` is True (the caller asks for
    one edge per arm), else a faulted drive gets Disable voltage, so bit 7 is low again before
    the next reset. Quick stop active is left through Switch on disabled (transition 12), the
    one way every drive supports. An unknown state (no statusword yet) gets Disable voltage.
    """
    if goal is Goal.DISABLED:
        return CW_DISABLE_VOLTAGE
    if goal is Goal.QUICK_STOP:
        return CW_QUICK_STOP
    if state is DriveState.SWITCH_ON_DISABLED:
        return CW_SHUTDOWN
    if state is DriveState.READY_TO_SWITCH_ON:
        return CW_SWITCH_ON
    if state is DriveState.SWITCHED_ON or state is DriveState.OPERATION_ENABLED:
        return CW_ENABLE_OPERATION
    if state is DriveState.FAULT and fault_reset:
        return CW_FAULT_RESET
    return CW_DISABLE_VOLTAGE


# Error codes of CiA 301 and CiA 402 that servo drives commonly report, with canopen's
# category (EmcyError.get_desc) added to every name. Codes not listed get the category alone.
EMCY_NAMES: dict[int, str] = {
    0x1000: "Generic error",
    0x2310: "Continuous over-current",
    0x2320: "Short circuit / earth leakage",
    0x3210: "DC link over-voltage",
    0x3220: "DC link under-voltage",
    0x4210: "Excess temperature device",
    0x4310: "Excess temperature drive",
    0x5530: "EEPROM / data storage",
    0x6320: "Parameter error",
    0x7121: "Motor blocked",
    0x7300: "Sensor",
    0x7305: "Incremental sensor 1 fault",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "Life guard or heartbeat error",
    0x8140: "Recovered from bus off",
    0x8250: "RPDO timeout",
    0x8611: "Following error",
    0x8612: "Reference limit",
}

NO_EMCY_CODE = 0x1000
"""`axis_error` of a faulted drive that sent no EMCY (Generic error)."""


def emcy_text(code: int) -> str:
    """A readable name of EMCY error code `code`, e.g. "Following error (Monitoring)"."""
    category = EmcyError(code, 0, b"", 0.0).get_desc()
    name = EMCY_NAMES.get(code)
    if name is None:
        return category or "unknown error code"
    return name if name.lower() == category.lower() or not category else f"{name} ({category})"


def interpolation_period(period_s: float) -> tuple[int, int]:
    """Object 0x60C2 for `period_s`: (time period value 1..255, time index), value·10^index s.

    Prefers milliseconds (index -3), then finer units, then coarser ones. Raises ValueError if
    the period is not finite and positive or has no exact representation (to 1 ppm).
    """
    if not (math.isfinite(period_s) and period_s > 0.0):
        raise ValueError(f"loop period must be finite and > 0, got {period_s!r}")
    for index in (-3, -4, -5, -6, -2, -1, 0):
        value = period_s / 10.0**index
        rounded = round(value)
        if 1 <= rounded <= 255 and abs(value - rounded) <= 1e-6 * value:
            return rounded, index
    raise ValueError(
        f"loop period {period_s!r} s has no exact CiA 402 interpolation time period "
        "(value 1..255 times a power of ten)"
    )
