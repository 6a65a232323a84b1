"""The driver over a real SocketCAN vcan0, the simulated ODrives in a separate process.

Run by `make test-vcan` (natively where the kernel has vcan, else in the virtme-ng VM, where
Python is several times slower: every deadline is scaled by the `slow_factor` fixture).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Iterator

import can
import pytest

from drivers.bus import open_bus
from drivers.odrive import cansimple as cs
from drivers.odrive.driver import ODriveReels
from tests.sim_procs import poll_until, start_sim, stop_sim

# Generous: under the emulated VM each step takes several times longer than on a host.
pytestmark = [pytest.mark.vcan, pytest.mark.timeout(900)]

# Node ids away from 0..3 so a stray process of another vcan test cannot answer for ours.
NODES = (20, 21, 22, 23)
INITIAL_REV = (0.0, 1.0, -2.0, 0.5)


@pytest.fixture
def vcan_driver_bus(vcan_channel: str) -> Iterator[can.BusABC]:
    bus = open_bus("socketcan", vcan_channel)
    yield bus
    bus.shutdown()


def sim_args(channel: str, *extra: str) -> list[str]:
    return [
        "--interface",
        "socketcan",
        "--channel",
        channel,
        "--nodes",
        ",".join(map(str, NODES)),
        "--initial-rev",
        ",".join(map(str, INITIAL_REV)),
        "--duration-s",
        "600",
        *extra,
    ]


def test_vcan_arm_command_read_back(
    vcan_channel: str, vcan_driver_bus: can.BusABC, slow_factor: float, vcan_report: list[str]
) -> None:
    proc = start_sim(sim_args(vcan_channel), 30.0 * slow_factor)
    try:
        driver = ODriveReels(vcan_driver_bus, NODES)
        assert driver.fast_path  # SocketCAN: the kernel socket directly
        r = driver.read()
        wait_s = 10.0 * slow_factor
        assert poll_until(
            driver, lambda: all(x.stamp_ns and x.heartbeat_stamp_s > 0 for x in r), wait_s
        )
        assert tuple(x.position_rev for x in r) == INITIAL_REV
        assert all(x.axis_state == cs.AxisState.IDLE for x in r)
        driver.arm()
        assert poll_until(driver, lambda: all(x.axis_state == 8 for x in r), wait_s)
        targets = [1.25, -0.5, -1.0, 3.0]
        t0 = time.monotonic()
        driver.command(targets)
        assert poll_until(
            driver,
            lambda: all(
                x.position_rev == t and x.velocity_rps == 0.0
                for x, t in zip(r, targets, strict=True)
            ),
            wait_s,
        ), [(x.position_rev, x.velocity_rps) for x in r]
        vcan_report.append(
            f"drivers: 4 axes armed, commanded and settled over {vcan_channel} in "
            f"{time.monotonic() - t0:.3f} s (sim process)"
        )
        assert driver.stats.decode_errors == 0 and driver.stats.bus_errors == 0
        assert driver.stats.errors_by_kind.get("not_for_host", 0) == 0  # socketcan: no echo
        driver.estop()
        assert poll_until(
            driver,
            lambda: all(
                x.axis_state == 1 and x.axis_error & cs.ODriveError.ESTOP_REQUESTED for x in r
            ),
            wait_s,
        )
    finally:
        stop_sim(proc, 30.0)
    assert proc.returncode == 0


def test_vcan_rtr_round_trip(
    vcan_channel: str, vcan_driver_bus: can.BusABC, slow_factor: float, vcan_report: list[str]
) -> None:
    """Encoder estimates by RTR only (cyclic broadcast off): every request is answered."""
    proc = start_sim(sim_args(vcan_channel, "--encoder-period-s", "1000"), 30.0 * slow_factor)
    try:
        driver = ODriveReels(vcan_driver_bus, NODES)
        r = driver.read()
        assert poll_until(
            driver, lambda: all(x.heartbeat_stamp_s > 0 for x in r), 10.0 * slow_factor
        )
        driver.poll()
        rtts: list[float] = []
        for _ in range(20):
            before = [x.stamp_s for x in r]
            t0 = time.monotonic()
            driver.request_encoders()
            assert poll_until(
                driver,
                lambda b=before: all(x.stamp_s > s for x, s in zip(r, b, strict=True)),  # type: ignore[misc]
                5.0 * slow_factor,
            )
            rtts.append(time.monotonic() - t0)
        assert tuple(x.position_rev for x in r) == INITIAL_REV
        vcan_report.append(
            f"drivers: RTR encoder poll of 4 axes over {vcan_channel}: median "
            f"{statistics.median(rtts) * 1e3:.2f} ms, max {max(rtts) * 1e3:.2f} ms"
        )
    finally:
        stop_sim(proc, 30.0)
