"""`cablebot sim`: the simulated drives as their own process get the daemon loop's scheduling."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from controller.cli import exitcodes
from tests.daemon_procs import CABLEBOT, Proc, udp_bus, write_config


def fifo_threads(pid: int) -> list[tuple[int, int]]:
    """(thread id, SCHED_FIFO priority) of every SCHED_FIFO thread of process `pid`."""
    out: list[tuple[int, int]] = []
    for name in os.listdir(f"/proc/{pid}/task"):
        tid = int(name)
        try:
            if os.sched_getscheduler(tid) == os.SCHED_FIFO:
                out.append((tid, os.sched_getparam(tid).sched_priority))
        except OSError:  # the thread ended meanwhile
            continue
    return out


def test_the_sim_process_serves_at_the_loop_real_time_priority(tmp_path: Path) -> None:
    # A sim at normal priority beside a real-time daemon loop starves on a busy machine and
    # its drives look stale (stale_encoder): it gets the in-process simulator's scheduling.
    cfg, _info = write_config(tmp_path, udp_bus(), loop={"realtime": True, "rt_priority": 20})
    sim = Proc([*CABLEBOT, "sim", "--config", str(cfg)], "sim")
    try:
        sim.wait_line("READY", 30)
        line = sim.wait_line("simulated ODrive nodes", 10, stderr=True)
        if "not available" in line:
            pytest.skip(f"this machine grants no SCHED_FIFO: {line}")
        assert "SCHED_FIFO priority 19" in line, line
        assert [prio for _tid, prio in fifo_threads(sim.p.pid)] == [19], sim.log()
    finally:
        assert sim.terminate() == 0, sim.log()


def test_the_sim_process_stays_at_normal_priority_without_loop_realtime(tmp_path: Path) -> None:
    cfg, _info = write_config(tmp_path, udp_bus())  # loop.realtime = false
    sim = Proc([*CABLEBOT, "sim", "--config", str(cfg)], "sim")
    try:
        sim.wait_line("READY", 30)
        line = sim.wait_line("simulated ODrive nodes", 10, stderr=True)
        assert "SCHED_OTHER (loop.realtime = false)" in line, line
        assert fifo_threads(sim.p.pid) == []
    finally:
        assert sim.terminate() == 0, sim.log()


def test_sim_without_the_bus_says_so_in_one_line(tmp_path: Path) -> None:
    """A SocketCAN interface this machine lacks: one clean line and exit 1 (as `run`), no
    traceback (its own process: `sim` sets up the process's logging)."""
    cfg, _info = write_config(
        tmp_path, {"interface": "socketcan", "channel": "nocan-sim9", "bitrate": 1_000_000}
    )
    cp = subprocess.run(
        [*CABLEBOT, "sim", "--config", str(cfg)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert cp.returncode == exitcodes.REFUSED, cp.stderr
    assert "Traceback" not in cp.stderr
    lines = [ln for ln in cp.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, cp.stderr
    assert "start-up failed" in lines[0] and "nocan-sim9" in lines[0], cp.stderr
