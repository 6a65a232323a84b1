"""The CiA 402 driver over a real SocketCAN vcan0 (run by `make test-vcan`).

The simulated drives serve on a bus of their own on the same interface. On the fast path (the
default on SocketCAN): configure by SDO through python-can's `recv` on the filtered socket, arm,
command and read back, every cycle in one system call; the kernel filter keeps other nodes'
frames, host traffic and extended ids away from Python (the counters say so) while error
frames still arrive. The stock path (python-can and canopen) runs the same scenario once.
Deadlines are scaled by the `slow_factor` fixture (Python runs 20-40x slower in the VM).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import can
import pytest

from drivers.base import NEVER_S
from drivers.bus import open_bus
from drivers.cia402 import CiA402Reels
from drivers.cia402.sim import SimCiA402Bank
from tests.drivers.test_cia402_driver import poll_until

pytestmark = [pytest.mark.vcan, pytest.mark.timeout(900)]

# Node ids away from the daemon test's so a stray process of another vcan test cannot answer.
NODES = (50, 51, 52, 53)
CPR = 4096
PERIOD_S = 0.01
INITIAL_REV = (0.0, 0.5, -1.25, 2.0)


@pytest.fixture
def driver_bus(vcan_channel: str) -> Iterator[can.BusABC]:
    bus = open_bus("socketcan", vcan_channel)
    yield bus
    bus.shutdown()


def _driver(bus: can.BusABC, slow_factor: float, *, fast: bool) -> CiA402Reels:
    return CiA402Reels(
        bus,
        NODES,
        counts_per_rev=CPR,
        period_s=PERIOD_S,
        heartbeat_period_s=0.2,
        sdo_timeout_s=min(10.0, 0.3 * slow_factor),
        fast_path=fast,
    )


@pytest.mark.parametrize("fast", [True, False], ids=["fast", "stock"])
def test_configure_arm_command_read_back(
    fast: bool,
    driver_bus: can.BusABC,
    vcan_bus_factory: Callable[..., can.BusABC],
    slow_factor: float,
    vcan_report: list[str],
) -> None:
    bank = SimCiA402Bank(
        vcan_bus_factory(), NODES, initial_position_rev=INITIAL_REV, counts_per_rev=CPR
    ).start()
    try:
        driver = _driver(driver_bus, slow_factor, fast=fast)
        assert driver.fast_path is fast
        t0 = time.monotonic()
        driver.configure()  # SDO answers pass the kernel filter, read by python-can's recv
        configure_s = time.monotonic() - t0
        r = driver.read()
        wait_s = 20.0 * slow_factor
        assert poll_until(
            driver, lambda: all(x.stamp_ns and x.heartbeat_stamp_s > NEVER_S for x in r), wait_s
        ), [str(x) for x in r]
        assert [x.position_rev for x in r] == list(INITIAL_REV)
        driver.arm()
        assert poll_until(driver, lambda: all(x.ready for x in r), wait_s), [
            x.state_name for x in r
        ]
        targets = [1.0, -0.75, 0.3, 2.5]
        sent = driver._fast.send_calls if driver._fast is not None else 0
        syncs = driver._syncs_sent
        cycles = 0
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline:
            driver.poll()
            driver.command(targets)
            cycles += 1
            if all(abs(x.position_rev - t) < 1e-3 for x, t in zip(r, targets, strict=True)):
                break
        assert all(abs(x.position_rev - t) < 1e-3 for x, t in zip(r, targets, strict=True)), [
            x.position_rev for x in r
        ]
        if driver._fast is not None:
            # One system call per cycle: 4 RPDO1, 4 RPDO2 and the SYNC.
            assert driver._fast.send_calls - sent == driver._syncs_sent - syncs >= cycles
        s = driver.stats
        assert s.decode_errors == 0 and s.bus_errors == 0, s
        assert s.errors_by_kind.get("unknown_cob_id", 0) == 0, s
        assert s.errors_by_kind.get("not_for_host", 0) == 0, s  # SocketCAN: no own echo
        vcan_report.append(
            f"cia402 ({'fast' if fast else 'stock'} path): 4 drives configured in "
            f"{configure_s:.2f} s, armed and moved over vcan0 in {cycles} cycles"
        )
    finally:
        assert bank.stop(timeout_s=10.0 * slow_factor)


def test_fast_path_kernel_filter_and_error_frames(
    driver_bus: can.BusABC,
    vcan_bus_factory: Callable[..., can.BusABC],
    slow_factor: float,
) -> None:
    """Only our drives' TPDO1/EMCY/SDO-answer/heartbeat frames, another master's SYNC and error
    frames reach Python: another node's frames, SDO requests, RPDOs, extended ids and remote
    frames stay in the kernel, and the counters show none of them. Our own SYNC is never heard
    back; another's is a named conflict (two masters on one bus)."""
    driver = _driver(driver_bus, slow_factor, fast=True)
    assert driver.fast_path
    driver.request_encoders()  # our own SYNC: not handed back by the kernel
    tx = vcan_bus_factory()
    ours = NODES[1]
    plan = [
        can.Message(arbitration_id=0x180 + 9, data=bytes(8), is_extended_id=False),  # other TPDO
        can.Message(arbitration_id=0x700 + 9, data=b"\x05", is_extended_id=False),  # other node
        can.Message(arbitration_id=0x600 + ours, data=bytes(8), is_extended_id=False),  # SDO req
        can.Message(arbitration_id=0x080, data=b"", is_extended_id=False),  # SYNC
        can.Message(arbitration_id=0x200 + ours, data=bytes(6), is_extended_id=False),  # RPDO1
        can.Message(arbitration_id=0x700 + ours, data=b"\x05", is_extended_id=True),
        can.Message(arbitration_id=0x180 + ours, is_remote_frame=True, dlc=8, is_extended_id=False),
        can.Message(arbitration_id=0x4, is_error_frame=True, dlc=8, data=bytes(8)),
        can.Message(arbitration_id=0x700 + ours, data=b"\x7f", is_extended_id=False),  # ours
    ]
    for msg in plan:
        tx.send(msg, timeout=1.0)
    taken = 0
    deadline = time.monotonic() + 10.0 * slow_factor
    while driver.reading(ours).heartbeat_stamp_s == NEVER_S and time.monotonic() < deadline:
        taken += driver.poll()
    assert driver.reading(ours).heartbeat_stamp_s > NEVER_S
    assert driver.drive_status(ours).nmt_state == "PRE-OPERATIONAL"
    s = driver.stats
    assert taken == 3 == s.frames_rx, s
    assert s.errors_by_kind == {"error_frame": 1, "another_master": 1}, s
    assert s.conflicts == 1 and "another SYNC producer" in str(s.last_conflict)
    assert s.last_error == "CAN error frame 0x4"
    assert s.decode_errors == 0 and s.commands_heard == 0
    # A stock socket on the same interface heard what the filter kept away.
    stock = vcan_bus_factory(receive_own_messages=False)
    tx.send(plan[0], timeout=1.0)
    got = stock.recv(timeout=5.0 * slow_factor)
    assert got is not None and got.arbitration_id == 0x189
    assert driver.poll() == 0
