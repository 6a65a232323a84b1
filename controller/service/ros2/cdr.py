"""CDR (XCDR1, the ROS 2 default) encode/decode of the few messages cablebot speaks. Pure.

A payload is the 4-byte encapsulation header (`00 01 00 00`: plain CDR, little-endian) and the
message, each primitive aligned to its size counted from the end of the header; a string is a
uint32 length that counts its terminating NUL, the bytes and the NUL; a sequence is a uint32
count and its elements. Encoders are precomputed per frame and joint names (one struct.pack
per message); they are checked byte for byte against rosbags' serializer in the tests.

Decoders take what a ROS 2 node sends (little- or big-endian CDR), bounded in size, and raise
CdrError (a ValueError with a reason fit to log) for anything malformed: wrong header, short or
oversized payload, bad string, non-finite number.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

CDR_LE = b"\x00\x01\x00\x00"
CDR_BE = b"\x00\x00\x00\x00"
MAX_STRING_BYTES = 256
"""The longest frame_id (bytes, without the NUL) a received message may carry."""
MAX_POSE_STAMPED_BYTES = 4 + 12 + MAX_STRING_BYTES + 1 + 7 + 56
TWIST_BYTES = 4 + 48
_MAX_TRAILING = 3  # alignment padding a writer may leave at the end
_IDENTITY_QUAT = (0.0, 0.0, 0.0, 1.0)
_NS_PER_S = 1_000_000_000


class CdrError(ValueError):
    """A CDR payload this module refuses: malformed, truncated, oversized or not finite."""


def _pad(offset: int, align: int) -> int:
    return (-offset) % align


def _string_fmt(offset: int, text: str) -> tuple[str, int, bytes]:
    """(struct format, new offset, encoded bytes with NUL) of a CDR string at `offset`."""
    raw = text.encode("utf-8") + b"\x00"
    pad = _pad(offset, 4)
    fmt = f"{pad}xI{len(raw)}s" if pad else f"I{len(raw)}s"
    return fmt, offset + pad + 4 + len(raw), raw


def split_stamp(stamp_ns: int) -> tuple[int, int]:
    """builtin_interfaces/Time (sec, nanosec) of a wall-clock stamp in nanoseconds."""
    sec, nanosec = divmod(int(stamp_ns), _NS_PER_S)
    return sec, nanosec


# --------------------------------------------------------------------------------------------
# Encoders


class PoseStampedEncoder:
    """geometry_msgs/msg/PoseStamped in `frame_id` with the identity orientation (the robot is
    a point: it has a position, no attitude)."""

    def __init__(self, frame_id: str) -> None:
        sfmt, off, self._frame = _string_fmt(8, frame_id)
        pad = _pad(off, 8)
        self._struct = struct.Struct(f"<4siI{sfmt}{pad}x7d" if pad else f"<4siI{sfmt}7d")
        self._len = len(self._frame)

    def encode(self, stamp_ns: int, position_m: Sequence[float]) -> bytes:
        """The payload for a pose at `position_m` stamped `stamp_ns` (wall clock). Raises
        CdrError if a coordinate is not finite (never published), struct.error if the stamp
        does not fit builtin_interfaces/Time."""
        x, y, z = position_m
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            raise CdrError("position_m is not finite")
        sec, nanosec = divmod(stamp_ns, _NS_PER_S)
        return self._struct.pack(
            CDR_LE, sec, nanosec, self._len, self._frame, x, y, z, *_IDENTITY_QUAT
        )


class JointStateEncoder:
    """sensor_msgs/msg/JointState in `frame_id` for the joints `names` (one per cable):
    position (m), velocity (m/s) and effort (N), each either one value per joint or empty."""

    def __init__(self, frame_id: str, names: Sequence[str]) -> None:
        self._n = len(names)
        sfmt, off, frame = _string_fmt(8, frame_id)
        fmt = f"<4siI{sfmt}"
        fixed: list[object] = [len(frame), frame]
        pad = _pad(off, 4)
        fmt += f"{pad}xI" if pad else "I"
        off += pad + 4
        fixed.append(self._n)
        for name in names:
            nfmt, off, raw = _string_fmt(off, name)
            fmt += nfmt
            fixed += [len(raw), raw]
        self._fixed = tuple(fixed)
        self._head_fmt = fmt
        self._head_off = off
        self._structs: dict[tuple[bool, bool, bool], struct.Struct] = {}

    def _struct(self, key: tuple[bool, bool, bool]) -> struct.Struct:
        s = self._structs.get(key)
        if s is None:
            fmt, off = self._head_fmt, self._head_off
            for present in key:
                pad = _pad(off, 4)
                fmt += f"{pad}xI" if pad else "I"
                off += pad + 4
                if present and self._n:
                    pad = _pad(off, 8)
                    fmt += f"{pad}x{self._n}d" if pad else f"{self._n}d"
                    off += pad + 8 * self._n
            s = self._structs[key] = struct.Struct(fmt)
        return s

    def encode(
        self,
        stamp_ns: int,
        position: Sequence[float],
        velocity: Sequence[float] | None = None,
        effort: Sequence[float] | None = None,
    ) -> bytes:
        """The payload; `velocity` and `effort` may be None (sent empty). Raises CdrError for a
        present array whose length is not one per joint or with a non-finite value."""
        arrays = (position, velocity, effort)
        values: list[object] = []
        for arr in arrays:
            if arr is None:
                values.append(0)
                continue
            if len(arr) != self._n:
                raise CdrError(f"{len(arr)} values for {self._n} joints")
            if not all(map(math.isfinite, arr)):
                raise CdrError("a joint value is not finite")
            values.append(self._n)
            values.extend(arr)
        s = self._struct((True, velocity is not None, effort is not None))
        sec, nanosec = divmod(stamp_ns, _NS_PER_S)
        return s.pack(CDR_LE, sec, nanosec, *self._fixed, *values)


def encode_string(text: str) -> bytes:
    """std_msgs/msg/String carrying `text`."""
    sfmt, _, raw = _string_fmt(0, text)
    return struct.pack(f"<4s{sfmt}", CDR_LE, len(raw), raw)


# --------------------------------------------------------------------------------------------
# Decoders


@dataclass(frozen=True, slots=True)
class PoseStampedMsg:
    """A received geometry_msgs/msg/PoseStamped (finite numbers only)."""

    sec: int
    nanosec: int
    frame_id: str
    position_m: tuple[float, float, float]
    orientation: tuple[float, float, float, float]


@dataclass(frozen=True, slots=True)
class TwistMsg:
    """A received geometry_msgs/msg/Twist (finite numbers only)."""

    linear: tuple[float, float, float]
    angular: tuple[float, float, float]


def _endian(data: bytes, max_bytes: int) -> str:
    if len(data) > max_bytes:
        raise CdrError(f"payload of {len(data)} bytes, at most {max_bytes}")
    if len(data) < 4:
        raise CdrError(f"payload of {len(data)} bytes is shorter than the CDR header")
    head = data[:2]
    if head == CDR_LE[:2]:
        return "<"
    if head == CDR_BE[:2]:
        return ">"
    raise CdrError(f"not plain CDR: encapsulation {data[:4].hex()} (expected 00010000)")


def _finite(values: tuple[float, ...], what: str) -> None:
    for v in values:
        if not math.isfinite(v):
            raise CdrError(f"{what} is not finite: {v!r}")


def _end(data: bytes, off: int) -> None:
    extra = len(data) - 4 - off
    if extra > _MAX_TRAILING:
        raise CdrError(f"{extra} bytes after the message")


def decode_pose_stamped(data: bytes) -> PoseStampedMsg:
    """Decode a geometry_msgs/msg/PoseStamped payload. Raises CdrError if it is malformed,
    truncated, longer than MAX_POSE_STAMPED_BYTES, its frame_id is not UTF-8 or longer than
    MAX_STRING_BYTES, or a number is not finite."""
    e = _endian(data, MAX_POSE_STAMPED_BYTES)
    body = memoryview(data)[4:]
    try:
        sec, nanosec, n = struct.unpack_from(f"{e}iII", body, 0)
        if not 1 <= n <= MAX_STRING_BYTES + 1:
            raise CdrError(f"frame_id length {n} (at most {MAX_STRING_BYTES} bytes and a NUL)")
        raw = bytes(body[12 : 12 + n])
        if len(raw) != n or raw[-1] != 0:
            raise CdrError("frame_id is truncated or not NUL-terminated")
        off = 12 + n
        off += _pad(off, 8)
        values = struct.unpack_from(f"{e}7d", body, off)
    except struct.error as exc:
        raise CdrError(f"truncated PoseStamped ({len(data)} bytes): {exc}") from None
    _end(data, off + 56)
    try:
        frame_id = raw[:-1].decode("utf-8")
    except UnicodeDecodeError:
        raise CdrError("frame_id is not UTF-8") from None
    if "\x00" in frame_id:
        raise CdrError("frame_id contains a NUL")
    _finite(values, "pose")
    pos = (values[0], values[1], values[2])
    quat = (values[3], values[4], values[5], values[6])
    return PoseStampedMsg(sec, nanosec, frame_id, pos, quat)


def decode_twist(data: bytes) -> TwistMsg:
    """Decode a geometry_msgs/msg/Twist payload. Raises CdrError if it is malformed, not
    exactly six float64 (give or take end padding), or a number is not finite."""
    e = _endian(data, TWIST_BYTES + _MAX_TRAILING)
    try:
        values = struct.unpack_from(f"{e}6d", data, 4)
    except struct.error as exc:
        raise CdrError(f"truncated Twist ({len(data)} bytes): {exc}") from None
    _finite(values, "twist")
    return TwistMsg((values[0], values[1], values[2]), (values[3], values[4], values[5]))
