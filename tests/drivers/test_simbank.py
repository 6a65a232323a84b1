"""`drivers.simbank.SimLink`: a bank's frames in and out, through python-can or the SocketCAN
fast path (an AF_UNIX socket pair stands in for the CAN socket on the host), a late tick's
drain bounded by its budget; and the CiA402 serving loop, late on every tick, still hears the
host."""

from __future__ import annotations

import socket
import threading
import time
import uuid
from collections.abc import Iterator

import can
import pytest

from drivers import socketcan_fast as sf
from drivers.cia402.sim import SimCiA402Drive, run_sim
from drivers.simbank import SimLink


class _QueueBus:
    """A bus with `n` frames waiting (`n` < 0: a flood that never ends)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.msg = can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self.n == 0:
            return None
        self.n -= 1
        return self.msg


def test_serve_takes_every_waiting_frame_and_a_flood_for_one_budget_only() -> None:
    got: list[tuple[int, bytes | bytearray, float]] = []
    bus = _QueueBus(50)
    link = SimLink(bus, fast_path=False)  # type: ignore[arg-type]
    assert link.serve(lambda *f: got.append(f), 0.0, 60.0) == 50
    assert len(got) == 50 and bus.n == 0 and got[0][0] == 0x123
    flood = SimLink(_QueueBus(-1), fast_path=False)  # type: ignore[arg-type]
    t0 = time.monotonic()
    taken = flood.serve(lambda *f: time.sleep(0.001), 0.0, 0.02)
    took_s = time.monotonic() - t0
    assert 1 <= taken <= 21 and took_s >= 0.02  # the budget ends it, not the (endless) queue
    assert flood.serve(lambda *f: None, 0.0, 60.0, max_frames=7) == 7


def test_python_cans_path_hands_frames_on_with_socketcans_flags() -> None:
    channel = f"test-simbank-{uuid.uuid4().hex}"
    bus = can.Bus(interface="virtual", channel=channel)
    host = can.Bus(interface="virtual", channel=channel)
    try:
        link = SimLink(bus)
        assert link.fast is None  # not SocketCAN
        host.send(can.Message(arbitration_id=0x1ABCDEF, data=b"\x01", is_extended_id=True))
        host.send(can.Message(arbitration_id=0x209, is_remote_frame=True, is_extended_id=False))
        got: list[tuple[int, bytes | bytearray, float]] = []
        assert link.serve(lambda *f: got.append(f), 10.0, 10.0) == 2
        assert [g[0] for g in got] == [0x1ABCDEF | sf.CAN_EFF_FLAG, 0x209 | sf.CAN_RTR_FLAG]
        assert link.serve(lambda *f: got.append(f), 0.0, 1.0) == 0
        link.send([(0x123, b"\x05", False), (0x0A9, b"", True)])
        a, b = host.recv(10.0), host.recv(10.0)
        assert a is not None and (a.arbitration_id, bytes(a.data)) == (0x123, b"\x05")
        assert b is not None and b.is_remote_frame and b.dlc == 8
    finally:
        bus.shutdown()
        host.shutdown()


@pytest.fixture
def pair() -> Iterator[tuple[socket.socket, sf.FastSocketCan]]:
    peer, mine = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    yield peer, sf.FastSocketCan(mine)
    peer.close()
    mine.close()


def test_the_fast_path_takes_what_is_pending_in_batches_and_answers_in_one_call(
    pair: tuple[socket.socket, sf.FastSocketCan],
) -> None:
    peer, fast = pair
    bus = can.Bus(interface="virtual", channel=f"test-simbank-{uuid.uuid4().hex}")
    bus.shutdown()  # never used: the fast path given is
    link = SimLink(bus, fast_path=fast)
    assert link.fast is fast
    got: list[tuple[int, bytes | bytearray, float]] = []
    assert link.serve(lambda *f: got.append(f), 0.0, 1.0) == 0  # nothing pending, no wait
    for i in range(100):
        peer.send(sf.CAN_FRAME.pack(0x200 + i, 2, bytes([i, 1])))
    assert link.serve(lambda *f: got.append(f), 10.0, 10.0) == 100
    assert [(c, bytes(d)) for c, d, _ in got] == [(0x200 + i, bytes([i, 1])) for i in range(100)]
    assert fast.recv_calls <= 1 + 3  # 64 + 36 (+ the empty look and the empty end)
    calls = fast.send_calls
    link.send([(0x100 + i, bytes([i]), False) for i in range(9)])
    assert fast.send_calls == calls + 1
    out = [sf.CAN_FRAME.unpack(peer.recv(64)) for _ in range(9)]
    assert [(c, n) for c, n, _ in out] == [(0x100 + i, 1) for i in range(9)]
    # A waiting serve returns after its timeout when nothing comes.
    t0 = time.monotonic()
    assert link.serve(lambda *f: got.append(f), 0.05, 1.0) == 0
    assert time.monotonic() - t0 >= 0.045


class _SlowDrive(SimCiA402Drive):
    """A drive whose step takes 3 ms (every 1 ms tick of the serving loop falls due late)."""

    steps = 0
    heard = 0

    def step(self, dt_s: float) -> list[tuple[int, bytes]]:
        time.sleep(0.003)  # the cost of the step, not a synchronisation
        self.steps += 1
        return []

    def hears(self, arb_id: int) -> bool:
        return True

    def handle(
        self, arb_id: int, data: bytes | bytearray, timestamp: float = 0.0
    ) -> list[tuple[int, bytes]]:
        self.heard += 1
        return []


def test_a_late_cia402_serving_loop_still_hears_the_host() -> None:
    channel = f"test-simbank-{uuid.uuid4().hex}"
    bus = can.Bus(interface="virtual", channel=channel)
    host = can.Bus(interface="virtual", channel=channel)
    drive = _SlowDrive.__new__(_SlowDrive)  # no canopen node: only step and handle are used
    stop = threading.Event()
    thread = threading.Thread(target=run_sim, args=(bus, [drive], stop), daemon=True)
    try:
        thread.start()
        sent = 0
        deadline = time.monotonic() + 60.0
        while drive.steps < 60 and time.monotonic() < deadline:
            host.send(can.Message(arbitration_id=0x201, data=b"\x0f\x00", is_extended_id=False))
            sent += 1
            time.sleep(0.002)
        assert drive.steps >= 60
        # what the host sent reaches the drive while every tick is late
        deadline = time.monotonic() + 60.0
        while drive.heard < sent - 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert drive.heard >= sent - 2, (drive.heard, sent, drive.steps)
    finally:
        stop.set()
        thread.join(5.0)
        bus.shutdown()
        host.shutdown()


def test_simulated_odrives_serve_a_fast_socket(
    pair: tuple[socket.socket, sf.FastSocketCan],
) -> None:
    """The ODrive serving loop on the fast path: an RTR request is answered by the node it
    names, before the first tick (no answer for a node not served), and the nodes' broadcasts
    arrive."""
    from drivers.odrive import cansimple as cs
    from drivers.odrive.sim import SimODriveAxis
    from drivers.odrive.sim import run_sim as run_odrives

    peer, fast = pair
    bus = can.Bus(interface="virtual", channel=f"test-simbank-{uuid.uuid4().hex}")
    axes = [SimODriveAxis(n, heartbeat_period_s=0.05, encoder_period_s=1000.0) for n in (0, 1)]
    for node in (1, 5):
        arb_id, _, _ = cs.encode_rtr(node, cs.GET_ENCODER_ESTIMATES)
        peer.send(sf.CAN_FRAME.pack(arb_id | sf.CAN_RTR_FLAG, 8, b""))
    stop = threading.Event()
    thread = threading.Thread(
        target=run_odrives, args=(bus, axes, stop), kwargs={"fast_path": fast}, daemon=True
    )
    thread.start()
    try:
        peer.settimeout(30.0)
        seen: list[cs.Message | cs.DecodeError] = []
        while not (
            any(isinstance(m, cs.EncoderEstimates) for m in seen)
            and {m.node_id for m in seen if isinstance(m, cs.Heartbeat)} == {0, 1}
        ):
            can_id, length, data = sf.CAN_FRAME.unpack(peer.recv(64))
            seen.append(cs.decode(can_id, data[:length]))
        # The queued request is answered before the first tick's broadcasts (both encoders
        # once, then not for 1000 s); node 5 is not served.
        estimates = [m.node_id for m in seen if isinstance(m, cs.EncoderEstimates)]
        assert estimates[0] == 1 and sorted(estimates[1:]) == [0, 1], estimates
    finally:
        stop.set()
        thread.join(5.0)
        bus.shutdown()
    assert not thread.is_alive()
