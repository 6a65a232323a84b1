"""Real SocketCAN frames through vcan0 with python-can (run by `make test-vcan`).

These prove the bus itself works (natively or in the virtme-ng VM) before the driver and daemon
tests build on it: data and remote frames, standard and extended ids, kernel filters, a
cross-process echo, and the round-trip times printed in the summary.
"""

from __future__ import annotations

import itertools
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

import can
import pytest

pytestmark = pytest.mark.vcan

N_FRAMES = 300


def _frame(i: int) -> can.Message:
    """The i-th frame of the bulk test: every DLC 0..8, standard and extended ids."""
    dlc = i % 9
    extended = i % 5 == 4
    arbitration_id = (0x1ABC0000 + i) if extended else (0x100 + i) & 0x7FF
    data = bytes((i * 7 + k) & 0xFF for k in range(dlc))
    return can.Message(arbitration_id=arbitration_id, is_extended_id=extended, data=data)


def _recv_or_fail(bus: can.BusABC, deadline_s: float) -> can.Message:
    """Receive one frame, failing the test if none arrives within ``deadline_s``."""
    msg = bus.recv(timeout=deadline_s)
    if msg is None:
        pytest.fail(f"no frame within {deadline_s:.1f} s")
    return msg


def test_frames_cross_between_two_buses(
    vcan_bus_factory: Callable[..., can.BusABC], vcan_channel: str, slow_factor: float
) -> None:
    """300 frames from one socket arrive intact, in order, on another; the sender hears none."""
    tx = vcan_bus_factory()
    rx = vcan_bus_factory()
    sent = [_frame(i) for i in range(N_FRAMES)]
    received: list[can.Message] = []
    for msg in sent:
        tx.send(msg, timeout=1.0)
        # Receive as we go so the socket receive buffer can never overflow.
        received.append(_recv_or_fail(rx, 2.0 * slow_factor))

    assert len(received) == N_FRAMES
    for want, got in zip(sent, received, strict=True):
        assert got.arbitration_id == want.arbitration_id
        assert got.is_extended_id == want.is_extended_id
        assert got.dlc == want.dlc
        assert bytes(got.data) == bytes(want.data)
        assert not got.is_remote_frame
        assert not got.is_error_frame
        assert got.channel == vcan_channel
    assert rx.recv(timeout=0.05) is None, "an extra frame arrived"
    assert tx.recv(timeout=0.0) is None, "the sender received its own frame"
    # Kernel timestamps must be increasing wall-clock seconds.
    stamps = [m.timestamp for m in received]
    assert all(b >= a for a, b in itertools.pairwise(stamps))
    assert abs(stamps[-1] - time.time()) < 60.0


def test_remote_frame(vcan_bus_factory: Callable[..., can.BusABC], slow_factor: float) -> None:
    """An RTR frame (the CANSimple encoder poll) keeps its id and DLC and carries no data."""
    tx = vcan_bus_factory()
    rx = vcan_bus_factory()
    tx.send(
        can.Message(
            arbitration_id=(3 << 5) | 0x09, is_extended_id=False, is_remote_frame=True, dlc=8
        )
    )
    got = _recv_or_fail(rx, 2.0 * slow_factor)
    assert got.is_remote_frame
    assert got.arbitration_id == 0x69
    assert not got.is_extended_id
    assert got.dlc == 8
    assert len(got.data) == 0


def test_kernel_filter_passes_only_matching_frames(
    vcan_bus_factory: Callable[..., can.BusABC], slow_factor: float
) -> None:
    """A filtered socket gets only its ids; an open socket gets all frames and no error frame."""
    tx = vcan_bus_factory()
    everything = vcan_bus_factory()
    filtered = vcan_bus_factory(
        can_filters=[
            {"can_id": 0x123, "can_mask": 0x7FF, "extended": False},
            {"can_id": 0x7FF, "can_mask": 0x7FF, "extended": False},  # sentinel
        ]
    )
    plan = [
        can.Message(arbitration_id=0x122, is_extended_id=False, data=b"\x01"),
        can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x02"),
        can.Message(arbitration_id=0x124, is_extended_id=False, data=b"\x03"),
        can.Message(arbitration_id=0x123, is_extended_id=True, data=b"\x04"),
        can.Message(arbitration_id=0x523, is_extended_id=False, data=b"\x05"),
        can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x06"),
        can.Message(arbitration_id=0x7FF, is_extended_id=False, data=b"\xff"),
    ]
    for msg in plan:
        tx.send(msg)

    got_filtered: list[can.Message] = []
    while not got_filtered or got_filtered[-1].arbitration_id != 0x7FF:
        got_filtered.append(_recv_or_fail(filtered, 2.0 * slow_factor))
    assert [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in got_filtered] == [
        (0x123, False, b"\x02"),
        (0x123, False, b"\x06"),
        (0x7FF, False, b"\xff"),
    ]
    assert filtered.recv(timeout=0.05) is None

    got_all = [_recv_or_fail(everything, 2.0 * slow_factor) for _ in plan]
    assert [bytes(m.data) for m in got_all] == [bytes(m.data) for m in plan]
    assert not any(m.is_error_frame for m in got_all)
    assert everything.recv(timeout=0.05) is None


def _median_ms(samples_s: list[float]) -> float:
    return statistics.median(samples_s) * 1e3


def test_round_trip_in_process(
    vcan_bus_factory: Callable[..., can.BusABC],
    slow_factor: float,
    under_vm: bool,
    vcan_report: list[str],
) -> None:
    """Ping-pong between two sockets of one process; report the median round trip."""
    a = vcan_bus_factory(can_filters=[{"can_id": 0x601, "can_mask": 0x7FF, "extended": False}])
    b = vcan_bus_factory(can_filters=[{"can_id": 0x600, "can_mask": 0x7FF, "extended": False}])
    samples_s: list[float] = []
    for i in range(200):
        payload = i.to_bytes(4, "little")
        t0 = time.perf_counter()
        a.send(can.Message(arbitration_id=0x600, is_extended_id=False, data=payload))
        ping = _recv_or_fail(b, 2.0 * slow_factor)
        b.send(can.Message(arbitration_id=0x601, is_extended_id=False, data=bytes(ping.data)))
        pong = _recv_or_fail(a, 2.0 * slow_factor)
        samples_s.append(time.perf_counter() - t0)
        assert bytes(pong.data) == payload
    median_ms = _median_ms(samples_s)
    where = "VM" if under_vm else "native"
    vcan_report.append(
        f"in-process round trip on vcan0 ({where}): median {median_ms:.3f} ms, "
        f"p95 {statistics.quantiles(samples_s, n=20)[-1] * 1e3:.3f} ms over {len(samples_s)}"
    )
    assert median_ms < 5.0 * slow_factor


_ECHO_CHILD = """
import sys, can
bus = can.Bus(interface="socketcan", channel=sys.argv[1],
              can_filters=[{"can_id": 0x610, "can_mask": 0x7FF, "extended": False}])
bus.send(can.Message(arbitration_id=0x611, is_extended_id=False, data=b"ready"))
while True:
    msg = bus.recv(timeout=float(sys.argv[2]))
    if msg is None or bytes(msg.data) == b"bye":
        break
    bus.send(can.Message(arbitration_id=0x611, is_extended_id=False, data=bytes(msg.data)))
bus.shutdown()
"""


def test_round_trip_cross_process(
    vcan_bus_factory: Callable[..., Any],
    vcan_channel: str,
    slow_factor: float,
    under_vm: bool,
    vcan_report: list[str],
) -> None:
    """A child process echoes frames back over vcan0; report the median round trip."""
    me = vcan_bus_factory(can_filters=[{"can_id": 0x611, "can_mask": 0x7FF, "extended": False}])
    idle_s = 10.0 * slow_factor
    child = subprocess.Popen([sys.executable, "-c", _ECHO_CHILD, vcan_channel, str(idle_s)])
    try:
        t_start = time.perf_counter()
        ready = _recv_or_fail(me, 30.0 * slow_factor)
        startup_s = time.perf_counter() - t_start
        assert bytes(ready.data) == b"ready"
        samples_s: list[float] = []
        for i in range(200):
            payload = (0xC0DE0000 + i).to_bytes(4, "big")
            t0 = time.perf_counter()
            me.send(can.Message(arbitration_id=0x610, is_extended_id=False, data=payload))
            echo = _recv_or_fail(me, 2.0 * slow_factor)
            samples_s.append(time.perf_counter() - t0)
            assert bytes(echo.data) == payload
        me.send(can.Message(arbitration_id=0x610, is_extended_id=False, data=b"bye"))
        assert child.wait(timeout=10.0 * slow_factor) == 0
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    median_ms = _median_ms(samples_s)
    where = "VM" if under_vm else "native"
    vcan_report.append(
        f"cross-process round trip on vcan0 ({where}): median {median_ms:.3f} ms, "
        f"p95 {statistics.quantiles(samples_s, n=20)[-1] * 1e3:.3f} ms over {len(samples_s)}; "
        f"child start-up to first frame {startup_s:.2f} s"
    )
    assert median_ms < 10.0 * slow_factor
