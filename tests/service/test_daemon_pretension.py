"""`cablebot home X Y Z --pretension` through the daemon, as a user runs it: the simulated
ODrives carrying the payload (physical plant) in their own process, the daemon in another, the
CLI in a third, over udp_multicast on this host."""

from __future__ import annotations

import math
import signal
import subprocess
import time
import tomllib
from pathlib import Path
from typing import Any

import pytest

from tests.daemon_procs import (
    CABLEBOT,
    REPO,
    Proc,
    to_toml,
    udp_bus,
    write_config,
    zenoh_session,
    zquery,
)


def _cli(info: dict[str, Any], *args: str, timeout_s: float) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*CABLEBOT, *args, "--connect", info["endpoint"], "--prefix", info["prefix"]],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        cwd=REPO,
    )


@pytest.mark.slow
def test_home_with_pretension_through_the_daemon_then_move(tmp_path: Path) -> None:
    cfg, info = write_config(
        tmp_path,
        udp_bus(),
        loop={"torque_telemetry": "cyclic"},
        sim={
            "plant": "physical",
            "cable_ea_n": 2e5,
            "torque_period_s": 0.01,
            # the simulator and the daemon are processes of a loaded host: either may stall
            "watchdog_timeout_s": 3.0,
            # the pre-tension waits for the effector to be still: every mode damped critically
            "cable_damping_ratio": 1.0,
            "effector_damping_n_s_per_m": 5.0,
        },
        drive={"velocity_limit_rps": 100.0, "current_limit_a": 10.0},
        faults={"heartbeat_timeout_s": 2.0},
    )
    data = tomllib.loads(cfg.read_text())
    # Stillness judged to 0.2 mm/s of cable over 3 s (the paper robot's slow swings).
    data["homing"].update(pretension_still_mps=0.0002, pretension_settle_s=3.0)
    cfg.write_text(to_toml(data))
    home = (0.3, 0.0, 2.0)  # the effector hangs at (0, 0, 2): the pulls draw it over here
    sim = Proc([*CABLEBOT, "sim", "--config", str(cfg)], "sim")
    daemon: Proc | None = None
    try:
        sim.wait_line("READY", 60)
        daemon = Proc([*CABLEBOT, "run", "--config", str(cfg)], "daemon")
        daemon.wait_line("ready:", 60, stderr=True)
        done = _cli(
            info,
            "home",
            *map(str, home),
            "--pretension",
            "--wait-timeout",
            "90",
            timeout_s=120,
        )
        assert done.returncode == 0, f"{done.stdout}\n{done.stderr}\n{daemon.log()}"
        lines = done.stdout.splitlines()
        assert lines[0].startswith("pretension: the reels pull in torque control with 10"), lines
        assert lines[-1].startswith("pretension: still after "), lines
        assert "homed at x=+0.3000 y=+0.0000 z=+2.0000 m; offsets (turns) node 0 " in lines[-1]
        assert "; saved to " in lines[-1] and "; measured tensions " in lines[-1]
        daemon.wait_line("PRETENSIONING -> HOLDING: pretension: still after", 30, stderr=True)
        session = zenoh_session(info["endpoint"])
        try:
            st = zquery(session, f"{info['prefix']}/status")
            assert st["state"] == "HOLDING" and st["home_source"] == "pretension", st["reason"]
            assert math.dist(st["pose"]["position_m"], home) < 0.002
            res = st["pretension"]["result"]
            assert res["ok"] and res["saved"] and res["state_file"] == str(info["state_file"])
            planned = st["tensions"]["planned_n"]
            measured = st["tensions"]["measured_n"]
            assert measured == pytest.approx(planned, rel=0.02), (measured, planned)
        finally:
            session.close()
        assert Path(info["state_file"]).exists()
        moved = _cli(info, "move", "1.3", "0.5", "2.3", "--wait", timeout_s=60)
        assert moved.returncode == 0, f"{moved.stdout}\n{moved.stderr}\n{daemon.log()}"
        assert moved.stdout.splitlines()[-1].startswith("arrived:")
        daemon.p.send_signal(signal.SIGTERM)
        assert daemon.p.wait(30) == 0, daemon.log()
    finally:
        if daemon is not None:
            daemon.kill()
        assert sim.terminate() == 0, sim.log()


def test_home_with_pretension_is_refused_on_the_kinematic_simulator_before_anything_moves(
    tmp_path: Path,
) -> None:
    """The shipped paper robot's set-up: `cablebot sim` in its own process with the kinematic
    plant (nothing hangs on the reels). `home --pretension` is refused by name; the reels never
    leave position control and the pose stays where it was."""
    cfg, info = write_config(
        tmp_path, udp_bus(), sim={"watchdog_timeout_s": 3.0}, faults={"heartbeat_timeout_s": 2.0}
    )
    sim = Proc([*CABLEBOT, "sim", "--config", str(cfg)], "sim")
    daemon: Proc | None = None
    try:
        sim.wait_line("READY", 60)
        daemon = Proc([*CABLEBOT, "run", "--config", str(cfg)], "daemon")
        daemon.wait_line("ready:", 60, stderr=True)
        armed = _cli(info, "arm", timeout_s=60)
        assert armed.returncode == 0, armed.stderr
        session = zenoh_session(info["endpoint"])
        try:
            deadline = time.monotonic() + 30.0
            while (st := zquery(session, f"{info['prefix']}/status"))["state"] != "HOLDING":
                assert time.monotonic() < deadline, st
                time.sleep(0.1)
            before = st["pose"]["position_m"]
            done = _cli(info, "home", "0", "0", "2", "--pretension", timeout_s=60)
            assert done.returncode == 1, f"{done.stdout}\n{done.stderr}"
            assert done.stdout == ""
            assert done.stderr.startswith(
                "cablebot: refused: pretension: the reels are the kinematic simulator's "
                "(simulated drives on udp_multicast "
            ), done.stderr
            assert 'give the robot file [sim] plant = "physical"' in done.stderr
            st = zquery(session, f"{info['prefix']}/status")
            assert st["state"] == "HOLDING", st
            assert math.dist(st["pose"]["position_m"], before) < 1e-4
        finally:
            session.close()
        assert "PRETENSIONING" not in daemon.log()
    finally:
        if daemon is not None:
            assert daemon.terminate() == 0, daemon.log()
        assert sim.terminate() == 0, sim.log()
