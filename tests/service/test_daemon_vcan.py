"""The daemon, the simulated nodes and a Zenoh observer as three processes over SocketCAN vcan0.

The same scenario as tests/test_daemon.py (arm, move 1 m, arrive within 1 mm, SIGTERM exits 0
within 2 s) on a real kernel CAN interface. Marked `vcan`: run by `make test-vcan` (natively or
in the virtme-ng VM, where deadlines are scaled by the `slow_factor` fixture).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.daemon_procs import write_config
from tests.service.test_daemon import run_three_processes


@pytest.mark.vcan
@pytest.mark.slow
def test_daemon_sim_observer_over_vcan(
    tmp_path: Path, vcan_channel: str, slow_factor: float
) -> None:
    if slow_factor <= 1.0:
        rate_hz, sim, faults = 250.0, None, None
    else:
        # Under the emulated VM (Python 20-40x slower, 2 vCPUs for three processes plus
        # pytest) the simulated ODrives cannot tick at 1 kHz nor broadcast every 2 ms: slow the
        # whole robot down, as a slower real rig would be, and widen the fault windows to match.
        rate_hz = 25.0
        sim = {"tick_s": 0.005, "encoder_period_s": 0.02, "heartbeat_period_s": 0.2}
        faults = {
            "stale_timeout_s": 0.1 * slow_factor,
            "heartbeat_timeout_s": 1.0 * slow_factor,
            "arm_timeout_s": 5.0 * slow_factor,
            "tracking_max_m": 1.0,
        }
    cfg, info = write_config(
        tmp_path,
        {"interface": "socketcan", "channel": vcan_channel},
        rate_hz=rate_hz,
        sim=sim,
        faults=faults,
    )
    run_three_processes(cfg, info, slow=slow_factor)
