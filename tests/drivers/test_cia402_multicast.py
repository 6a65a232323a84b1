"""Cross-process: simulated CiA 402 drives in their own process (`python -m
drivers.cia402.sim`), CiA402Reels here, over udp_multicast kept on this host."""

from __future__ import annotations

import os
import random
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import can
import pytest

from drivers.bus import open_bus
from drivers.cia402 import CiA402Reels
from tests.sim_procs import REPO, poll_until, stop_sim

NODES = (1, 2, 3, 4)
INITIAL_REV = (0.0, 1.0, -2.0, 0.5)
CPR = 4096


def multicast_channel() -> tuple[str, int]:
    """A private IPv6 multicast group and port, so parallel tests never hear each other."""
    group = f"ff15:7079:7468:6f6e:6465:6d6f:6d63:{random.randrange(1, 0xFFFF):x}"
    return group, random.randrange(20_000, 60_000)


def start_cia402_sim(group: str, port: int, timeout_s: float = 30.0) -> subprocess.Popen[str]:
    """Start the simulated drives' process and wait (bounded) for its READY line."""
    args = [
        "--interface",
        "udp_multicast",
        "--channel",
        group,
        "--option",
        f"port={port}",
        "--nodes",
        ",".join(map(str, NODES)),
        "--initial-rev",
        ",".join(map(str, INITIAL_REV)),
        "--counts-per-rev",
        str(CPR),
        "--duration-s",
        "120",
    ]
    proc = subprocess.Popen(
        [sys.executable, "-m", "drivers.cia402.sim", *args],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    line: list[str] = []
    reader = threading.Thread(
        target=lambda: line.append(proc.stdout.readline() if proc.stdout else ""), daemon=True
    )
    reader.start()
    reader.join(timeout_s)
    if not line or line[0].strip() != "READY " + ",".join(map(str, NODES)):
        proc.kill()
        _, err = proc.communicate(timeout=30)
        raise AssertionError(f"sim process not ready within {timeout_s:.0f} s: {line!r} {err}")
    return proc


@pytest.fixture
def link() -> Iterator[tuple[str, int, can.BusABC]]:
    group, port = multicast_channel()
    bus = open_bus("udp_multicast", group, port=port)
    yield group, port, bus
    bus.shutdown()


def test_cross_process_configure_arm_command_estop(link: tuple[str, int, can.BusABC]) -> None:
    group, port, bus = link
    proc = start_cia402_sim(group, port)
    try:
        driver = CiA402Reels(bus, NODES, counts_per_rev=CPR, period_s=0.002, sdo_timeout_s=1.0)
        r = driver.read()
        driver.configure()
        assert poll_until(driver, lambda: all(x.stamp_ns and x.heartbeat_stamp_s > 0 for x in r))
        assert tuple(x.position_rev for x in r) == INITIAL_REV
        assert all(x.state_name == "Switch on disabled" for x in r)
        driver.arm()
        assert poll_until(driver, lambda: all(x.ready for x in r)), [x.state_name for x in r]
        targets = [1.25, -0.5, -1.0, 3.0]
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            driver.poll()
            driver.command(targets)
            if all(abs(x.position_rev - t) < 1e-3 for x, t in zip(r, targets, strict=True)):
                break
            time.sleep(0.002)
        assert all(abs(x.position_rev - t) < 1e-3 for x, t in zip(r, targets, strict=True)), [
            x.position_rev for x in r
        ]
        now = time.monotonic()
        assert all(now - x.stamp_s < 5.0 for x in r)
        assert all(abs(time.time_ns() - x.stamp_ns) < 5e9 for x in r)
        assert driver.stats.decode_errors == 0 and driver.stats.bus_errors == 0
        driver.estop()
        assert poll_until(
            driver,
            lambda: all(
                x.state_name in ("Quick stop active", "Switch on disabled") and x.axis_state == 1
                for x in r
            ),
        )
    finally:
        stop_sim(proc)
    assert proc.returncode == 0
    # the process is gone: every drive's heartbeat and position stamps age
    driver.poll()
    beats = [x.heartbeat_stamp_s for x in r]
    time.sleep(0.3)
    driver.poll()
    assert [x.heartbeat_stamp_s for x in r] == beats
    assert all(x.heartbeat_age_s(time.monotonic()) > 0.25 for x in r)
