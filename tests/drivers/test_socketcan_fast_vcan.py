"""The SocketCAN fast path on a real kernel CAN interface (run by `make test-vcan`).

Frames in both directions with the kernel's timestamps, the kernel receive filters (only the
configured nodes' data frames and error frames reach Python), no own-frame echo, and errors of
an interface that is down counted rather than raised.
"""

from __future__ import annotations

import socket
import subprocess
import time
import uuid
from collections.abc import Callable, Iterator

import can
import pytest

from drivers import socketcan_fast as sf
from drivers.base import BusError
from drivers.bus import open_bus
from drivers.odrive import cansimple as cs
from drivers.odrive.driver import ODriveReels

pytestmark = [pytest.mark.vcan, pytest.mark.timeout(600)]

NODES = (40, 41, 42, 43)


@pytest.fixture
def driver_bus(vcan_channel: str) -> Iterator[can.BusABC]:
    bus = open_bus("socketcan", vcan_channel)
    yield bus
    bus.shutdown()


def _poll_until(driver: ODriveReels, cond: Callable[[], bool], deadline_s: float) -> int:
    """Poll `driver` until `cond()`; returns the frames taken; fails after the deadline."""
    taken = 0
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        taken += driver.poll()
        if cond():
            return taken
    pytest.fail(f"condition not met within {deadline_s:.1f} s")


def test_fast_path_filters_stamps_and_error_frames(
    driver_bus: can.BusABC,
    vcan_bus_factory: Callable[..., can.BusABC],
    slow_factor: float,
) -> None:
    """Only our nodes' data frames and error frames reach the driver: other nodes, extended ids
    and RTR requests stay in the kernel; readings carry the kernel's receive time."""
    driver = ODriveReels(driver_bus, NODES)
    assert driver.fast_path
    tx = vcan_bus_factory()
    enc = cs.encode_encoder_estimates(41, 2.5, -1.0)
    other = cs.encode_encoder_estimates(5, 9.0, 9.0)
    before = time.monotonic()
    plan = [
        can.Message(arbitration_id=other[0], data=other[1], is_extended_id=False),
        can.Message(arbitration_id=enc[0], data=enc[1], is_extended_id=True),
        can.Message(arbitration_id=enc[0], is_remote_frame=True, dlc=8, is_extended_id=False),
        can.Message(arbitration_id=0x4, is_error_frame=True, dlc=8, data=bytes(8)),
        can.Message(arbitration_id=enc[0], data=enc[1], is_extended_id=False),
    ]
    for msg in plan:
        tx.send(msg, timeout=1.0)
    taken = _poll_until(driver, lambda: driver.reading(41).stamp_ns != 0, 10.0 * slow_factor)
    r = driver.reading(41)
    assert (r.position_rev, r.velocity_rps) == (2.5, -1.0)
    assert before - 0.5 < r.stamp_s <= time.monotonic()
    s = driver.stats
    assert taken == 2 == s.frames_rx, s
    assert s.errors_by_kind == {"error_frame": 1}, s
    assert s.last_error == "CAN error frame 0x4"
    assert s.decode_errors == 0 and s.dropped == 0 and s.untimed_frames == 0
    # A stock socket on the same interface heard everything the filter kept away.
    stock = vcan_bus_factory(receive_own_messages=False)
    tx.send(can.Message(arbitration_id=other[0], data=other[1], is_extended_id=False))
    got = stock.recv(timeout=5.0 * slow_factor)
    assert got is not None and got.arbitration_id == other[0]
    assert driver.poll() == 0


def test_fast_path_sends_a_tick_in_one_call_and_hears_no_echo(
    driver_bus: can.BusABC,
    vcan_bus_factory: Callable[..., can.BusABC],
    slow_factor: float,
) -> None:
    """A tick's Set_Input_Pos frames leave in one system call, in order, byte-exact; the
    driver's own frames (which would pass its filter) never come back to it."""
    driver = ODriveReels(driver_bus, NODES)
    fast = driver._fast
    assert fast is not None
    rx = vcan_bus_factory()
    calls = fast.send_calls
    driver.command([0.5, -0.5, 1.0, 2.0], [0.1, 0.2, 0.3, 0.4])
    assert fast.send_calls == calls + 1
    assert driver.stats.frames_tx == 4
    want = [
        cs.encode_set_input_pos(n, p, v, 0.0)
        for n, p, v in zip(NODES, [0.5, -0.5, 1.0, 2.0], [0.1, 0.2, 0.3, 0.4], strict=True)
    ]
    for arb_id, data, _ in want:
        got = rx.recv(timeout=5.0 * slow_factor)
        assert got is not None
        assert (got.arbitration_id, bytes(got.data), got.is_extended_id) == (arb_id, data, False)
    driver.request_encoders()
    got = rx.recv(timeout=5.0 * slow_factor)
    assert got is not None and got.is_remote_frame and got.dlc == 8
    assert got.arbitration_id == cs.arbitration_id(NODES[0], cs.GET_ENCODER_ESTIMATES)
    assert driver.poll() == 0
    assert driver.stats.commands_heard == 0


def test_fast_path_drains_a_burst_in_batches(
    driver_bus: can.BusABC,
    vcan_bus_factory: Callable[..., can.BusABC],
    slow_factor: float,
) -> None:
    """200 queued frames come out in a handful of receive calls, none lost, last value kept."""
    driver = ODriveReels(driver_bus, NODES, max_frames_per_poll=1000)
    fast = driver._fast
    assert fast is not None
    tx = vcan_bus_factory()
    for i in range(200):
        f = cs.encode_encoder_estimates(NODES[i % 4], float(i), 0.0)
        tx.send(can.Message(arbitration_id=f[0], data=f[1], is_extended_id=False), timeout=1.0)
    taken = _poll_until(
        driver, lambda: driver.reading(NODES[3]).position_rev == 199.0, 10.0 * slow_factor
    )
    assert taken == 200 and driver.stats.frames_rx == 200
    assert fast.recv_calls < 50  # batched: one call per frame would be 200
    assert [driver.reading(n).position_rev for n in NODES] == [196.0, 197.0, 198.0, 199.0]
    assert fast.kernel_drops == 0


def test_interface_down_is_counted_not_raised(slow_factor: float) -> None:
    """On an interface that goes down, a send fails with ENETDOWN per frame (BusError) and a
    poll counts the receive error; neither raises into the loop's poll."""
    name = f"cbf{uuid.uuid4().hex[:8]}"
    subprocess.run(["ip", "link", "add", "dev", name, "type", "vcan"], check=True)
    try:
        subprocess.run(["ip", "link", "set", "up", name], check=True)
        bus = open_bus("socketcan", name)
        try:
            driver = ODriveReels(bus, NODES)
            assert driver.fast_path
            subprocess.run(["ip", "link", "set", "down", name], check=True)
            driver.poll()  # the socket reports the interface going down once
            with pytest.raises(BusError, match="ENETDOWN"):
                driver.command([0.0] * 4)
            assert driver.stats.frames_tx == 0
            assert driver.stats.bus_errors >= 4
            assert "ENETDOWN" in (driver.stats.last_error or "")
        finally:
            bus.shutdown()
    finally:
        subprocess.run(["ip", "link", "del", "dev", name], check=False)


def test_receive_queue_overrun_is_counted(
    driver_bus: can.BusABC,
    vcan_bus_factory: Callable[..., can.BusABC],
    slow_factor: float,
) -> None:
    """Frames the kernel drops while the loop does not poll (a full receive queue) are counted
    as dropped, kind "rx_overrun", from the socket's drop counter; the frames kept still read."""
    sock = sf.socket_of(driver_bus)
    assert sock is not None
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # the kernel's minimum
    driver = ODriveReels(driver_bus, NODES, max_frames_per_poll=10_000)
    tx = vcan_bus_factory()
    for i in range(500):
        f = cs.encode_encoder_estimates(NODES[0], float(i), 0.0)
        tx.send(can.Message(arbitration_id=f[0], data=f[1], is_extended_id=False), timeout=1.0)
    taken = driver.poll()
    assert 0 < taken < 500
    # The kernel reports the count with the next frame it queues.
    f = cs.encode_encoder_estimates(NODES[0], 500.0, 0.0)
    tx.send(can.Message(arbitration_id=f[0], data=f[1], is_extended_id=False), timeout=1.0)
    taken += _poll_until(
        driver, lambda: driver.reading(NODES[0]).position_rev == 500.0, 10.0 * slow_factor
    )
    s = driver.stats
    assert s.errors_by_kind.get("rx_overrun", 0) == 501 - taken == s.dropped > 0
    assert s.bus_errors == 0


def test_a_can_fd_bus_keeps_python_can(vcan_channel: str) -> None:
    """A bus opened for CAN FD receives 72-byte frames, which the fast path's 16-byte slots
    would cut to 8 data bytes: both drivers keep python-can's path on it."""
    from drivers.cia402 import CiA402Reels

    bus = open_bus("socketcan", vcan_channel, fd=True)
    try:
        assert sf.socket_of(bus) is not None
        assert sf.open_fast_path(bus, [(0, 0x7E0)]) is None
        assert not ODriveReels(bus, NODES).fast_path
        assert not CiA402Reels(bus, (44,), counts_per_rev=4096, period_s=0.002).fast_path
    finally:
        bus.shutdown()
