"""The SocketCAN fast path: a python-can SocketCAN bus's kernel socket read and written directly.

python-can opens and configures the bus (`drivers.bus.open_bus`), and stays the only path for
every other interface. Its SocketCAN receive path costs a `select` and a `can.Message` object per
frame, and its send path a `select` and a `send` per frame. `FastSocketCan` uses the same socket:

* receive: `recvmmsg(2)` with `MSG_DONTWAIT` fills a preallocated array of `can_frame`s and
  their ancillary data (the kernel's receive timestamp, SO_TIMESTAMPNS, and the socket's
  cumulative drop count, SO_RXQ_OVFL) in one system call for up to `batch` frames; the caller
  unpacks each frame with a precompiled struct (`frame`). Draining ends when the kernel has no
  more (EAGAIN), never with a `select` per frame.
* send: the tick's frames are packed into a preallocated array and handed to `sendmmsg(2)`: one
  system call per `batch` frames (64 by default; CAN_RAW takes one frame per message, and
  `sendmmsg` is the fewest calls the kernel allows). A full socket buffer is waited for, up to
  the send timeout for the whole call (python-can waits up to it per frame); a full device
  queue (`ENOBUFS`), or a socket buffer still full at the deadline, fails the frames not sent,
  each named, as python-can's send does.
* kernel receive filters (CAN_RAW_FILTER) pass only the ids the driver asks for; error frames
  (CAN_RAW_ERR_FILTER, every class) still arrive; own frames are never echoed back
  (CAN_RAW_RECV_OWN_MSGS off).

Linux only (glibc's or musl's `recvmmsg`/`sendmmsg` through ctypes), classic CAN only (16-byte
`can_frame` slots). `open_fast_path(bus, ...)` returns None for any bus that is not a python-can
SocketCAN bus on an AF_CAN socket, and for one opened for CAN FD (`fd=True`: its socket receives
72-byte `canfd_frame`s, which a slot would cut to their first 8 data bytes), so a caller simply
keeps python-can's path there.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import errno
import math
import os
import select
import socket
import struct
import sys
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Final

if TYPE_CHECKING:
    import can

CAN_EFF_FLAG: Final = 0x80000000
CAN_RTR_FLAG: Final = 0x40000000
CAN_ERR_FLAG: Final = 0x20000000
CAN_SFF_MASK: Final = 0x000007FF
CAN_EFF_MASK: Final = 0x1FFFFFFF
CAN_ERR_MASK: Final = 0x1FFFFFFF

_AF_CAN: Final = 29
_SOL_CAN_RAW: Final = 101  # SOL_CAN_BASE + CAN_RAW
_CAN_RAW_FILTER: Final = 1
_CAN_RAW_ERR_FILTER: Final = 2
_CAN_RAW_RECV_OWN_MSGS: Final = 4
_CAN_RAW_FD_FRAMES: Final = 5
_SOL_SOCKET: Final = socket.SOL_SOCKET
_SO_TIMESTAMPNS: Final = 35  # SO_TIMESTAMPNS_OLD (asm-generic, x86, ARM): a native timespec
_SO_RXQ_OVFL: Final = 40
_SO_MEMINFO: Final = 55
_SK_MEMINFO: Final = struct.Struct("=9I")  # SK_MEMINFO_VARS u32s; the last is SK_MEMINFO_DROPS

#: struct can_frame (linux/can.h): id with flags, length, 3 padding bytes, 8 data bytes.
CAN_FRAME: Final = struct.Struct("=IB3x8s")
FRAME_SIZE: Final = CAN_FRAME.size  # 16 = CAN_MTU
_CAN_FILTER: Final = struct.Struct("=II")

# Ancillary data per received frame: a cmsghdr + timespec (timestamp), then a cmsghdr + u32
# (drop counter). Native layout, so one precompiled struct reads a header and its timespec.
_CMSG_TS: Final = struct.Struct("@Niill")
_CMSG_U32: Final = struct.Struct("@NiiI")
_TS_SPACE: Final = socket.CMSG_SPACE(struct.calcsize("@ll"))
_CTRL_SIZE: Final = _TS_SPACE + socket.CMSG_SPACE(4)

_MSG_DONTWAIT: Final = 0x40

DEFAULT_BATCH: Final = 64
"""Frames one receive call can take (a 4-reel tick at 1 kHz brings 8 to 13)."""


def flagged_id(msg: can.Message) -> int:
    """`msg`'s id as SocketCAN carries it: with the EFF, RTR and ERR flags (python-can's
    `Message` keeps them as attributes). Raises nothing."""
    can_id: int = msg.arbitration_id
    if msg.is_extended_id:
        can_id |= CAN_EFF_FLAG
    if msg.is_remote_frame:
        can_id |= CAN_RTR_FLAG
    if msg.is_error_frame:
        can_id |= CAN_ERR_FLAG
    return can_id


class _IoVec(ctypes.Structure):
    _fields_ = [("iov_base", ctypes.c_void_p), ("iov_len", ctypes.c_size_t)]


class _MsgHdr(ctypes.Structure):
    _fields_ = [
        ("msg_name", ctypes.c_void_p),
        ("msg_namelen", ctypes.c_uint32),
        ("msg_iov", ctypes.c_void_p),
        ("msg_iovlen", ctypes.c_size_t),
        ("msg_control", ctypes.c_void_p),
        ("msg_controllen", ctypes.c_size_t),
        ("msg_flags", ctypes.c_int),
    ]


class _MMsgHdr(ctypes.Structure):
    _fields_ = [("msg_hdr", _MsgHdr), ("msg_len", ctypes.c_uint)]


_MMSG_SIZE: Final = ctypes.sizeof(_MMsgHdr)


class FastPathUnavailable(OSError):
    """This system cannot run the fast path (no Linux libc with recvmmsg/sendmmsg)."""


class FastPathClosed(OSError):
    """The bus's socket was closed (`bus.shutdown()`): the fast path no longer receives or sends
    (its old descriptor number may name another file by now). errno EBADF."""

    def __init__(self) -> None:
        super().__init__(errno.EBADF, "the bus's socket is closed (the bus was shut down)")


def _libc() -> Any:
    """The C library with `recvmmsg` and `sendmmsg` bound; raises FastPathUnavailable."""
    if not sys.platform.startswith("linux"):
        raise FastPathUnavailable("the SocketCAN fast path needs Linux")
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    try:
        recv = libc.recvmmsg
        send = libc.sendmmsg
    except AttributeError as exc:
        raise FastPathUnavailable(f"this C library has no recvmmsg/sendmmsg: {exc}") from exc
    recv.argtypes = [ctypes.c_int, ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_void_p]
    recv.restype = ctypes.c_int
    send.argtypes = [ctypes.c_int, ctypes.c_void_p, ctypes.c_uint, ctypes.c_int]
    send.restype = ctypes.c_int
    return libc


class _MsgArray:
    """`n` message headers, each with one iovec on a `can_frame` slot and `ctrl` control bytes,
    all in preallocated memory; `template` restores the headers the kernel rewrote."""

    def __init__(self, n: int, ctrl: int) -> None:
        self.frames = (ctypes.c_ubyte * (n * FRAME_SIZE))()
        self.view = memoryview(self.frames).cast("B")
        self.control = (ctypes.c_ubyte * max(1, n * ctrl))()
        self.control_view = memoryview(self.control).cast("B")
        self.iov = (_IoVec * n)()
        self.msgs = (_MMsgHdr * n)()
        base = ctypes.addressof(self.frames)
        cbase = ctypes.addressof(self.control)
        for i in range(n):
            self.iov[i].iov_base = base + i * FRAME_SIZE
            self.iov[i].iov_len = FRAME_SIZE
            hdr = self.msgs[i].msg_hdr
            hdr.msg_iov = ctypes.addressof(self.iov[i])
            hdr.msg_iovlen = 1
            if ctrl:
                hdr.msg_control = cbase + i * ctrl
                hdr.msg_controllen = ctrl
        self.template = (_MMsgHdr * n)()
        ctypes.memmove(self.template, self.msgs, ctypes.sizeof(self.msgs))
        self.address = ctypes.addressof(self.msgs)


def can_filters_for(ids_and_masks: Sequence[tuple[int, int]]) -> bytes:
    """Pack standard-id data-frame filters: each (id, mask) passes 11-bit data frames whose id
    matches `id` under `mask` (extended and remote frames never match). Raises ValueError on an
    id or mask outside 11 bits."""
    out = bytearray()
    for can_id, mask in ids_and_masks:
        if not (0 <= can_id <= CAN_SFF_MASK and 0 <= mask <= CAN_SFF_MASK):
            raise ValueError(f"filter id 0x{can_id:x} / mask 0x{mask:x} is not an 11-bit value")
        out += _CAN_FILTER.pack(can_id, mask | CAN_EFF_FLAG | CAN_RTR_FLAG)
    return bytes(out)


def configure_can_socket(sock: socket.socket, filters: Sequence[tuple[int, int]] | None) -> None:
    """Set the kernel receive filters of a SocketCAN raw socket: `filters` are (id, mask) pairs
    of the standard data frames to receive (None = every frame; empty = no data frame at all);
    error frames of every class pass; own frames are never echoed back. Raises ValueError on a
    bad filter, OSError if the socket refuses an option."""
    packed = None if filters is None else can_filters_for(filters)
    sock.setsockopt(_SOL_CAN_RAW, _CAN_RAW_RECV_OWN_MSGS, 0)
    sock.setsockopt(_SOL_CAN_RAW, _CAN_RAW_ERR_FILTER, struct.pack("=I", CAN_ERR_MASK))
    if packed is not None:
        sock.setsockopt(_SOL_CAN_RAW, _CAN_RAW_FILTER, packed)


class FastSocketCan:
    """Direct receive and send on a python-can SocketCAN bus's kernel socket.

    Not thread-safe: one thread (the control loop) calls every method. The python-can bus keeps
    owning the socket (open and shut it down through python-can); once it is closed every
    receive and send raises `FastPathClosed`.
    """

    def __init__(
        self,
        sock: socket.socket,
        *,
        batch: int = DEFAULT_BATCH,
        send_timeout_s: float = 0.005,
    ) -> None:
        """Switch on `sock`'s receive timestamps and drop counter and allocate the buffers.

        `sock` is a datagram socket carrying one `can_frame` per datagram: a SocketCAN raw
        socket configured by `configure_can_socket` (any other, e.g. an AF_UNIX socket pair,
        serves tests). Raises FastPathUnavailable if the C library lacks recvmmsg/sendmmsg,
        ValueError on a bad batch, OSError if the socket refuses an option.
        """
        if batch <= 0:
            raise ValueError("batch must be > 0")
        self._libc = _libc()
        self._recvmmsg = self._libc.recvmmsg
        self._sendmmsg = self._libc.sendmmsg
        self._sock = sock
        self._fd = sock.fileno()
        self._send_timeout_s = send_timeout_s
        self._send_deadline_s: float | None = None
        # poll, not select: any descriptor number (select refuses those >= 1024).
        self._room = select.poll()
        self._room.register(self._fd, select.POLLOUT)
        self._pending = select.poll()
        self._pending.register(self._fd, select.POLLIN)
        sock.setsockopt(_SOL_SOCKET, _SO_TIMESTAMPNS, 1)
        with contextlib.suppress(OSError):  # not every socket family counts drops
            sock.setsockopt(_SOL_SOCKET, _SO_RXQ_OVFL, 1)
        self.batch = batch
        self._rx = _MsgArray(batch, _CTRL_SIZE)
        self._tx = _MsgArray(batch, 0)
        self._rx_ctrl_bytes = batch * _CTRL_SIZE
        self._drops_seen = _socket_drops(sock)
        self.kernel_drops = 0
        """Frames the kernel dropped because this socket's receive queue was full since this
        fast path was set up (total)."""
        self.send_calls = 0
        """System calls made to send (for the benchmark)."""
        self.recv_calls = 0
        """System calls made to receive (for the benchmark)."""

    # --- receive ----------------------------------------------------------------------------

    def recv_batch(self, max_frames: int) -> int:
        """Take up to min(`max_frames`, `batch`) pending frames off the socket in one system call,
        without waiting; return how many (0 = none pending). Read them with `frame(i)`.

        Raises FastPathClosed once the socket is closed, OSError for a receive error other than
        "nothing pending" (e.g. ENETDOWN).
        """
        if self._sock.fileno() != self._fd:
            raise FastPathClosed
        n = self.batch if max_frames > self.batch else max_frames
        if n <= 0:
            return 0
        rx = self._rx
        ctypes.memset(rx.control, 0, self._rx_ctrl_bytes)
        ctypes.memmove(rx.msgs, rx.template, n * _MMSG_SIZE)
        self.recv_calls += 1
        got: int = self._recvmmsg(self._fd, rx.address, n, _MSG_DONTWAIT, None)
        if got < 0:
            err = ctypes.get_errno()
            if err in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EINTR):
                return 0
            raise OSError(err, os.strerror(err))
        if got:
            # The drop counter is cumulative: the last frame of the batch carries the newest.
            kind_off = (got - 1) * _CTRL_SIZE + _TS_SPACE
            _len, level, ctype, drops = _CMSG_U32.unpack_from(rx.control_view, kind_off)
            if level == _SOL_SOCKET and ctype == _SO_RXQ_OVFL and drops != self._drops_seen:
                self._count_drops(drops)
        return got

    def wait_readable(self, timeout_s: float) -> bool:
        """Wait up to `timeout_s` (rounded up to whole milliseconds; 0 = do not wait) for a
        frame to receive; True if one is pending (or the socket has an error to report), for a
        serving loop that sleeps between frames. Raises FastPathClosed once the socket is
        closed."""
        if self._sock.fileno() != self._fd:
            raise FastPathClosed
        wait_ms = math.ceil(timeout_s * 1000.0) if timeout_s > 0.0 else 0
        return bool(self._pending.poll(wait_ms))

    def _count_drops(self, drops: int) -> None:
        """Take the socket's cumulative drop count `drops` (a u32 that wraps) into
        `kernel_drops`. Frames queued before the last count seen carry older (smaller) counts:
        the signed 32-bit difference ignores them. Without a starting count (SO_MEMINFO
        refused) the first count seen is the start. Raises nothing."""
        seen = self._drops_seen
        if seen is None:
            self._drops_seen = drops
            return
        delta = ((drops - seen + 0x80000000) & 0xFFFFFFFF) - 0x80000000
        if delta > 0:
            self.kernel_drops += delta
            self._drops_seen = drops

    def frame(self, i: int) -> tuple[int, int, bytes, float]:
        """Frame `i` of the last `recv_batch`: (can_id with the EFF/RTR/ERR flags, length,
        8 data bytes (use the first `length`), kernel receive time in wall-clock seconds, 0.0 if
        the kernel gave none). Raises nothing for i < the batch size."""
        can_id, length, data = CAN_FRAME.unpack_from(self._rx.view, i * FRAME_SIZE)
        _l, level, ctype, sec, nsec = _CMSG_TS.unpack_from(self._rx.control_view, i * _CTRL_SIZE)
        stamp = sec + nsec * 1e-9 if ctype == _SO_TIMESTAMPNS and level == _SOL_SOCKET else 0.0
        return can_id, length, data, stamp

    # --- send -------------------------------------------------------------------------------

    def send_frames(
        self, frames: Sequence[tuple[int, bytes, bool]]
    ) -> list[tuple[int, OSError]] | None:
        """Send standard-id `frames` ((id, data, is_remote), in order) with as few system calls
        as the kernel allows (one `sendmmsg` per `batch` frames when all goes well).

        Returns None when every frame went out, else (index, error) for each frame that did not
        (the others were still tried): ENOBUFS when the interface's queue is full, "transmit
        buffer full" (EAGAIN) when the socket buffer had no room before the call's deadline (the
        send timeout after its first wait for room; after it, a frame finding no room fails at
        once). Raises ValueError (sending nothing) on an id outside 11 bits or data over 8 bytes,
        FastPathClosed (sending nothing) once the socket is closed.
        """
        if self._sock.fileno() != self._fd:
            raise FastPathClosed
        self._send_deadline_s = None
        failures: list[tuple[int, OSError]] | None = None
        for start in range(0, len(frames), self.batch):
            chunk = frames[start : start + self.batch]
            failed = self._send_chunk(chunk)
            if failed:
                if failures is None:
                    failures = []
                failures.extend((start + i, e) for i, e in failed)
        return failures

    def _send_chunk(self, frames: Sequence[tuple[int, bytes, bool]]) -> list[tuple[int, OSError]]:
        tx = self._tx
        view = tx.view
        pack = CAN_FRAME.pack_into
        for i, (arb_id, data, is_remote) in enumerate(frames):
            if not 0 <= arb_id <= CAN_SFF_MASK or len(data) > 8:
                raise ValueError(f"not a standard CAN frame: id 0x{arb_id:x}, {len(data)} bytes")
            if is_remote:
                pack(view, i * FRAME_SIZE, arb_id | CAN_RTR_FLAG, 8, b"")
            else:
                pack(view, i * FRAME_SIZE, arb_id, len(data), data)
        n = len(frames)
        failed: list[tuple[int, OSError]] = []
        i = 0
        while i < n:
            self.send_calls += 1
            sent: int = self._sendmmsg(self._fd, tx.address + i * _MMSG_SIZE, n - i, _MSG_DONTWAIT)
            if sent > 0:
                i += sent
                continue
            err = ctypes.get_errno() if sent < 0 else errno.EIO
            if err == errno.EINTR:
                continue
            full = err in (errno.EAGAIN, errno.EWOULDBLOCK)
            if full and self._wait_for_room():
                continue
            failed.append((i, OSError(err, "Transmit buffer full" if full else os.strerror(err))))
            i += 1
        return failed

    def _wait_for_room(self) -> bool:
        """Wait for room in the socket's send buffer until the `send_frames` call's deadline
        (its first wait sets it, `send_timeout_s` ahead). True if there is room (or the socket
        has an error to report), False once the deadline has passed. Raises nothing."""
        now_s = time.monotonic()
        deadline_s = self._send_deadline_s
        if deadline_s is None:
            deadline_s = self._send_deadline_s = now_s + self._send_timeout_s
        left_s = deadline_s - now_s
        if left_s <= 0.0:
            return False
        return bool(self._room.poll(math.ceil(left_s * 1000.0)))


def _socket_drops(sock: socket.socket) -> int | None:
    """The frames `sock`'s receive queue has dropped so far (SO_MEMINFO's SK_MEMINFO_DROPS, the
    counter SO_RXQ_OVFL reports), or None if the socket does not tell. Raises nothing."""
    try:
        raw = sock.getsockopt(_SOL_SOCKET, _SO_MEMINFO, _SK_MEMINFO.size)
    except OSError:
        return None
    if len(raw) < _SK_MEMINFO.size:
        return None
    drops: int = _SK_MEMINFO.unpack_from(raw)[-1]
    return drops


def socket_of(bus: object) -> socket.socket | None:
    """The AF_CAN raw socket of a python-can SocketCAN bus, or None for any other bus."""
    if type(bus).__name__ != "SocketcanBus":
        return None
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket) or sock.family != _AF_CAN:
        return None
    return sock


def _receives_fd_frames(sock: socket.socket) -> bool:
    """True if `sock` (a SocketCAN raw socket) has CAN FD frames switched on. Raises nothing."""
    try:
        return bool(sock.getsockopt(_SOL_CAN_RAW, _CAN_RAW_FD_FRAMES))
    except OSError:  # a kernel without CAN FD: classic frames only
        return False


def open_fast_path(
    bus: object,
    filters: Sequence[tuple[int, int]] | None,
    *,
    fast_path: bool | FastSocketCan = True,
    send_timeout_s: float = 0.005,
) -> FastSocketCan | None:
    """The fast path a driver asked for with `fast_path` (its constructor's argument): a
    `FastSocketCan` given is used as it is (tests, the benchmark); False is None (python-can's
    path); True is a `FastSocketCan` on `bus`'s socket with kernel `filters` (see
    `FastSocketCan`), or None when `bus` is not a python-can SocketCAN bus, receives CAN FD
    frames, or this system cannot run the fast path (the caller then keeps python-can's path).
    Raises ValueError on a bad filter, OSError if the socket refuses an option."""
    if isinstance(fast_path, FastSocketCan):
        return fast_path
    if not fast_path:
        return None
    sock = socket_of(bus)
    if sock is None or _receives_fd_frames(sock):
        return None
    try:
        fast = FastSocketCan(sock, send_timeout_s=send_timeout_s)
    except FastPathUnavailable:
        return None
    configure_can_socket(sock, filters)
    return fast
