"""The CiA 402 driver on the SocketCAN fast path, on the host.

The host has no AF_CAN: an AF_UNIX datagram socket pair stands in for the CAN socket (the same
16-byte `can_frame` datagrams through the same `recvmmsg`/`sendmmsg`), while the start-up SDO
exchange runs over a python-can `virtual` bus with the simulated drives, as `configure` reads
through python-can's `recv` on either path. The kernel filters, error frames from a real
interface and the daemon run in the vcan suite (tests/drivers/test_cia402_vcan.py).
"""

from __future__ import annotations

import errno
import socket
import struct
import threading
import time
import uuid
from collections.abc import Iterator

import can
import pytest

from drivers import socketcan_fast as sf
from drivers.base import NEVER_S, BusError
from drivers.bus import open_bus
from drivers.cia402 import CiA402Reels, profile
from drivers.cia402.driver import kernel_filters
from drivers.cia402.profile import Goal
from drivers.cia402.sdo_config import local_mapping
from drivers.cia402.sim import SimCiA402Bank
from tests.drivers.test_socketcan_fast import _ENOBUFSOnce

NODES = (1, 2, 3, 4)
CPR = 4096
PERIOD_S = 0.002
TPDO = struct.Struct("<Hih")  # statusword, position actual, torque actual
SW_OPERATION_ENABLED = 0x0237


def _raw(can_id: int, data: bytes) -> bytes:
    return sf.CAN_FRAME.pack(can_id, len(data), data)


class FastRig:
    """A driver whose cyclic traffic runs on `peer` (the other end of its fast socket), set up
    by SDO with simulated drives on a virtual bus that are stopped once it is configured."""

    def __init__(self) -> None:
        self.peer, mine = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.peer.setblocking(False)
        self.mine = mine
        channel = f"test-cia402-fast-{uuid.uuid4().hex}"
        self.sim_bus = open_bus("virtual", channel)
        self.bus = open_bus("virtual", channel)
        self.fast = sf.FastSocketCan(mine)
        self.driver = CiA402Reels(
            self.bus,
            NODES,
            counts_per_rev=CPR,
            period_s=PERIOD_S,
            fast_path=self.fast,
            sdo_timeout_s=5.0,  # the simulated drives' thread may be starved on a busy machine
        )
        bank = SimCiA402Bank(
            self.sim_bus, NODES, initial_position_rev=[0.0] * 4, counts_per_rev=CPR
        ).start()
        try:
            self.driver.configure()
        finally:
            assert bank.stop(timeout_s=2.0)

    def sent(self) -> list[tuple[int, bytes]]:
        """The frames the driver sent on its fast socket since the last call."""
        out = []
        while True:
            try:
                raw = self.peer.recv(64)
            except BlockingIOError:
                return out
            can_id, length, data = sf.CAN_FRAME.unpack(raw)
            out.append((can_id, data[:length]))

    def close(self) -> None:
        for bus in (self.sim_bus, self.bus):
            bus.shutdown()
        self.peer.close()
        self.mine.close()


@pytest.fixture
def rig() -> Iterator[FastRig]:
    r = FastRig()
    yield r
    r.close()


def test_kernel_filters_pass_sync_tpdo1_emcy_sdo_answers_and_heartbeats() -> None:
    got = kernel_filters((1, 127))
    assert sorted(got) == sorted(
        (c, 0x7FF) for c in (0x080, 0x181, 0x081, 0x581, 0x701, 0x1FF, 0x0FF, 0x5FF, 0x77F)
    )
    assert len(sf.can_filters_for(got)) == 9 * 8


def test_another_sync_producer_on_the_fast_path_is_a_named_conflict(rig: FastRig) -> None:
    # The fast path never hears its own frames: a SYNC it receives is another master's.
    rig.driver.command([0.0] * 4)
    assert [c for c, _ in rig.sent()].count(0x080) == 1  # ours went out, not echoed back
    rig.driver.poll()
    assert rig.driver.stats.conflicts == 0
    rig.peer.send(_raw(0x080, b""))
    rig.peer.send(_raw(0x080, b"\x05"))  # a SYNC with its counter (CiA 301)
    rig.driver.poll()
    st = rig.driver.stats
    assert st.conflicts == 2 and st.errors_by_kind["another_master"] == 2
    assert st.last_conflict is not None and "another SYNC producer" in st.last_conflict
    assert st.commands_heard == 0 and st.dropped == 0


def test_not_socketcan_keeps_python_can() -> None:
    bus = open_bus("virtual", f"test-cia402-fast-{uuid.uuid4().hex}")
    try:
        assert not CiA402Reels(bus, NODES, counts_per_rev=CPR, period_s=PERIOD_S).fast_path
        assert not CiA402Reels(
            bus, NODES, counts_per_rev=CPR, period_s=PERIOD_S, fast_path=False
        ).fast_path
    finally:
        bus.shutdown()


def test_configure_reads_through_python_can_and_poll_through_the_fast_socket(
    rig: FastRig,
) -> None:
    """The SDO set-up ran over the virtual bus (python-can's recv); nothing went out on the fast
    socket until the first cycle, which leaves there."""
    d = rig.driver
    assert d.fast_path
    assert all(d.drive_status(n).configured for n in NODES)
    assert rig.fast.send_calls == 0 and rig.fast.recv_calls == 0
    d.poll()  # no cycle since the last poll: runs one with the held set-points
    assert rig.fast.recv_calls == 1 and rig.fast.send_calls == 1
    assert len(rig.sent()) == 2 * len(NODES) + 1


def test_poll_hands_every_kind_of_frame_off(rig: FastRig) -> None:
    """TPDOs are decoded by the driver; heartbeats and EMCY reach canopen's consumers; error
    frames, extended ids, remote frames, unknown ids and unsolicited SDO answers are counted."""
    d = rig.driver
    d.command([0.0] * 4)  # the loop's rhythm: this poll runs no cycle of its own
    rig.sent()
    stats0 = d.stats.snapshot()
    t0 = time.monotonic()
    plan = [
        _raw(0x182, TPDO.pack(SW_OPERATION_ENABLED, 2048, -7)),
        _raw(0x702, b"\x05"),  # heartbeat: OPERATIONAL
        _raw(0x083, struct.pack("<HB5s", 0x2310, 0x03, bytes(5))),  # EMCY: over-current
        _raw(sf.CAN_ERR_FLAG | 0x40, bytes(8)),
        _raw(sf.CAN_EFF_FLAG | 0x182, b"\x01"),
        sf.CAN_FRAME.pack(sf.CAN_RTR_FLAG | 0x202, 8, b""),
        _raw(0x185, TPDO.pack(0, 0, 0)),  # a node not ours (no kernel filter on this socket)
        _raw(0x582, bytes(8)),  # an SDO answer nobody asked for
        _raw(0x182, b"\x01\x02"),  # a TPDO of the wrong length
    ]
    for raw in plan:
        rig.peer.send(raw)
    assert d.poll() == len(plan)
    r = d.reading(2)
    assert r.position_rev == 0.5
    assert t0 <= r.stamp_s <= time.monotonic()
    assert r.heartbeat_stamp_s > NEVER_S
    st = d.drive_status(2)
    assert st.statusword == SW_OPERATION_ENABLED and st.torque_permille == -7
    assert st.nmt_state == "OPERATIONAL"
    assert r.ready and r.state_name == "Operation enabled"
    assert d.drive_status(3).emcy_code == 0x2310
    s = d.stats
    assert s.frames_rx - stats0.frames_rx == len(plan)
    assert s.bus_errors == 1 and s.last_error == "CAN error frame 0x40"
    kinds = {k: v - stats0.errors_by_kind.get(k, 0) for k, v in s.errors_by_kind.items()}
    assert {k: v for k, v in kinds.items() if v} == {
        "error_frame": 1,
        "extended_id": 1,
        "not_for_host": 1,
        "unknown_cob_id": 1,
        "sdo_unsolicited": 1,
        "length": 1,
    }
    assert d.bad_frames(2) == 1
    assert d.poll() == 0


def test_a_cycle_leaves_in_one_system_call_byte_exact(rig: FastRig) -> None:
    """command(): every drive's RPDO1 (controlword, target) and RPDO2 (velocity offset), then
    the SYNC, in one sendmmsg."""
    d = rig.driver
    calls = rig.fast.send_calls
    tx0 = d.stats.frames_tx
    d.command([0.25, -0.5, 1.0, 2.0], [0.5, 0.0, -1.0, 0.0])
    assert rig.fast.send_calls == calls + 1
    assert d.stats.frames_tx - tx0 == 9
    cw = profile.controlword_for(Goal.DISABLED, None, False)
    want: list[tuple[int, bytes]] = []
    for n, p in zip(NODES, [0.25, -0.5, 1.0, 2.0], strict=True):
        # Not in Operation enabled and no position actual heard yet: the target as commanded,
        # no feed-forward.
        want.append((0x200 + n, struct.pack("<Hi", cw, round(p * CPR))))
        want.append((0x300 + n, struct.pack("<i", 0)))
    want.append((0x080, b""))
    assert rig.sent() == want


def test_a_failed_frame_is_counted_named_and_the_rest_still_sent(rig: FastRig) -> None:
    """ENOBUFS on node 2's RPDO1: named as the stock path names a failed send, counted once;
    the other eight frames (the SYNC too) went out."""
    d = rig.driver
    real = rig.fast._sendmmsg
    rig.fast._sendmmsg = _ENOBUFSOnce(real, fail_at=2)  # type: ignore[method-assign]
    syncs = d._syncs_sent
    errors0, tx0 = d.stats.bus_errors, d.stats.frames_tx
    with pytest.raises(
        BusError, match=r"^node 2 RPDO1: send 0x202: ENOBUFS: No buffer space available$"
    ):
        d.command([0.0] * 4)
    assert d.stats.bus_errors - errors0 == 1
    assert d.stats.last_error == "send 0x202: ENOBUFS: No buffer space available"
    assert d.stats.frames_tx - tx0 == 8
    assert d._syncs_sent == syncs + 1
    sent = [c for c, _ in rig.sent()]
    assert 0x202 not in sent and sent[-1] == 0x080 and len(sent) == 8
    # A SYNC that fails is no SYNC: no TPDO answers it.
    rig.fast._sendmmsg = _ENOBUFSOnce(real, fail_at=8)  # type: ignore[method-assign]
    with pytest.raises(BusError, match=r"^SYNC: send 0x080: ENOBUFS: No buffer space available$"):
        d.command([0.0] * 4)
    assert d._syncs_sent == syncs + 1
    assert [c for c, _ in rig.sent()] == [0x201, 0x301, 0x202, 0x302, 0x203, 0x303, 0x204, 0x304]


def test_a_full_socket_buffer_fails_every_frame_not_sent(rig: FastRig) -> None:
    """The peer never reads: the frames that find no room are each named, then the loop sees
    one BusError listing them."""
    d = rig.driver
    rig.fast._send_timeout_s = 0.001
    failed = None
    for _ in range(100_000):
        try:
            d.command([0.0] * 4)
        except BusError as exc:
            failed = str(exc)
            break
    assert failed is not None, "the socket buffer never filled"
    assert "Transmit buffer full" in failed
    assert d.stats.bus_errors == failed.count("; ") + 1


def test_poll_reads_nothing_while_configure_pumps(rig: FastRig) -> None:
    """While configure's SDO pump runs, it alone reads the bus: poll leaves the frames."""
    d = rig.driver
    rig.peer.send(_raw(0x701, b"\x05"))
    d._configuring = True
    try:
        assert d.poll() == 0
    finally:
        d._configuring = False
    d.command([0.0] * 4)
    assert d.poll() == 1
    assert d.reading(1).heartbeat_stamp_s > NEVER_S


def test_kernel_drops_are_counted_as_rx_overrun(
    rig: FastRig, monkeypatch: pytest.MonkeyPatch
) -> None:
    d = rig.driver
    real = rig.fast.recv_batch

    def overflowing(max_frames: int) -> int:
        rig.fast.kernel_drops += 5
        monkeypatch.setattr(rig.fast, "recv_batch", real)
        return real(max_frames)

    monkeypatch.setattr(rig.fast, "recv_batch", overflowing)
    dropped = d.stats.dropped
    d.command([0.0] * 4)
    d.poll()
    assert d.stats.dropped - dropped == 5
    assert d.stats.errors_by_kind["rx_overrun"] == 5


def test_kernel_drops_are_read_from_the_sockets_drop_counter() -> None:
    """The receive queue overflows while the loop does not poll: the drop count the kernel hands
    over with the next frame (SO_RXQ_OVFL, in `recvmmsg`'s ancillary data) is counted as
    dropped, kind "rx_overrun", and the frames kept still read. A loopback UDP socket stands in
    for the CAN socket: it reports its drops the same way (the CAN socket's in the vcan suite)."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    bus = open_bus("virtual", f"test-cia402-fast-{uuid.uuid4().hex}")
    try:
        rx.bind(("127.0.0.1", 0))
        tx.bind(("127.0.0.1", 0))
        rx.connect(tx.getsockname())  # the driver's cycles go to `tx`, never read
        rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # the kernel's minimum
        d = CiA402Reels(
            bus, NODES, counts_per_rev=CPR, period_s=PERIOD_S, fast_path=sf.FastSocketCan(rx)
        )
        for n in NODES:  # configured as if by SDO, without drives to answer
            drive = d._by_node[n]
            d._use_mapping(drive, *local_mapping(drive.node, n, velocity_offset=True, torque=True))
        for i in range(500):
            tx.sendto(_raw(0x181, TPDO.pack(SW_OPERATION_ENABLED, i, 0)), rx.getsockname())
        taken = 0
        deadline = time.monotonic() + 10.0
        while taken == 0 and time.monotonic() < deadline:
            d.command([0.0] * 4)
            taken += d.poll()
        assert 0 < taken < 500
        # The kernel hands the count over with the next frame it queues.
        tx.sendto(_raw(0x181, TPDO.pack(SW_OPERATION_ENABLED, 500, 0)), rx.getsockname())
        deadline = time.monotonic() + 10.0
        while d.reading(1).position_rev != 500 / CPR and time.monotonic() < deadline:
            d.command([0.0] * 4)
            taken += d.poll()
        assert d.reading(1).position_rev == 500 / CPR
        s = d.stats
        assert s.errors_by_kind.get("rx_overrun", 0) == 501 - taken == s.dropped > 0, s
        assert s.decode_errors == 0 and s.bus_errors == 0, s
    finally:
        bus.shutdown()
        rx.close()
        tx.close()


def test_receive_error_is_counted_never_raised(
    rig: FastRig, monkeypatch: pytest.MonkeyPatch
) -> None:
    d = rig.driver

    def down(max_frames: int) -> int:
        raise OSError(errno.ENETDOWN, "Network is down")

    monkeypatch.setattr(rig.fast, "recv_batch", down)
    d.command([0.0] * 4)
    errors = d.stats.bus_errors
    assert d.poll() == 0
    assert d.stats.bus_errors == errors + 1
    assert "Network is down" in (d.stats.last_error or "")


def test_stock_path_names_a_failed_send_the_same_way() -> None:
    """One naming rule for both paths: "<frame>: send 0x<id>: <errno name>: <error>"."""

    class Refusing(can.BusABC):
        def __init__(self) -> None:
            super().__init__(channel="refusing")

        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            raise OSError(errno.ENOBUFS, "No buffer space available")

        def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
            return None, False

    bus = Refusing()
    d = CiA402Reels(bus, (2,), counts_per_rev=CPR, period_s=PERIOD_S)
    assert not d.fast_path
    drive = d._by_node[2]  # configured as if by SDO, without a drive to answer
    d._use_mapping(drive, *local_mapping(drive.node, 2, velocity_offset=True, torque=True))
    with pytest.raises(
        BusError, match=r"^node 2 RPDO1: send 0x202: ENOBUFS: No buffer space available; "
    ):
        d.command([0.0])
    assert d.stats.bus_errors == 3  # RPDO1, RPDO2, SYNC: every frame tried
    assert d.stats.last_error == "send 0x080: ENOBUFS: No buffer space available"
    bus.shutdown()


def test_bench_socketpair_figures_measure_both_drivers() -> None:
    """`bench_vcan --socketpair` (the host's fast-path cost per frame) runs both drivers."""
    from controller.cli.bench_vcan import socketpair_figures

    got = socketpair_figures(1, 20, 3)
    assert set(got) == {"odrive", "cia402"}
    assert all(0.0 < v < 1e5 for fig in got.values() for v in fig.values())


def test_an_unexpected_send_error_is_a_bus_error_naming_every_frame(
    rig: FastRig, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Whatever the fast send raises (select's ValueError on a descriptor >= 1024, say), every
    frame of the cycle is named as failed: `estop` raises BusError, `poll` nothing."""
    d = rig.driver

    def odd(frames: object) -> None:
        raise ValueError("filedescriptor out of range in select()")

    monkeypatch.setattr(rig.fast, "send_frames", odd)
    errors0, tx0 = d.stats.bus_errors, d.stats.frames_tx
    syncs = d._syncs_sent
    with pytest.raises(BusError) as info:
        d.estop()
    text = str(info.value)
    assert text.startswith("node 1 RPDO1: send 0x201: ValueError: filedescriptor out of range")
    assert text.count("ValueError") == 2 * len(NODES) + 1 and "SYNC: send 0x080" in text
    assert d.stats.bus_errors - errors0 == 2 * len(NODES) + 1
    assert d.stats.frames_tx == tx0 and d._syncs_sent == syncs
    assert d.poll() == 0  # the estop's cycle was this poll's
    d._last_sync_s -= 1.0  # the next poll is due a held-set-point cycle, which fails
    assert d.poll() == 0  # counted, not raised
    assert d.stats.bus_errors - errors0 == 2 * (2 * len(NODES) + 1)


def test_an_error_frame_is_a_bus_error_not_a_dropped_frame(rig: FastRig) -> None:
    """The same error-frame rule as the ODrive driver's: a bus error, kind "error_frame", and
    no dropped data frame."""
    d = rig.driver
    d.command([0.0] * 4)
    before = d.stats.snapshot()
    rig.peer.send(_raw(sf.CAN_ERR_FLAG | 0x40, bytes(8)))
    assert d.poll() == 1
    s = d.stats
    assert s.bus_errors - before.bus_errors == 1 and s.last_error == "CAN error frame 0x40"
    assert s.errors_by_kind["error_frame"] - before.errors_by_kind.get("error_frame", 0) == 1
    assert (s.dropped, s.decode_errors) == (before.dropped, before.decode_errors)


def test_a_closed_socket_is_a_named_bus_error(rig: FastRig) -> None:
    """After the bus's socket is closed: poll counts the refused receive, estop raises BusError
    naming every frame of its cycle."""
    d = rig.driver
    d.command([0.0] * 4)
    rig.mine.close()
    errors0 = d.stats.bus_errors
    assert d.poll() == 0
    assert d.stats.bus_errors == errors0 + 1 and "closed" in (d.stats.last_error or "")
    with pytest.raises(BusError, match=r"^node 1 RPDO1: send 0x201: EBADF: .*closed"):
        d.estop()
    assert d.stats.bus_errors == errors0 + 1 + 2 * len(NODES) + 1


def _recv_until(sock: socket.socket, want: int, timeout_s: float) -> list[tuple[int, bytes]]:
    """At least `want` frames from `sock` (blocking, bounded by `timeout_s`)."""
    out: list[tuple[int, bytes]] = []
    sock.settimeout(timeout_s)
    try:
        while len(out) < want:
            can_id, length, data = sf.CAN_FRAME.unpack(sock.recv(64))
            out.append((can_id, data[:length]))
    except TimeoutError:
        pass
    return out


def test_the_simulated_drives_serve_a_fast_socket_in_batches() -> None:
    """`run_sim` on the fast path: frames already queued are taken in one receive call and
    answered in one send call; each goes only to the drive it concerns (no answer for a node
    not served); error, extended and remote frames are ignored; NMT start then brings TPDOs."""
    from drivers.cia402.sim import SimCiA402Drive, run_sim

    peer, mine = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    fast = sf.FastSocketCan(mine)
    bus = open_bus("virtual", f"test-cia402-fast-{uuid.uuid4().hex}")
    drives = [SimCiA402Drive(n) for n in NODES]
    sdo_upload_1000 = bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])
    for n in (*NODES, 9):
        peer.send(_raw(0x600 + n, sdo_upload_1000))
    peer.send(_raw(sf.CAN_ERR_FLAG | 0x40, bytes(8)))
    peer.send(_raw(sf.CAN_EFF_FLAG | 0x601, sdo_upload_1000))
    peer.send(sf.CAN_FRAME.pack(sf.CAN_RTR_FLAG | 0x602, 8, b""))
    stop = threading.Event()
    thread = threading.Thread(
        target=run_sim, args=(bus, drives, stop), kwargs={"fast_path": fast}, daemon=True
    )
    thread.start()
    try:
        first = _recv_until(peer, 2 * len(NODES), 30.0)
        # The queued requests were taken in one batch: their answers left in one send, with
        # the boot-up messages the drives had pending.
        assert fast.send_calls == 1
        answers = [f for f in first if f[0] & 0x780 == 0x580]
        assert sorted(c for c, _ in answers) == [0x580 + n for n in NODES]
        assert all(data[0] == 0x43 for _, data in answers)  # expedited upload, 4 bytes
        assert sorted(c for c, _ in first if c & 0x780 == 0x700) == [0x700 + n for n in NODES]
        peer.send(_raw(0x000, b"\x01\x00"))  # NMT start, every node
        tpdos = {c for c, _ in _recv_until(peer, 2 * len(NODES), 30.0) if c & 0x780 == 0x180}
        assert sorted(tpdos) == [0x180 + n for n in NODES]  # (and TPDO2, also asynchronous)
    finally:
        stop.set()
        thread.join(5.0)
        bus.shutdown()
        peer.close()
        mine.close()
    assert not thread.is_alive()
