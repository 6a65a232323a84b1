"""The daemon, the simulated drives and a Zenoh observer as three processes over SocketCAN vcan0.

The same scenarios as tests/test_daemon.py on a real kernel CAN interface: ODrive nodes (arm,
move 1 m, arrive within 1 mm, SIGTERM exits 0 within 2 s) and CiA 402 drives from
config/cia402-sim.toml (SDO set-up at start, arm, move 0.2 m, arrive within 1 mm, e-stop
confirmed by every drive, SIGTERM). Both drivers run on the SocketCAN fast path (the daemon
says so). Marked `vcan`: run by `make test-vcan` (natively or in the
virtme-ng VM, where deadlines are scaled by the `slow_factor` fixture).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.daemon_procs import write_config
from tests.service.test_daemon import CIA402_SIM, run_three_processes


def _vm_settings(slow_factor: float) -> tuple[float, dict[str, Any] | None, dict[str, Any] | None]:
    """Loop rate, [sim] and [faults] keys for this host: as on the udp_multicast test natively;
    under the emulated VM (Python 20-40x slower, 2 vCPUs for three processes plus pytest) the
    simulated drives cannot tick at 1 kHz nor broadcast every 2 ms: slow the whole robot down,
    as a slower real rig would be, and widen the fault windows to match."""
    if slow_factor <= 1.0:
        return 250.0, None, None
    sim = {"tick_s": 0.005, "encoder_period_s": 0.02, "heartbeat_period_s": 0.2}
    faults = {
        "stale_timeout_s": 0.1 * slow_factor,
        "heartbeat_timeout_s": 1.0 * slow_factor,
        "arm_timeout_s": 5.0 * slow_factor,
        "tracking_max_m": 1.0,
        # The simulated drives' process stalls for hundreds of ms between the four axes'
        # encoder frames of one broadcast: a tick can read two axes a stall apart, whose cable
        # lengths disagree by more than 20 mm at 1 m/s. The SocketCAN fast path takes what has
        # arrived at once, which makes such a tick likelier than python-can's slower reads.
        "residual_max_m": 0.1,
    }
    return 25.0, sim, faults


@pytest.mark.vcan
@pytest.mark.slow
def test_daemon_sim_observer_over_vcan(
    tmp_path: Path, vcan_channel: str, slow_factor: float
) -> None:
    rate_hz, sim, faults = _vm_settings(slow_factor)
    if sim is not None:
        # The simulated ODrives' axis watchdog idles an axis that heard no command for this
        # long; the emulated VM stalls the daemon for hundreds of ms (compute p99 ~0.3 s).
        sim = {**sim, "watchdog_timeout_s": min(10.0, 0.3 * slow_factor)}
    cfg, info = write_config(
        tmp_path,
        {"interface": "socketcan", "channel": vcan_channel},
        rate_hz=rate_hz,
        sim=sim,
        faults=faults,
    )
    # The ODrive driver reads and writes vcan0 through the SocketCAN fast path.
    run_three_processes(
        cfg, info, slow=slow_factor, daemon_says=f"SocketCAN fast path on {vcan_channel}"
    )


@pytest.mark.vcan
@pytest.mark.slow
def test_cia402_daemon_sim_observer_over_vcan(
    tmp_path: Path, vcan_channel: str, slow_factor: float
) -> None:
    rate_hz, sim, faults = _vm_settings(slow_factor)
    # The drives answer every SYNC (no broadcast periods); their heartbeat and each SDO
    # answer of the start-up set-up come from the simulated drives' process: slow them down
    # and wait longer for them as for the ODrive nodes. 25 Hz = 40 ms, an exact CiA 402
    # interpolation period.
    drive: dict[str, Any] | None = None
    if slow_factor > 1.0:
        drive = {"heartbeat_period_s": 0.2, "sdo_timeout_s": min(10.0, 0.3 * slow_factor)}
        if faults is not None:
            faults["tracking_max_m"] = 0.2  # the desk rig's workspace is 0.9 m across
    cfg, info = write_config(
        tmp_path,
        {"interface": "socketcan", "channel": vcan_channel},
        rate_hz=rate_hz,
        sim=sim,
        faults=faults,
        base=CIA402_SIM,
        drive=drive,
    )
    # The CiA 402 driver reads and writes vcan0 through the SocketCAN fast path too.
    run_three_processes(
        cfg,
        info,
        slow=slow_factor,
        kind="cia402",
        move_m=0.2,
        speed_mps=0.3,
        estop=True,
        daemon_says=f"SocketCAN fast path on {vcan_channel}",
    )
