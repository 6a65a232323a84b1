"""The simulated ODrive node as a separate process, for the cross-process driver tests.

Used by tests/test_drivers_multicast.py (udp_multicast) and tests/test_drivers_vcan.py (vcan0).
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from drivers.odrive.driver import ODriveReels

REPO = Path(__file__).resolve().parents[1]


def start_sim(args: list[str], ready_timeout_s: float = 30.0) -> subprocess.Popen[str]:
    """Start `python -m drivers.odrive.sim ARGS` and wait (bounded) for its READY line."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "drivers.odrive.sim", *args],
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
    reader.join(ready_timeout_s)
    if not line or not line[0].startswith("READY"):
        proc.kill()
        _, err = proc.communicate(timeout=30)
        raise AssertionError(
            f"sim process not ready within {ready_timeout_s:.0f} s: {line!r} {err}"
        )
    return proc


def stop_sim(proc: subprocess.Popen[str], timeout_s: float = 10.0) -> None:
    """SIGTERM the sim process; SIGKILL it if it has not exited within `timeout_s`."""
    proc.terminate()
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=timeout_s)


def poll_until(driver: ODriveReels, cond: Callable[[], bool], timeout_s: float = 20.0) -> bool:
    """Poll the driver until `cond()` holds (True) or `timeout_s` passes (False)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        driver.poll()
        if cond():
            return True
        time.sleep(0.001)
    return False
