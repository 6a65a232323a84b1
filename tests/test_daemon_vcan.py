"""The daemon, the simulated nodes and a Zenoh observer as three processes over SocketCAN vcan0.

The same scenario as tests/test_daemon.py (arm, move 1 m, arrive within 1 mm, SIGTERM exits 0
within 2 s) on a real kernel CAN interface. Marked `vcan`: run by `make test-vcan` (natively or
in the virtme-ng VM, where deadlines are scaled by the `slow_factor` fixture).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.daemon_procs import write_config
from tests.test_daemon import run_three_processes


@pytest.mark.vcan
@pytest.mark.slow
def test_daemon_sim_observer_over_vcan(
    tmp_path: Path, vcan_channel: str, slow_factor: float
) -> None:
    cfg, info = write_config(
        tmp_path,
        {"interface": "socketcan", "channel": vcan_channel},
        # Under the emulated VM everything is slower: a lower rate and wider stale windows.
        rate_hz=250.0 if slow_factor <= 1.0 else 100.0,
        faults={"stale_timeout_s": 0.05 * slow_factor, "heartbeat_timeout_s": 0.5 * slow_factor},
    )
    run_three_processes(cfg, info, slow=slow_factor)
