"""`drivers.simbank.take_queued`: a late tick hears the host first, within one tick's time;
and the CiA402 serving loop, late on every tick, still hears the host."""

from __future__ import annotations

import threading
import time
import uuid

import can

from drivers.cia402.sim import SimCiA402Drive, run_sim
from drivers.simbank import take_queued


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


def test_take_queued_takes_every_waiting_frame_and_a_flood_for_one_budget_only() -> None:
    got: list[can.Message] = []
    bus = _QueueBus(50)
    assert take_queued(bus, got.append, 60.0) == 50  # type: ignore[arg-type]
    assert len(got) == 50 and bus.n == 0
    flood = _QueueBus(-1)
    t0 = time.monotonic()
    taken = take_queued(flood, lambda m: time.sleep(0.001), 0.02)  # type: ignore[arg-type]
    took_s = time.monotonic() - t0
    assert 1 <= taken <= 21 and took_s >= 0.02  # the budget ends it, not the (endless) queue


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
