"""Cross-process: simulated ODrives in their own process, ODriveReels here, over udp_multicast."""

from __future__ import annotations

import math
import random
import time
from collections.abc import Iterator

import can
import pytest

from drivers.bus import open_bus
from drivers.odrive import cansimple as cs
from drivers.odrive.driver import ODriveReels
from tests.sim_procs import poll_until, start_sim, stop_sim

NODES = (0, 1, 2, 3)
INITIAL_REV = (0.0, 1.0, -2.0, 0.5)


def multicast_channel() -> tuple[str, int]:
    """A private IPv6 multicast group and port, so parallel tests never hear each other."""
    group = f"ff15:7079:7468:6f6e:6465:6d6f:6d63:{random.randrange(1, 0xFFFF):x}"
    return group, random.randrange(20_000, 60_000)


@pytest.fixture
def link() -> Iterator[tuple[str, int, can.BusABC]]:
    group, port = multicast_channel()
    bus = open_bus("udp_multicast", group, port=port)
    yield group, port, bus
    bus.shutdown()


def sim_args(group: str, port: int, *extra: str) -> list[str]:
    return [
        "--interface",
        "udp_multicast",
        "--channel",
        group,
        "--port",
        str(port),
        "--nodes",
        ",".join(map(str, NODES)),
        "--initial-rev",
        ",".join(map(str, INITIAL_REV)),
        "--duration-s",
        "120",
        *extra,
    ]


def test_cross_process_arm_command_read_back(link: tuple[str, int, can.BusABC]) -> None:
    group, port, bus = link
    proc = start_sim(sim_args(group, port))
    try:
        driver = ODriveReels(bus, NODES)
        r = driver.read()
        assert poll_until(driver, lambda: all(x.stamp_ns and x.heartbeat_stamp_s > 0 for x in r))
        assert tuple(x.position_rev for x in r) == INITIAL_REV
        assert all(x.axis_state == cs.AxisState.IDLE for x in r)
        driver.arm()
        assert poll_until(driver, lambda: all(x.axis_state == 8 for x in r))
        targets = [1.25, -0.5, -1.0, 3.0]
        driver.command(targets)
        assert poll_until(
            driver,
            lambda: all(
                x.position_rev == t and x.velocity_rps == 0.0
                for x, t in zip(r, targets, strict=True)
            ),
        ), [(x.position_rev, x.velocity_rps) for x in r]
        # encoder frames are fresh: stamped on arrival, recent, wall clock set
        now = time.monotonic()
        assert all(now - x.stamp_s < 5.0 for x in r)
        assert all(abs(time.time_ns() - x.stamp_ns) < 5e9 for x in r)
        assert driver.stats.decode_errors == 0 and driver.stats.bus_errors == 0
        driver.estop()
        assert poll_until(
            driver,
            lambda: all(
                x.axis_state == 1 and x.axis_error & cs.ODriveError.ESTOP_REQUESTED for x in r
            ),
        )
    finally:
        stop_sim(proc)
    assert proc.returncode == 0


def test_cross_process_rtr_polling_and_silent_node(link: tuple[str, int, can.BusABC]) -> None:
    """With the cyclic encoder broadcast effectively off, estimates arrive only by RTR polling."""
    group, port, bus = link
    proc = start_sim(sim_args(group, port, "--encoder-period-s", "1000"))
    try:
        driver = ODriveReels(bus, NODES, encoder_rtr=True)
        r = driver.read()
        # the one broadcast at start-up may be missed; RTR answers keep arriving
        assert poll_until(driver, lambda: all(x.stamp_ns for x in r))
        first = [x.stamp_s for x in r]
        assert poll_until(driver, lambda: all(x.stamp_s > f for x, f in zip(r, first, strict=True)))
        assert all(math.isfinite(x.position_rev) for x in r)
    finally:
        stop_sim(proc)
    # the process is gone: every axis goes silent and check() says so (readings are stamped when
    # decoded, so drain what it sent before it ended first)
    driver.poll()
    time.sleep(0.3)
    driver.poll()
    kinds = {(f.node_id, f.kind) for f in driver.check(0.25, 0.25)}
    assert {(n, "silent") for n in NODES} <= kinds
