"""CiA 402 profile rules (states, controlwords, EMCY names, interpolation period) and CAN
frame bit counts: pure functions."""

from __future__ import annotations

import math
import random

import pytest

from drivers.cia402 import busload
from drivers.cia402.profile import (
    CW_DISABLE_VOLTAGE,
    CW_ENABLE_OPERATION,
    CW_FAULT_RESET,
    CW_QUICK_STOP,
    CW_SHUTDOWN,
    CW_SWITCH_ON,
    DriveState,
    Goal,
    controlword_for,
    drive_state,
    emcy_text,
    interpolation_period,
)

S = DriveState


@pytest.mark.parametrize(
    ("statusword", "state"),
    [
        (0x0000, S.NOT_READY_TO_SWITCH_ON),
        (0x0240, S.SWITCH_ON_DISABLED),
        (0x0250, S.SWITCH_ON_DISABLED),  # voltage present: still switch on disabled
        (0x0231, S.READY_TO_SWITCH_ON),
        (0x0233, S.SWITCHED_ON),
        (0x1237, S.OPERATION_ENABLED),
        (0x02B7, S.OPERATION_ENABLED),  # warning bit set
        (0x0217, S.QUICK_STOP_ACTIVE),
        (0x021F, S.FAULT_REACTION_ACTIVE),
        (0x0208, S.FAULT),
        (0x0218, S.FAULT),
    ],
)
def test_statusword_names_the_state(statusword: int, state: DriveState) -> None:
    assert drive_state(statusword) is state


def test_statusword_matching_no_state() -> None:
    # bits 0-3 = 0001 with bit 5 clear and bit 6 clear: no CiA 402 state looks like that
    assert drive_state(0x0001) is None


def test_state_names_are_for_people() -> None:
    assert S.OPERATION_ENABLED.value == "Operation enabled"
    assert S.SWITCH_ON_DISABLED.value == "Switch on disabled"
    assert S.QUICK_STOP_ACTIVE.value == "Quick stop active"


def test_arming_steps_one_transition_per_cycle() -> None:
    e = Goal.ENABLED
    assert controlword_for(e, S.SWITCH_ON_DISABLED, False) == CW_SHUTDOWN == 0x06
    assert controlword_for(e, S.READY_TO_SWITCH_ON, False) == CW_SWITCH_ON == 0x07
    assert controlword_for(e, S.SWITCHED_ON, False) == CW_ENABLE_OPERATION == 0x0F
    assert controlword_for(e, S.OPERATION_ENABLED, False) == 0x0F
    # quick stop active is left through switch on disabled; unknown/transient states wait
    assert controlword_for(e, S.QUICK_STOP_ACTIVE, False) == CW_DISABLE_VOLTAGE == 0x00
    assert controlword_for(e, S.NOT_READY_TO_SWITCH_ON, False) == 0x00
    assert controlword_for(e, S.FAULT_REACTION_ACTIVE, True) == 0x00
    assert controlword_for(e, None, False) == 0x00


def test_fault_reset_only_when_asked_so_bit_7_has_an_edge() -> None:
    assert controlword_for(Goal.ENABLED, S.FAULT, True) == CW_FAULT_RESET == 0x80
    assert controlword_for(Goal.ENABLED, S.FAULT, False) == 0x00
    # a fault reset is never sent while disarmed or e-stopped
    assert controlword_for(Goal.DISABLED, S.FAULT, True) == 0x00
    assert controlword_for(Goal.QUICK_STOP, S.FAULT, True) == CW_QUICK_STOP


@pytest.mark.parametrize("state", [*DriveState, None])
def test_disarm_and_estop_are_the_same_word_in_every_state(state: DriveState | None) -> None:
    assert controlword_for(Goal.DISABLED, state, False) == 0x00
    assert controlword_for(Goal.QUICK_STOP, state, False) == CW_QUICK_STOP == 0x02


def test_emcy_text_names_code_and_category() -> None:
    assert emcy_text(0x8611) == "Following error (Monitoring)"
    assert emcy_text(0x2310) == "Continuous over-current (Current)"
    assert emcy_text(0x1000) == "Generic error"
    assert emcy_text(0x4999) == "Temperature"  # unlisted: canopen's category alone
    assert emcy_text(0xFF42) == "Device Specific"


@pytest.mark.parametrize(
    ("period_s", "expected"),
    [
        (0.002, (2, -3)),
        (0.001, (1, -3)),
        (0.004, (4, -3)),
        (0.0005, (5, -4)),
        (0.00025, (25, -5)),
        (0.3, (30, -2)),
        (1 / 1000.0, (1, -3)),
    ],
)
def test_interpolation_period(period_s: float, expected: tuple[int, int]) -> None:
    value, index = interpolation_period(period_s)
    assert (value, index) == expected
    assert value * 10.0**index == pytest.approx(period_s, rel=1e-9)


@pytest.mark.parametrize("period_s", [0.0, -0.001, math.nan, math.inf, 1 / 3, 0.0123456])
def test_interpolation_period_refuses_what_a_drive_cannot_hold(period_s: float) -> None:
    with pytest.raises(ValueError, match="period"):
        interpolation_period(period_s)


# --- bits on the wire -------------------------------------------------------------------------


def test_crc15_check_value() -> None:
    # CRC-15/CAN of the ASCII string "123456789" is 0x059E (the catalogue check value).
    bits = [b for ch in b"123456789" for b in busload._bits(ch, 8)]
    assert busload._crc15(bits) == 0x059E


def test_stuffing_of_an_all_zero_frame() -> None:
    # Identifier 0, no data: 34 dominant bits (CRC of zeros is 0) -> a stuff bit after every 5.
    assert busload.stuff_bits(0x000, b"") == 6
    assert busload.frame_bits(0x000, b"") == 47 + 6


def test_sync_frame_bits() -> None:
    # SYNC 0x080, no data: SOF 0, id 00010000000 -> the seven trailing zeros with RTR, IDE,
    # r0 and DLC 0000 make 12 zeros in a row, then the CRC.
    n = busload.stuff_bits(0x080, b"")
    assert 2 <= n <= busload.worst_case_bits(0) - 47
    assert busload.frame_bits(0x080, b"") == 47 + n


def test_exact_bits_never_exceed_the_worst_case() -> None:
    rng = random.Random(402)
    for _ in range(2000):
        n = rng.randrange(9)
        data = bytes(rng.randrange(256) for _ in range(n))
        arb = rng.randrange(0x800)
        bits = busload.frame_bits(arb, data)
        assert 47 + 8 * n <= bits <= busload.worst_case_bits(n)
    assert busload.worst_case_bits(8) == 47 + 64 + 24
    assert busload.worst_case_bits(0) == 47 + 8


def test_bus_load() -> None:
    assert busload.bus_load(1000, 500.0) == pytest.approx(0.5)
    assert busload.bus_load(1000, 1000.0, 500_000) == pytest.approx(2.0)


def test_frame_bits_refuses_bad_frames() -> None:
    with pytest.raises(ValueError, match="identifier"):
        busload.frame_bits(0x800, b"")
    with pytest.raises(ValueError, match="8 bytes"):
        busload.frame_bits(0x100, bytes(9))
    with pytest.raises(ValueError):
        busload.worst_case_bits(9)
