"""The SocketCAN fast path's batching, frame layout and error reporting, on the host.

The host has no AF_CAN: an AF_UNIX datagram socket pair carries the same 16-byte `can_frame`
datagrams through the same `recvmmsg`/`sendmmsg` calls (the kernel filters, error frames from a
real interface and the daemon run in the vcan suite, tests/drivers/test_socketcan_fast_vcan.py).
"""

from __future__ import annotations

import ctypes
import errno
import socket
import time
from collections.abc import Iterator
from typing import Any

import can
import pytest

from drivers import socketcan_fast as sf
from drivers.base import BusError
from drivers.odrive import cansimple as cs
from drivers.odrive.driver import ODriveReels


@pytest.fixture
def pair() -> Iterator[tuple[socket.socket, socket.socket]]:
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    yield a, b
    a.close()
    b.close()


def _raw(can_id: int, data: bytes) -> bytes:
    return sf.CAN_FRAME.pack(can_id, len(data), data)


def test_can_frame_layout_golden_bytes() -> None:
    """struct can_frame: little-endian id with flags, length, 3 pad bytes, 8 data bytes."""
    assert sf.FRAME_SIZE == 16
    assert _raw(0x123 | sf.CAN_RTR_FLAG, b"\x01\x02") == bytes.fromhex(
        "23010040020000000102000000000000"
    )


def test_filters_pack_standard_data_frames_only() -> None:
    """Each filter matches 11-bit data frames: the mask also covers the EFF and RTR flags."""
    assert sf.can_filters_for([(0x20, 0x7E0)]) == bytes.fromhex("20000000e00700c0")
    with pytest.raises(ValueError, match="11-bit"):
        sf.can_filters_for([(0x800, 0x7FF)])


def test_recv_batch_takes_every_pending_frame_in_few_calls(
    pair: tuple[socket.socket, socket.socket],
) -> None:
    """100 pending frames come out intact, in order, stamped by the kernel, in 2 calls of up
    to 64 (plus one that finds nothing), then 0 without waiting."""
    a, b = pair
    fast = sf.FastSocketCan(b)
    before = time.time()
    for i in range(100):
        a.send(_raw(0x100 + i, bytes([i]) * (i % 9)))
    got = []
    while n := fast.recv_batch(1000):
        got.extend(fast.frame(i) for i in range(n))
    assert fast.recv_calls == 3
    assert [(c, n, d[:n]) for c, n, d, _ in got] == [
        (0x100 + i, i % 9, bytes([i]) * (i % 9)) for i in range(100)
    ]
    stamps = [t for *_, t in got]
    assert all(before - 1.0 < t < time.time() + 1.0 for t in stamps)
    assert stamps == sorted(stamps)
    t0 = time.monotonic()
    assert fast.recv_batch(10) == 0
    assert time.monotonic() - t0 < 1.0


def test_recv_batch_respects_the_callers_cap(pair: tuple[socket.socket, socket.socket]) -> None:
    a, b = pair
    fast = sf.FastSocketCan(b, batch=8)
    for i in range(5):
        a.send(_raw(i, b""))
    assert fast.recv_batch(3) == 3
    assert [fast.frame(i)[0] for i in range(3)] == [0, 1, 2]
    assert fast.recv_batch(100) == 2
    assert [fast.frame(i)[0] for i in range(2)] == [3, 4]


def test_send_frames_one_system_call_for_a_tick(
    pair: tuple[socket.socket, socket.socket],
) -> None:
    """A 4-reel tick's frames (data and RTR) leave in one sendmmsg, byte-exact."""
    a, b = pair
    fast = sf.FastSocketCan(a)
    frames = [cs.encode_set_input_pos(n, 0.25 * n, 1.0, 0.0) for n in range(4)]
    frames += [cs.encode_rtr(n, cs.GET_ENCODER_ESTIMATES) for n in range(4)]
    assert fast.send_frames(frames) is None
    assert fast.send_calls == 1
    b.setblocking(False)
    for arb_id, data, remote in frames:
        want = sf.CAN_FRAME.pack(arb_id | sf.CAN_RTR_FLAG, 8, b"") if remote else _raw(arb_id, data)
        assert b.recv(64) == want
    with pytest.raises(BlockingIOError):
        b.recv(64)


def test_send_frames_rejects_what_is_not_a_standard_frame(
    pair: tuple[socket.socket, socket.socket],
) -> None:
    fast = sf.FastSocketCan(pair[0])
    with pytest.raises(ValueError, match="standard CAN frame"):
        fast.send_frames([(0x800, b"", False)])
    with pytest.raises(ValueError, match="standard CAN frame"):
        fast.send_frames([(0x1, b"123456789", False)])
    assert fast.send_calls == 0


def test_a_full_socket_buffer_fails_the_frames_not_sent(
    pair: tuple[socket.socket, socket.socket],
) -> None:
    """Once the peer's queue is full every further frame is named as failed, after one bounded
    wait for room; the frames before went out."""
    a, _b = pair
    fast = sf.FastSocketCan(a, send_timeout_s=0.01)
    sent = 0
    failures = None
    while failures is None and sent < 100_000:
        failures = fast.send_frames([(0x10, b"\x00" * 8, False)] * 10)
        sent += 10
    assert failures is not None, "the socket buffer never filled"
    assert failures, "a failure list is never empty"
    assert all(e.errno == errno.EAGAIN and "Transmit buffer full" in str(e) for _, e in failures)
    idx = [i for i, _ in failures]
    assert idx == list(range(idx[0], 10))


class _ENOBUFSOnce:
    """A sendmmsg stand-in: the frame at `fail_at` meets a full device queue (ENOBUFS)."""

    def __init__(self, real: object, fail_at: int) -> None:
        self.real = real
        self.fail_at = fail_at
        self.done = 0

    def __call__(self, fd: int, address: int, n: int, flags: int) -> int:
        if self.done == self.fail_at:
            self.done += 1
            ctypes.set_errno(errno.ENOBUFS)
            return -1
        todo = n if self.done > self.fail_at else min(n, self.fail_at - self.done)
        sent = self.real(fd, address, todo, flags)  # type: ignore[operator]
        self.done += sent
        return int(sent)


def _driver_on(sock: socket.socket, nodes: tuple[int, ...] = (0, 1, 2, 3)) -> ODriveReels:
    bus = can.Bus(interface="virtual", channel=f"fast-{id(sock)}")
    return ODriveReels(bus, nodes, fast_path=sf.FastSocketCan(sock))


def test_driver_counts_enobufs_per_frame_and_sends_the_rest(
    pair: tuple[socket.socket, socket.socket],
) -> None:
    a, b = pair
    driver = _driver_on(a)
    fast = driver._fast
    assert fast is not None and driver.fast_path
    fast._sendmmsg = _ENOBUFSOnce(fast._sendmmsg, fail_at=2)  # type: ignore[method-assign]
    text = "send Set_Input_Pos to node 2: ENOBUFS: No buffer space available"
    with pytest.raises(BusError, match=f"^{text}$"):
        driver.command([0.0, 1.0, 2.0, 3.0])
    assert driver.stats.frames_tx == 3
    assert driver.stats.bus_errors == 1
    assert driver.stats.last_error == text
    b.setblocking(False)
    got = [sf.CAN_FRAME.unpack(b.recv(64))[0] for _ in range(3)]
    assert got == [cs.arbitration_id(n, cs.SET_INPUT_POS) for n in (0, 1, 3)]
    with pytest.raises(BlockingIOError):
        b.recv(64)  # nothing beyond the tick's frames


def test_driver_polls_readings_error_frames_and_foreign_frames(
    pair: tuple[socket.socket, socket.socket],
) -> None:
    """Encoder and heartbeat frames update the readings with the kernel's stamp; an error frame
    is a bus error; an extended id is a decode error; an RTR request is host traffic."""
    a, b = pair
    driver = _driver_on(b)
    enc = cs.encode_encoder_estimates(2, 1.5, -0.25)
    hb = cs.encode_heartbeat(2, 0, cs.AxisState.CLOSED_LOOP_CONTROL)
    a.send(_raw(enc[0], enc[1]))
    a.send(_raw(hb[0], hb[1]))
    a.send(_raw(sf.CAN_ERR_FLAG | 0x40, b"\x00" * 8))
    a.send(_raw(sf.CAN_EFF_FLAG | 0x1ABCDE, b"\x01"))
    a.send(sf.CAN_FRAME.pack(sf.CAN_RTR_FLAG | cs.arbitration_id(1, 0x09), 8, b""))
    t_sent = time.monotonic()
    assert driver.poll() == 5
    r = driver.reading(2)
    assert (r.position_rev, r.velocity_rps) == (1.5, -0.25)
    assert r.ready and r.state_name == "CLOSED_LOOP_CONTROL"
    assert t_sent - 1.0 < r.stamp_s <= time.monotonic()
    s = driver.stats
    assert s.frames_rx == 5 and s.untimed_frames == 0
    assert s.bus_errors == 1 and s.last_error == "CAN error frame 0x40"
    assert s.errors_by_kind["error_frame"] == 1
    assert s.decode_errors == 1 and s.errors_by_kind["extended_id"] == 1
    assert s.commands_heard == 1
    assert driver.poll() == 0


def test_driver_catch_up_reads_a_backlog_past_the_cap(
    pair: tuple[socket.socket, socket.socket],
) -> None:
    """With frames older than catch_up_age_s at the cap, the poll reads on (as python-can's)."""
    a, b = pair
    bus = can.Bus(interface="virtual", channel=f"fast-cu-{id(b)}")
    driver = ODriveReels(
        bus,
        (0,),
        max_frames_per_poll=4,
        catch_up_age_s=1e-9,
        fast_path=sf.FastSocketCan(b),
    )
    for i in range(10):
        f = cs.encode_encoder_estimates(0, float(i), 0.0)
        a.send(_raw(f[0], f[1]))
    assert driver.poll() == 10
    assert driver.stats.catch_up_polls == 1
    assert driver.reading(0).position_rev == 9.0


def test_not_socketcan_keeps_python_can() -> None:
    bus = can.Bus(interface="virtual", channel="fast-none")
    try:
        assert sf.open_fast_path(bus, [(0, 0x7E0)]) is None
        assert not ODriveReels(bus, (0,)).fast_path
    finally:
        bus.shutdown()


class _CanRawStandIn(socket.socket):
    """An AF_UNIX datagram socket answering the CAN_RAW options as a SocketCAN raw socket
    would: accepts the ones the fast path sets, reports CAN FD frames on or off (`fd`)."""

    fd = False

    def getsockopt(self, level: int, option: int, *args: int) -> Any:
        if level == sf._SOL_CAN_RAW and option == sf._CAN_RAW_FD_FRAMES:
            return int(self.fd)
        return super().getsockopt(level, option, *args)

    def setsockopt(self, level: int, option: int, *args: Any) -> None:
        if level != sf._SOL_CAN_RAW:
            super().setsockopt(level, option, *args)


@pytest.mark.parametrize("fd", [False, True], ids=["classic", "fd"])
def test_a_can_fd_socket_keeps_python_can(fd: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """A bus opened for CAN FD receives 72-byte frames, which the fast path's 16-byte slots
    would cut to 8 data bytes (a 12-byte frame would pass as a well-formed 8-byte one): both
    drivers keep python-can's path there, and take the fast path on a classic socket."""
    from drivers.cia402 import CiA402Reels

    sock = _CanRawStandIn(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.fd = fd
    monkeypatch.setattr(sf, "socket_of", lambda bus: sock)
    bus = can.Bus(interface="virtual", channel="fast-fd")
    try:
        assert (sf.open_fast_path(bus, [(0, 0x7E0)]) is None) is fd
        assert ODriveReels(bus, (0,)).fast_path is not fd
        assert CiA402Reels(bus, (1,), counts_per_rev=4096, period_s=0.002).fast_path is not fd
    finally:
        bus.shutdown()
        sock.close()


def test_receive_error_is_counted_never_raised(
    pair: tuple[socket.socket, socket.socket], monkeypatch: pytest.MonkeyPatch
) -> None:
    _a, b = pair
    driver = _driver_on(b)
    fast = driver._fast
    assert fast is not None

    def down(max_frames: int) -> int:
        raise OSError(errno.ENETDOWN, "Network is down")

    monkeypatch.setattr(fast, "recv_batch", down)
    assert driver.poll() == 0
    assert driver.stats.bus_errors == 1
    assert "Network is down" in (driver.stats.last_error or "")


def test_an_unexpected_send_error_is_a_bus_error_naming_every_frame(
    pair: tuple[socket.socket, socket.socket], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Whatever the fast send raises (select's ValueError on a descriptor >= 1024, say), the
    driver raises BusError naming every frame of the call as failed, as python-can's path does;
    `estop` raises nothing else and a poll's encoder RTR never escapes."""
    a, _b = pair
    bus = can.Bus(interface="virtual", channel=f"fast-odd-{id(a)}")
    driver = ODriveReels(bus, (1, 2), encoder_rtr=True, fast_path=sf.FastSocketCan(a))
    fast = driver._fast
    assert fast is not None

    def odd(frames: object) -> None:
        raise ValueError("filedescriptor out of range in select()")

    monkeypatch.setattr(fast, "send_frames", odd)
    with pytest.raises(BusError) as info:
        driver.estop()
    text = str(info.value)
    assert "Estop to node 1: ValueError: filedescriptor out of range" in text
    assert "Estop to node 2: ValueError" in text
    assert driver.stats.bus_errors == 2 and driver.stats.frames_tx == 0
    assert driver.poll() == 0  # the RTR round fails: counted, not raised
    assert driver.stats.bus_errors == 4
    bus.shutdown()


class _BrieflyFull:
    """A sendmmsg stand-in: the socket buffer is full for the first `times` attempts (EAGAIN),
    then the real call."""

    def __init__(self, real: object, times: int) -> None:
        self.real = real
        self.left = times

    def __call__(self, fd: int, address: int, n: int, flags: int) -> int:
        if self.left > 0:
            self.left -= 1
            ctypes.set_errno(errno.EAGAIN)
            return -1
        return int(self.real(fd, address, n, flags))  # type: ignore[operator]


def test_a_briefly_full_socket_buffer_loses_no_frame(
    pair: tuple[socket.socket, socket.socket],
) -> None:
    """The buffer is full at several attempts of one call: the call keeps waiting for room
    while its send timeout lasts, so every frame goes out, in order."""
    a, b = pair
    fast = sf.FastSocketCan(a, send_timeout_s=5.0)
    fast._sendmmsg = _BrieflyFull(fast._sendmmsg, times=3)  # type: ignore[method-assign]
    frames = [(0x10 + i, bytes([i]), False) for i in range(4)]
    assert fast.send_frames(frames) is None
    b.setblocking(False)
    assert [sf.CAN_FRAME.unpack(b.recv(64))[0] for _ in frames] == [0x10, 0x11, 0x12, 0x13]


def test_a_full_socket_buffer_waits_once_per_call_then_fails_the_rest(
    pair: tuple[socket.socket, socket.socket],
) -> None:
    """The peer never reads: one call waits at most about its send timeout in all (not one per
    frame), then names every frame not sent."""
    a, _b = pair
    fast = sf.FastSocketCan(a, send_timeout_s=0.2)
    a.setblocking(False)
    with pytest.raises(BlockingIOError):
        while True:  # fill the peer's queue
            a.send(_raw(0x10, b""))
    t0 = time.monotonic()
    failures = fast.send_frames([(0x10 + i, b"", False) for i in range(20)])
    elapsed = time.monotonic() - t0
    assert failures is not None and [i for i, _ in failures] == list(range(20))
    assert all(e.errno == errno.EAGAIN and "Transmit buffer full" in str(e) for _, e in failures)
    assert 0.15 < elapsed < 2.0  # one deadline: 20 per-frame waits would take 4 s


def _overflow(tx: socket.socket, rx: socket.socket, first: int) -> None:
    """Send 500 frames to `rx`, far more than its queue holds."""
    for i in range(500):
        tx.sendto(_raw(0x100, (first + i).to_bytes(4, "little")), rx.getsockname())


def test_drops_before_the_fast_path_existed_are_not_counted() -> None:
    """Drops from before the fast path was set up are no loop stall: its count starts at the
    socket's drop counter then, and frames already queued with older counts (the socket counted
    drops before) add nothing; a later overflow counts exactly the frames lost. A loopback UDP
    socket stands in for the CAN socket: it reports its drops the same way."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        rx.bind(("127.0.0.1", 0))
        tx.bind(("127.0.0.1", 0))
        rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # the kernel's minimum
        rx.setsockopt(socket.SOL_SOCKET, sf._SO_RXQ_OVFL, 1)  # queued frames carry counts
        rx.setblocking(False)
        _overflow(tx, rx, 0)
        with pytest.raises(BlockingIOError):
            while True:
                rx.recv(64)
        _overflow(tx, rx, 1000)  # queued with the count of the first overflow, more dropped
        fast = sf.FastSocketCan(rx)
        frames = []
        while n := fast.recv_batch(64):
            frames += [int.from_bytes(fast.frame(i)[2][:4], "little") for i in range(n)]
        assert frames and fast.kernel_drops == 0
        _overflow(tx, rx, 2000)
        while n := fast.recv_batch(64):
            frames += [int.from_bytes(fast.frame(i)[2][:4], "little") for i in range(n)]
        tx.sendto(_raw(0x100, (3000).to_bytes(4, "little")), rx.getsockname())
        while n := fast.recv_batch(64):
            frames += [int.from_bytes(fast.frame(i)[2][:4], "little") for i in range(n)]
        after = [f for f in frames if f >= 2000]
        assert after[-1] == 3000
        assert fast.kernel_drops == 501 - len(after) > 0
    finally:
        rx.close()
        tx.close()


def test_both_paths_name_a_failed_send_the_same_way() -> None:
    """python-can's path names an OS error as the fast path does: by its errno name."""

    class Refusing(can.BusABC):
        def __init__(self) -> None:
            super().__init__(channel="refusing")

        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            raise OSError(errno.ENOBUFS, "No buffer space available")

        def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
            return None, False

    bus = Refusing()
    d = ODriveReels(bus, (2,))
    assert not d.fast_path
    text = "send Set_Input_Pos to node 2: ENOBUFS: No buffer space available"
    with pytest.raises(BusError, match=f"^{text}$"):
        d.command([0.0])
    assert d.stats.last_error == text
    bus.shutdown()


def test_open_fast_path_takes_the_drivers_choice(
    pair: tuple[socket.socket, socket.socket],
) -> None:
    """The constructors' `fast_path` goes to `open_fast_path` as given: a `FastSocketCan` is
    used as it is, False keeps python-can's path."""
    fast = sf.FastSocketCan(pair[0])
    bus = can.Bus(interface="virtual", channel="fast-choice")
    try:
        assert sf.open_fast_path(bus, [(0, 0x7E0)], fast_path=fast) is fast
        assert sf.open_fast_path(bus, [(0, 0x7E0)], fast_path=False) is None
        assert sf.open_fast_path(bus, [(0, 0x7E0)], fast_path=True) is None  # not SocketCAN
    finally:
        bus.shutdown()


def test_a_closed_socket_is_refused_never_its_number_reused() -> None:
    """After the bus's socket is closed (bus.shutdown()) the fast path refuses to receive or
    send, by name, even when its old descriptor number now belongs to another socket; the
    driver counts the refusals as bus errors and `estop` raises BusError."""
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    bus = can.Bus(interface="virtual", channel=f"fast-closed-{id(b)}")
    driver = ODriveReels(bus, (1,), fast_path=sf.FastSocketCan(b))
    fast = driver._fast
    assert fast is not None
    number = b.fileno()
    b.close()
    c, d = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        assert number in (c.fileno(), d.fileno())  # the number now names another socket
        for s in (c, d):
            s.send(_raw(0x21, b"\x01"))  # a frame another socket is meant to read
        calls = fast.recv_calls, fast.send_calls
        with pytest.raises(sf.FastPathClosed, match="closed"):
            fast.recv_batch(10)
        with pytest.raises(sf.FastPathClosed, match="closed"):
            fast.send_frames([(0x21, b"", False)])
        assert (fast.recv_calls, fast.send_calls) == calls
        assert driver.poll() == 0
        assert driver.stats.bus_errors == 1 and "closed" in (driver.stats.last_error or "")
        with pytest.raises(BusError, match=r"send Estop to node 1: EBADF: .*closed"):
            driver.estop()
        for s in (c, d):
            s.setblocking(False)
            assert sf.CAN_FRAME.unpack(s.recv(64))[0] == 0x21  # still there: not read
    finally:
        for s in (a, c, d):
            s.close()
        bus.shutdown()
