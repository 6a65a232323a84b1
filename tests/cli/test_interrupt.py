"""Ctrl-C on `cablebot move --wait` stops the robot (brakes to a hold) and says so; with
`--detach` it only stops waiting. A real daemon process and SIGINT to the CLI process."""

from __future__ import annotations

import math
import signal
import time
from pathlib import Path

import pytest

from controller.cli import exitcodes
from tests.daemon_procs import CABLEBOT, Proc
from tests.live_daemon import Daemon, live_daemon, wait_holding_at_rest

TARGET_X_M = 10.0  # 20 s away at 0.5 m/s: still moving when Ctrl-C comes


def _start_move(d: Daemon, *extra: str) -> Proc:
    cli = Proc(
        [
            *CABLEBOT,
            "move",
            str(TARGET_X_M),
            "0",
            "2",
            "--speed",
            "0.5",
            "--wait",
            "--connect",
            d.endpoint,
            "--prefix",
            d.prefix,
            *extra,
        ],
        "move",
    )
    cli.wait_line("move: to", 60.0)
    deadline = time.monotonic() + 30.0
    while d.status()["state"] != "MOVING":
        assert time.monotonic() < deadline, cli.log()
        time.sleep(0.05)
    return cli


def _interrupt(cli: Proc) -> int:
    cli.p.send_signal(signal.SIGINT)
    rc = cli.p.wait(60.0)
    return rc


@pytest.mark.slow
def test_ctrl_c_on_move_wait_brakes_to_a_hold_unless_detached(tmp_path: Path) -> None:
    with live_daemon(tmp_path) as (d, _cfg):
        cli = _start_move(d)
        rc = _interrupt(cli)
        assert rc == exitcodes.INTERRUPTED, cli.log()
        cli.wait_line("interrupted: braking to a hold", 10.0, stderr=True)
        cli.wait_line("stop: braking to a hold", 10.0)
        held = wait_holding_at_rest(d, 30.0)
        x_held = held["pose"]["position_m"][0]
        assert 0.0 < x_held < TARGET_X_M - 1.0, held  # it moved, then stopped short of the target
        later = d.latest_pose()
        assert later["state"] == "HOLDING"
        assert math.isclose(later["position_m"][0], x_held, abs_tol=1e-3)

        cli = _start_move(d, "--detach")
        rc = _interrupt(cli)
        assert rc == exitcodes.INTERRUPTED, cli.log()
        cli.wait_line("interrupted: detached", 10.0, stderr=True)
        assert d.status()["state"] == "MOVING"  # the motion goes on
        kind, _ = d.query("cmd/stop")
        assert kind == "ok"


@pytest.mark.slow
def test_another_clients_stop_ends_a_move_wait_at_once(tmp_path: Path) -> None:
    """`move --wait` whose motion another client stops reports the stop as soon as the robot
    holds (exit 1, the reason named), as it does an e-stop, not after `--wait-timeout`."""
    with live_daemon(tmp_path) as (d, _cfg):
        wait_holding_at_rest(d, 30.0)
        cli = _start_move(d, "--wait-timeout", "600")
        kind, _ = d.query("cmd/stop")
        assert kind == "ok"
        t_stop = time.monotonic()
        rc = cli.p.wait(60.0)
        waited_s = time.monotonic() - t_stop
        assert rc == exitcodes.REFUSED, cli.log()
        line = cli.wait_line("accepted, then the motion ended", 5.0, stderr=True)
        assert "stopped by a `stop` command" in line, line
        assert "short of x=+10.000 y=+0.000 z=+2.000 m" in line, line
        assert waited_s < 30.0, (waited_s, cli.log())  # braking takes 0.25 s at 0.5 m/s
        st = d.status()
        assert st["state"] == "HOLDING" and st["reason"] == "stopped by a `stop` command", st
        # a motion that arrives carries no such reason
        target = [v + 0.01 for v in st["setpoint_m"]]
        done = Proc(
            [
                *CABLEBOT,
                *("move", *(f"{v:.6f}" for v in target), "--wait"),
                *("--connect", d.endpoint, "--prefix", d.prefix),
            ],
            "move-again",
        )
        assert done.p.wait(60.0) == exitcodes.OK, done.log()
        assert d.status()["reason"] is None
