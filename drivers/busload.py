"""The bus load a configuration implies: the frames of one tick, their bits, the share of the bus.

Pure. Each drive family's tick is a list of frames (`tick_frames`); the bits of a frame come
from `drivers.cia402.busload` (47 + 8 x data bytes from start-of-frame to the intermission, plus
stuff bits). The stuff bits depend on the frame's bits: `typical` counts half the worst case
(four simulated CiA 402 drives measured 1317 bits per tick, this gives 1311; none gives 1187,
the worst case 1435), `worst` the bound. The load is `bits per tick x rate / bitrate`; a real
bus is refused a rate at which a tick's worst case does not fit in its period.

What a tick carries, per axis:

* ODrive (CANSimple): Set_Input_Pos (8 bytes) out; Get_Encoder_Estimates (8 bytes) back, once
  per tick (the drive's encoder broadcast at the loop rate, or the RTR poll's answer); with
  `loop.encoder_rtr` the RTR request (0 bytes); with torque telemetry Get_Torques (8 bytes)
  broadcast at the loop rate, or every `torque_rtr_period_s` with its RTR request.
* CiA 402: RPDO1 (controlword + target position, 6 bytes), RPDO2 (velocity offset, 4 bytes;
  `velocity_offset`), TPDO1 (statusword + position, 6 bytes, + torque 2 bytes with `torque`);
  one SYNC (0 bytes) per tick for the bus.

Heartbeats (a few per second) add well under 1 % and are left out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from drivers.cia402.busload import FIXED_BITS, worst_case_bits

DEFAULT_BITRATE = 1_000_000
"""The bit rate assumed when the configuration gives none (SocketCAN's is set by `ip link`)."""
MAX_PERCENT = 100.0
"""A configuration whose worst-case load is above this is refused: the bus cannot carry it."""
SIMULATED_INTERFACES = frozenset({"virtual", "udp_multicast"})
"""Buses without bit times: their load is stated (at the assumed bit rate), never refused."""


@dataclass(frozen=True, slots=True)
class TickFrame:
    """One kind of frame of a tick: `count` frames per tick (may be a fraction), `n_bytes` each."""

    name: str
    n_bytes: int
    count: float


@dataclass(frozen=True, slots=True)
class BusLoad:
    """The load of one bus at the configured rate."""

    frames: tuple[TickFrame, ...]
    rate_hz: float
    bitrate: int
    bitrate_assumed: bool
    """True when the configuration gave no bit rate and `DEFAULT_BITRATE` was used."""
    enforced: bool
    """False for a simulated bus (no bit times): the load is stated, never refused."""

    @property
    def frames_per_tick(self) -> float:
        """Frames on the bus per tick."""
        return sum(f.count for f in self.frames)

    @property
    def bits_per_tick(self) -> float:
        """Typical bit times per tick (stuff bits: half the worst case)."""
        return sum(f.count * typical_bits(f.n_bytes) for f in self.frames)

    @property
    def worst_bits_per_tick(self) -> float:
        """The most bit times a tick can take (every possible stuff bit)."""
        return sum(f.count * worst_case_bits(f.n_bytes) for f in self.frames)

    @property
    def percent(self) -> float:
        """Typical share of the bus, in percent of the bit rate."""
        return 100.0 * self.bits_per_tick * self.rate_hz / self.bitrate

    @property
    def worst_percent(self) -> float:
        """Worst-case share of the bus, in percent."""
        return 100.0 * self.worst_bits_per_tick * self.rate_hz / self.bitrate

    def refusal(self) -> str | None:
        """Why the bus cannot carry this rate, or None: on a real bus, a tick's frames with
        every possible stuff bit must fit in its period (worst case at most `MAX_PERCENT`)."""
        if not self.enforced or self.worst_percent <= MAX_PERCENT:
            return None
        fits_hz = MAX_PERCENT / 100.0 * self.bitrate / self.worst_bits_per_tick
        return (
            f"{self.rate_hz:g} Hz needs {self.percent:.0f} % of the {self.bitrate} bit/s bus, "
            f"{self.worst_percent:.0f} % in the worst case ({self.frames_per_tick:g} frames, "
            f"{self.bits_per_tick:.0f} bits per tick, {self.worst_bits_per_tick:.0f} with every "
            f"stuff bit): it cannot carry it; at most {math.floor(fits_hz):d} Hz fits, or split "
            "the drives over two buses"
        )

    def as_dict(self) -> dict[str, Any]:
        """JSON-able: percent, worst_percent, frames and bits per tick, the rate and bit rate."""
        return {
            "percent": round(self.percent, 1),
            "worst_percent": round(self.worst_percent, 1),
            "frames_per_tick": self.frames_per_tick,
            "bits_per_tick": round(self.bits_per_tick, 1),
            "worst_bits_per_tick": round(self.worst_bits_per_tick, 1),
            "rate_hz": self.rate_hz,
            "bitrate": self.bitrate,
            "bitrate_assumed": self.bitrate_assumed,
            "enforced": self.enforced,
            "frames": [
                {"name": f.name, "bytes": f.n_bytes, "per_tick": f.count} for f in self.frames
            ],
        }

    def describe(self) -> str:
        """One line for people: frames, bits with stuffing, percent of the bit rate."""
        rate = f"{self.bitrate} bit/s" + (" (assumed)" if self.bitrate_assumed else "")
        text = (
            f"{self.frames_per_tick:g} frames and {self.bits_per_tick:.0f} bits per tick "
            f"(worst {self.worst_bits_per_tick:.0f} with stuffing) at {self.rate_hz:g} Hz: "
            f"{self.percent:.0f} % of {rate} (worst {self.worst_percent:.0f} %)"
        )
        return text if self.enforced else text + ", a simulated bus: not limited"


def typical_bits(n_bytes: int) -> float:
    """Bit times of a standard frame with `n_bytes` data bytes, half the possible stuff bits.
    Raises ValueError outside 0..8 bytes."""
    worst = worst_case_bits(n_bytes)
    return FIXED_BITS + 8 * n_bytes + (worst - FIXED_BITS - 8 * n_bytes) / 2.0


def tick_frames(
    kind: str,
    n_axes: int,
    options: Mapping[str, Any],
    *,
    rate_hz: float,
    encoder_rtr: bool = False,
    torque_telemetry: str = "off",
    torque_rtr_period_s: float = 0.01,
) -> tuple[TickFrame, ...]:
    """The frames one tick of `n_axes` drives of family `kind` puts on the bus (module
    docstring), with the family's `[drive]` options. Raises ValueError for an unknown family."""
    n = float(n_axes)
    if kind == "odrive":
        frames = [TickFrame("Set_Input_Pos", 8, n), TickFrame("Get_Encoder_Estimates", 8, n)]
        if encoder_rtr:
            frames.append(TickFrame("encoder RTR", 0, n))
        if torque_telemetry == "broadcast":
            frames.append(TickFrame("Get_Torques", 8, n))
        elif torque_telemetry == "rtr":
            per_tick = min(1.0, 1.0 / (rate_hz * torque_rtr_period_s))
            frames += [TickFrame("torque RTR", 0, n * per_tick)]
            frames += [TickFrame("Get_Torques", 8, n * per_tick)]
        return tuple(frames)
    if kind == "cia402":
        frames = [TickFrame("SYNC", 0, 1.0), TickFrame("RPDO1", 6, n)]
        if options.get("velocity_offset", True):
            frames.append(TickFrame("RPDO2", 4, n))
        frames.append(TickFrame("TPDO1", 8 if options.get("torque", True) else 6, n))
        return tuple(frames)
    raise ValueError(f"no bus-load rule for drive family {kind!r}")


def estimate(
    kind: str,
    n_axes: int,
    options: Mapping[str, Any],
    *,
    rate_hz: float,
    interface: str,
    bitrate: int | None,
    encoder_rtr: bool = False,
    torque_telemetry: str = "off",
    torque_rtr_period_s: float = 0.01,
) -> BusLoad:
    """The `BusLoad` of a configuration (see `tick_frames`); `bitrate` None = the default.
    Raises ValueError for an unknown family."""
    frames = tick_frames(
        kind,
        n_axes,
        options,
        rate_hz=rate_hz,
        encoder_rtr=encoder_rtr,
        torque_telemetry=torque_telemetry,
        torque_rtr_period_s=torque_rtr_period_s,
    )
    return BusLoad(
        frames=frames,
        rate_hz=float(rate_hz),
        bitrate=DEFAULT_BITRATE if bitrate is None else int(bitrate),
        bitrate_assumed=bitrate is None,
        enforced=interface not in SIMULATED_INTERFACES,
    )


def for_config(drive: Any, n_axes: int, loop: Any, bus: Any) -> BusLoad:
    """The `BusLoad` of a robot configuration's `[drive]`, `[loop]` and `[bus]` sections
    (`controller.service.config`'s DriveConfig, LoopConfig, BusConfig) with `n_axes` reels.
    Raises ValueError for an unknown family."""
    return estimate(
        drive.kind,
        n_axes,
        drive.options,
        rate_hz=float(loop.rate_hz),
        interface=bus.interface,
        bitrate=bus.bitrate,
        encoder_rtr=bool(loop.encoder_rtr),
        torque_telemetry=loop.torque_telemetry,
        torque_rtr_period_s=float(loop.torque_rtr_period_s),
    )
