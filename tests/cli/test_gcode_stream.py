"""`cablebot gcode FILE`: a job streamed to a real daemon on the simulated robot as a path and
appends, resting at its waits; Ctrl-C brakes to a hold; a job out of the workspace moves
nothing."""

from __future__ import annotations

import json
import math
import signal
import time
from pathlib import Path

import pytest

from controller.cli import exitcodes
from tests.cli.test_monitor import Tmux, tmux_available  # noqa: F401 (a fixture)
from tests.daemon_procs import CABLEBOT, Proc
from tests.live_daemon import Daemon, live_daemon, wait_holding_at_rest


def _cli(d: Daemon, cfg: Path, job: Path, *extra: str) -> Proc:
    return Proc(
        [
            *CABLEBOT,
            "gcode",
            str(job),
            "--config",
            str(cfg),
            "--connect",
            d.endpoint,
            "--prefix",
            d.prefix,
            *extra,
        ],
        "gcode",
    )


def _circle(n: int, r_mm: float, z_mm: float) -> list[str]:
    out = []
    for k in range(n + 1):
        a = 2 * math.pi * k / n
        out.append(f"G1 X{r_mm * math.cos(a):.3f} Y{r_mm * math.sin(a):.3f} Z{z_mm:.1f}")
    return out


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_job_streams_in_chunks_and_ends_at_its_last_point(tmp_path: Path) -> None:
    # 2,404 moves: more than two path commands' worth (1,000 points each), a dwell between
    # them (the robot rests, then a new path starts), and a modal feed change
    lines = ["G21", "G90", "M83", "G1 X300 Y0 Z2000 F30000", "M104 S200", "F60000"]
    lines += _circle(1200, 300.0, 2000.0)
    lines += ["G4 P200", "M114", "G1 F45000"]
    lines += _circle(1200, 300.0, 2100.0)
    lines += ["G1 X0 Y0 Z2100 E1", "M400"]
    job = tmp_path / "job.gcode"
    job.write_text("\n".join(lines) + "\n")
    with live_daemon(tmp_path) as (d, cfg):
        cli = _cli(d, cfg, job, "--wait")
        rc = cli.p.wait(240.0)
        assert rc == exitcodes.OK, cli.log()
        done = cli.wait_line("gcode: done:", 5.0)
        assert f"{len(lines)} lines, 2404 moves in" in done, done
        commands = int(done.split(" moves in ")[1].split()[0])
        assert commands >= 4, done  # 1,202 + 1,202 points at two speeds: several chunks
        m114 = cli.wait_line("M114 (line 1209): ", 5.0)
        assert "X:300.000" in m114 and "Z:2000.000 E:0.000" in m114, m114
        st = wait_holding_at_rest(d, 30.0)
        assert st["setpoint_m"] == pytest.approx([0.0, 0.0, 2.1], abs=1e-9)
        assert st["pose"]["position_m"] == pytest.approx([0.0, 0.0, 2.1], abs=1e-4)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_ctrl_c_stops_the_job_and_brakes_to_a_hold(tmp_path: Path) -> None:
    job = tmp_path / "long.gcode"
    job.write_text("G1 X0 Y0 Z2000 F30000\nG1 X12000\nG1 X0\n")  # 24 m at 0.5 m/s
    with live_daemon(tmp_path) as (d, cfg):
        cli = _cli(d, cfg, job, "--wait")
        deadline = time.monotonic() + 60.0
        while d.status()["state"] != "MOVING":
            assert time.monotonic() < deadline, cli.log()
            time.sleep(0.05)
        cli.p.send_signal(signal.SIGINT)
        rc = cli.p.wait(60.0)
        assert rc == exitcodes.INTERRUPTED, cli.log()
        cli.wait_line("interrupted: braking to a hold", 10.0, stderr=True)
        held = wait_holding_at_rest(d, 30.0)
        x = held["pose"]["position_m"][0]
        assert 0.0 < x < 11.0, held  # it moved, then stopped short of the far end
        kind, reply = d.query(
            "cmd/path", json.dumps({"points_m": [[0.0, 0.0, 2.0]], "append": True}).encode()
        )
        assert kind == "err", reply  # the stopped job takes no more appends


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_job_out_of_the_workspace_moves_nothing(tmp_path: Path) -> None:
    job = tmp_path / "out.gcode"
    job.write_text("G1 X1000 Y0 Z2000 F6000\nG1 Z-5 ; under the floor\n")
    with live_daemon(tmp_path) as (d, cfg):
        before = d.status()["setpoint_m"]
        cli = _cli(d, cfg, job)
        rc = cli.p.wait(120.0)
        assert rc == exitcodes.REFUSED, cli.log()
        cli.wait_line("line 2: refused: point [1.0000, 0.0000, -0.0050]", 5.0, stderr=True)
        st = d.status()
        assert st["state"] == "HOLDING" and st["setpoint_m"] == before


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.usefixtures("tmux_available")
def test_progress_line_on_a_terminal(tmp_path: Path) -> None:
    job = tmp_path / "slow.gcode"
    job.write_text("G1 X0 Y0 Z2000 F30000\nG1 F24000\n" + "\n".join(_circle(200, 500.0, 2000.0)))
    with live_daemon(tmp_path) as (d, cfg):
        argv = [*CABLEBOT, "gcode", str(job), "--config", str(cfg), "--wait"]
        term = Tmux([*argv, "--connect", d.endpoint, "--prefix", d.prefix])
        try:
            live = term.wait_for(
                "the progress line", lambda s: "gcode: line" in s and "remaining ~" in s, 120.0
            )
            assert "moves " in live and "/202" in live and "elapsed " in live, live
            done = term.wait_for("the end", lambda s: "gcode: done:" in s, 180.0)
            assert "gcode: line" not in done, done  # the progress line is erased at the end
            assert term.dead_status() in (None, 0)
        finally:
            term.kill()
