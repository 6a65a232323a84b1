"""The daemon is the authority on its robot: a real daemon started with its own robot file,
whose `[gcode] origin_m` is not the built-in robot's, serves that file on `<prefix>/robot`; a
G-code job sent without `--config` lands where the daemon's table puts it, a `--config` of
another robot is refused by name; `gcode` brakes on SIGTERM and SIGHUP; a long path file is
checked whole before anything moves; a speed above the robot's maximum is refused by name."""

from __future__ import annotations

import hashlib
import math
import signal
import subprocess
import time
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from controller.cli import exitcodes
from tests.daemon_procs import CABLEBOT, Proc, to_toml
from tests.live_daemon import Daemon, live_daemon, wait_holding_at_rest

ORIGIN_M = (-0.1075, -0.1075, 0.1)
"""The daemon's G-code origin (the built-in robot's is (0, 0, 0))."""
SQUARE = "G21\nG90\nG1 X0 Y0 Z1900 F30000\nG1 X500 Y0\nG1 X500 Y500\nG1 X0 Y500\nG1 X0 Y0\nM400\n"


@pytest.fixture(scope="module")
def shop(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Daemon, Path]]:
    tmp = tmp_path_factory.mktemp("shop")
    with live_daemon(tmp, {"gcode": {"origin_m": list(ORIGIN_M)}}) as dc:
        yield dc


def _run(d: Daemon, *args: str, timeout_s: float = 180.0) -> subprocess.CompletedProcess[str]:
    return d.cli(*args, timeout_s=timeout_s)


def _counts(d: Daemon) -> dict[str, int]:
    commands: dict[str, int] = d.status()["zenoh"]["commands"]
    return commands


def _other_robot(cfg: Path, tmp: Path) -> Path:
    """The daemon's robot file with the built-in G-code origin: another robot."""
    data = tomllib.loads(cfg.read_text())
    data.pop("gcode")
    other = tmp / "other.toml"
    other.write_text(to_toml(data))
    return other


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_the_daemon_serves_its_robot_file_as_loaded(shop: tuple[Daemon, Path]) -> None:
    d, cfg = shop
    kind, robot = d.query("robot")
    assert kind == "ok", robot
    text = cfg.read_text()
    assert robot["toml"] == text
    assert robot["digest"] == "sha256:" + hashlib.sha256(text.encode()).hexdigest()
    assert robot["name"] == d.prefix.split("/")[-1] and robot["source"] == str(cfg)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_job_without_config_lands_where_the_daemons_gcode_table_says(
    shop: tuple[Daemon, Path], tmp_path: Path
) -> None:
    d, _ = shop
    job = tmp_path / "square.gcode"
    job.write_text(SQUARE)
    r = _run(d, "gcode", str(job), "--wait")
    assert r.returncode == exitcodes.OK, r.stderr
    assert "gcode: done: 8 lines, 5 moves" in r.stdout, r.stdout
    st = wait_holding_at_rest(d, 30.0)
    # G-code X0 Y0 Z1900 is the daemon's origin + (0, 0, 1.9 m), not the built-in (0, 0, 1.9)
    assert st["setpoint_m"] == pytest.approx([ORIGIN_M[0], ORIGIN_M[1], 2.0], abs=1e-9)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_config_of_another_robot_is_refused_by_name_and_its_own_accepted(
    shop: tuple[Daemon, Path], tmp_path: Path
) -> None:
    d, cfg = shop
    job = tmp_path / "square.gcode"
    job.write_text(SQUARE)
    other = _other_robot(cfg, tmp_path)
    before, counts = d.status()["setpoint_m"], _counts(d)
    for extra in ([str(job)], ["--serial", str(tmp_path / "tty")]):
        r = _run(d, "gcode", *extra, "--config", str(other))
        assert r.returncode == exitcodes.REFUSED, (extra, r.stderr)
        assert f"--config {other} (robot '{d.prefix.split('/')[-1]}') is not the robot" in r.stderr
        assert "gcode.origin_m ([0, 0, 0] in --config, [-0.1075, -0.1075, 0.1] at the daemon)" in (
            r.stderr
        )
        assert r.stdout == ""
    assert d.status()["setpoint_m"] == before and _counts(d) == counts  # nothing was sent
    r = _run(d, "gcode", str(job), "--wait", "--config", str(cfg))
    assert r.returncode == exitcodes.OK, r.stderr
    st = wait_holding_at_rest(d, 30.0)
    assert st["setpoint_m"] == pytest.approx([ORIGIN_M[0], ORIGIN_M[1], 2.0], abs=1e-9)


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_gcode_wait_brakes_to_a_hold_on_sigterm_and_sighup(
    shop: tuple[Daemon, Path], tmp_path: Path, sig: signal.Signals
) -> None:
    d, _ = shop
    r = _run(d, "move", str(ORIGIN_M[0]), str(ORIGIN_M[1]), "2", "--wait")
    assert r.returncode == exitcodes.OK, r.stderr  # at the job's start (x < 1 m)
    job = tmp_path / "long.gcode"
    job.write_text("G1 X0 Y0 Z1900 F30000\nG1 X12000\nG1 X0\n")  # 24 m at 0.5 m/s
    cli = Proc(
        [*CABLEBOT, "gcode", str(job), "--wait", "--connect", d.endpoint, "--prefix", d.prefix],
        "gcode",
    )
    deadline = time.monotonic() + 60.0
    while d.status()["setpoint_m"][0] < 1.0:  # well on its way to x = 12 m
        assert time.monotonic() < deadline and cli.p.poll() is None, cli.log()
        time.sleep(0.05)
    cli.p.send_signal(sig)
    rc = cli.p.wait(60.0)
    assert rc == exitcodes.INTERRUPTED, cli.log()
    cli.wait_line("interrupted: braking to a hold", 10.0, stderr=True)
    held = wait_holding_at_rest(d, 30.0)
    x = held["pose"]["position_m"][0]
    assert 1.0 < x < 4.0, held  # stopped near where the signal came (0.5 m/s, 1 m/s^2)
    time.sleep(1.0)  # the job goes on no more: nothing queued after the stop
    assert d.status()["setpoint_m"] == held["setpoint_m"]


def _circle_csv(path: Path, n: int, bad_line: int) -> None:
    lines = ["x,y,z"]
    for i in range(n):
        a = 2.0 * math.pi * i / 500.0
        lines.append(f"{3.0 * math.cos(a):.4f},{3.0 * math.sin(a):.4f},2")
    lines[bad_line - 1] = "100,0,2"  # line numbers from 1: the header is line 1
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_long_path_file_is_checked_whole_before_anything_moves(
    shop: tuple[Daemon, Path], tmp_path: Path
) -> None:
    d, _ = shop
    f = tmp_path / "long.csv"
    _circle_csv(f, 5000, 4000)
    before, counts = d.status()["setpoint_m"], _counts(d)
    r = _run(d, "path", str(f), "--wait")
    assert r.returncode == exitcodes.REFUSED, r.stderr
    assert f"{f} line 4000: refused: point [100.0000, 0.0000, 2.0000]: " in r.stderr, r.stderr
    assert "nothing was sent" in r.stderr and "points_m[" not in r.stderr
    assert d.status()["setpoint_m"] == before and _counts(d) == counts


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_speed_above_the_robots_maximum_is_refused_by_name(shop: tuple[Daemon, Path]) -> None:
    d, _ = shop
    counts: dict[str, Any] = _counts(d)
    r = _run(d, "move", "0", "0", "2", "--speed", "300")
    assert r.returncode == exitcodes.REFUSED
    assert r.stderr == (
        "cablebot: --speed 300 m/s is above the robot's limits.max_speed_mps (2 m/s): give at"
        " most 2 (the unit is m/s)\n"
    )
    assert _counts(d) == counts  # refused before anything was sent


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_gcode_serial_stops_on_sigterm(shop: tuple[Daemon, Path], tmp_path: Path) -> None:
    d, _ = shop
    link = tmp_path / "tty"
    cli = Proc(
        [*CABLEBOT, "gcode", "--serial", str(link), "--connect", d.endpoint, "--prefix", d.prefix],
        "serial",
    )
    cli.wait_line(f"gcode: serial port {link} -> /dev/pts/", 30.0)
    cli.p.send_signal(signal.SIGTERM)
    assert cli.p.wait(30.0) == exitcodes.INTERRUPTED, cli.log()
    cli.wait_line("interrupted: braking to a hold", 10.0, stderr=True)
    assert not link.exists()  # the link to the pseudo-terminal is removed
