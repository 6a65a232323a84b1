"""Bits on the wire of classic CAN frames, to turn frames per tick into bus load. Pure.

A classic CAN 2.0A data frame with n data bytes is 44 + 8n bits from start-of-frame to the end
of end-of-frame, plus 3 bits of intermission before the next frame can start: 47 + 8n. The
transmitter inserts a stuff bit after five equal bits in a row, from start-of-frame to the
end of the CRC sequence (34 + 8n bits), so the count depends on the frame's identifier and
bytes: `frame_bits` stuffs the real bit stream (with its CRC-15); `worst_case_bits` is the
bound (one stuff bit per four bits after the first five).
"""

from __future__ import annotations

from collections.abc import Iterable

_CRC15_POLY = 0x4599
FIXED_BITS = 47
"""Bits of a standard data frame besides its data, without stuffing (intermission included)."""


def _crc15(bits: Iterable[int]) -> int:
    crc = 0
    for bit in bits:
        crc_next = bit ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if crc_next:
            crc ^= _CRC15_POLY
    return crc


def _bits(value: int, width: int) -> list[int]:
    return [(value >> (width - 1 - i)) & 1 for i in range(width)]


def stuff_bits(arb_id: int, data: bytes) -> int:
    """The number of stuff bits in the standard data frame (`arb_id`, `data`).

    Raises ValueError if the identifier is not 11-bit or there are more than 8 bytes.
    """
    if not 0 <= arb_id <= 0x7FF:
        raise ValueError(f"standard CAN identifier 0..0x7FF expected, got 0x{arb_id:x}")
    if len(data) > 8:
        raise ValueError(f"a classic CAN frame carries at most 8 bytes, got {len(data)}")
    # SOF, identifier, RTR (data frame), IDE (standard), r0, DLC, data
    stream = [0, *_bits(arb_id, 11), 0, 0, 0, *_bits(len(data), 4)]
    for byte in data:
        stream.extend(_bits(byte, 8))
    stream.extend(_bits(_crc15(stream), 15))
    stuffed = 0
    run_bit = -1
    run = 0
    for bit in stream:
        if bit == run_bit:
            run += 1
        else:
            run_bit, run = bit, 1
        if run == 5:
            stuffed += 1
            # The stuff bit is the complement and starts the next run.
            run_bit, run = 1 - bit, 1
    return stuffed


def frame_bits(arb_id: int, data: bytes) -> int:
    """Bit times the standard data frame (`arb_id`, `data`) occupies, stuff bits and the
    3-bit intermission included. Raises ValueError as `stuff_bits`."""
    return FIXED_BITS + 8 * len(data) + stuff_bits(arb_id, data)


def worst_case_bits(n_bytes: int) -> int:
    """The most bit times a standard data frame with `n_bytes` bytes can occupy."""
    if not 0 <= n_bytes <= 8:
        raise ValueError(f"0..8 data bytes expected, got {n_bytes}")
    return FIXED_BITS + 8 * n_bytes + (34 + 8 * n_bytes - 1) // 4


def bus_load(bits_per_tick: float, rate_hz: float, bitrate: float = 1_000_000.0) -> float:
    """The fraction of the bus that `bits_per_tick` bit times every tick at `rate_hz` use."""
    return bits_per_tick * rate_hz / bitrate
