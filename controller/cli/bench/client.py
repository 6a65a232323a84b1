"""The client library's section: a long path streamed from a script through the library
(`Robot.stream_path`, then `Robot.wait`) against the same path streamed by the CLI (`cablebot
path FILE --wait`), both to one daemon, back to back.

The daemon is the built-in robot in a process of its own (simulated drives in-process, on a
`virtual` bus: nothing leaves the process; Zenoh on a free loopback port; the stale-reading and
heartbeat timeouts widened so that a starved process on a busy machine does not fault the run).
The path is a spiral through the robot's power-up pose, its points `CLIENT_SPACING_M` apart,
flown at `CLIENT_SPEED_MPS`; the daemon's queue paces both clients (each sends a chunk when
less than 3 s of motion is queued), so the wall time of each is the flight plus its own start
and end.
Each side is a fresh process, timed from its start to its exit (wall clock), with its CPU time
(user + system, from the kernel's accounting of the finished child). Between the runs the
robot is moved back to the spiral's start (not timed). `script_over_cli` is the ratio of the
wall times of the one run; `cpu_script_over_cli` that of the CPU times.
"""

from __future__ import annotations

import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from controller.cli.bench.settings import (
    CHILD_START_TIMEOUT_S,
    CLIENT_KEYS,
    CLIENT_SPACING_M,
    CLIENT_SPEED_MPS,
    TARGET_SCRIPT_OVER_CLI,
    BenchError,
    Plan,
)
from controller.cli.bench.table import Row

START_M = (0.0, 0.0, 2.0)

SCRIPT = """
import sys
from controller.client import Robot, load_path_file

path, endpoint, prefix, speed = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])
points = load_path_file(path, stream=True)["points_m"]
with Robot(endpoint, prefix) as robot:
    progress = robot.stream_path(points, speed_mps=speed)
    pose = robot.wait(timeout_s=600.0)
print(progress.sent, progress.commands, pose.position_m)
"""
"""What a script does to stream a path file (the library's own reader of it, as the CLI's)."""


def spiral(n_points: int, spacing_m: float) -> list[tuple[float, float, float]]:
    """An Archimedean spiral from `START_M` outwards, `n_points` points `spacing_m` apart along
    it (1 cm between turns). Raises ValueError for fewer than 2 points."""
    if n_points < 2:
        raise ValueError("a spiral needs at least 2 points")
    pitch_m = 0.01 / (2.0 * math.pi)
    out = [START_M]
    theta = 0.0
    for _ in range(n_points - 1):
        r = pitch_m * theta
        theta += spacing_m / math.hypot(r, pitch_m)
        r = pitch_m * theta
        out.append((START_M[0] + r * math.cos(theta), START_M[1] + r * math.sin(theta), START_M[2]))
    return out


def _daemon_config(tmp: Path) -> tuple[Path, str, str]:
    from controller.service.config import paper_robot_data
    from controller.service.config.tomltext import to_toml
    from controller.service.zenoh_io import free_tcp_port

    name = f"bench-client-{os.getpid()}"
    data: dict[str, Any] = paper_robot_data(name)
    data["bus"] = {"interface": "virtual", "channel": name}
    data["sim"] = {"enabled": True, "watchdog_timeout_s": 2.0}
    # This measures the clients: a daemon starved on a busy machine must not fault the run.
    data["faults"] = {**data["faults"], "stale_timeout_s": 2.0, "heartbeat_timeout_s": 4.0}
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    data["zenoh"] = {
        "prefix": f"cablebot/{name}",
        "mode": "peer",
        "listen": [endpoint],
        "multicast_scouting": False,
    }
    path = tmp / f"{name}.toml"
    path.write_text(to_toml(data))
    return path, endpoint, f"cablebot/{name}"


def _timed(argv: list[str], timeout_s: float) -> tuple[float, float, str]:
    """Run `argv` to its end: (wall s, CPU s of the child, its stdout). Raises BenchError when
    it fails."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s, check=False)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise BenchError(f"{argv[1:4]} exited {done.returncode}: {done.stderr.strip()[-400:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, done.stdout


def bench_client(n_points: int, log: Callable[[str], None] = lambda m: None) -> dict[str, float]:
    """Stream an `n_points` spiral through a daemon by the CLI and by a script on the library;
    the wall and CPU seconds of each and their ratios (`CLIENT_KEYS`). Raises BenchError."""
    from controller.client.errors import ClientError

    pts = spiral(n_points, CLIENT_SPACING_M)
    flight_s = sum(math.dist(pts[k - 1], pts[k]) for k in range(1, len(pts))) / CLIENT_SPEED_MPS
    with tempfile.TemporaryDirectory(prefix="cablebot-bench-client-") as d:
        tmp = Path(d)
        cfg, endpoint, prefix = _daemon_config(tmp)
        path_file = tmp / "spiral.csv"
        path_file.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in pts))
        script = tmp / "stream.py"
        script.write_text(SCRIPT)
        daemon = subprocess.Popen(
            [sys.executable, "-m", "controller.cli", "run", "--config", str(cfg)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            robot = _connect(endpoint, prefix)
            with robot:
                speed = str(CLIENT_SPEED_MPS)
                timeout_s = 120.0 + 3.0 * flight_s
                cli = [sys.executable, "-m", "controller.cli", "path", str(path_file)]
                cli += ["--speed", speed, "--wait", "--wait-timeout", str(timeout_s)]
                cli += ["--connect", endpoint, "--prefix", prefix]
                log(f"  cablebot path: {n_points:,} points, about {flight_s:.0f} s of flight ...")
                cli_s, cli_cpu, _ = _timed(cli, timeout_s)
                robot.move(START_M)
                robot.wait(120.0)
                log(f"  a script on the library: the same {n_points:,} points ...")
                argv = [sys.executable, str(script), str(path_file), endpoint, prefix, speed]
                script_s, script_cpu, out = _timed(argv, timeout_s)
                if not out.startswith(f"{n_points} "):
                    raise BenchError(f"the script streamed something else: {out.strip()}")
        except ClientError as exc:
            raise BenchError(f"client library: {exc}") from None
        finally:
            daemon.terminate()
            try:
                daemon.wait(10.0)
            except subprocess.TimeoutExpired:
                daemon.kill()
                daemon.wait(5.0)
    return {
        "points": float(n_points),
        "flight_s": flight_s,
        "cli_s": cli_s,
        "script_s": script_s,
        "script_over_cli": script_s / cli_s,
        "cli_cpu_s": cli_cpu,
        "script_cpu_s": script_cpu,
        "cpu_script_over_cli": script_cpu / cli_cpu,
    }


def _connect(endpoint: str, prefix: str) -> Any:
    """A Robot on the daemon once it holds its power-up pose. Raises BenchError."""
    from controller.client import Robot
    from controller.client.errors import ClientError

    deadline = time.monotonic() + CHILD_START_TIMEOUT_S
    while True:
        try:
            robot = Robot(endpoint, prefix, timeout_s=2.0)
        except ClientError:
            robot = None
        if robot is not None:
            try:
                while time.monotonic() < deadline:
                    if robot.status().state == "HOLDING":
                        return robot
                    time.sleep(0.1)
            except ClientError:
                pass
            robot.close()
        if time.monotonic() > deadline:
            raise BenchError("the bench daemon did not hold its pose in time")
        time.sleep(0.2)


def measure_client(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """The client section's JSON figures (`CLIENT_KEYS`) and table rows. Raises BenchError."""
    log(f"a {p.client_points:,}-point path: the CLI and a script on the library ...")
    f = bench_client(p.client_points, log)
    ratio = f["script_over_cli"]
    rep = f"one run each, {p.client_points:,} points"
    rows = [
        Row(
            "client_stream.script_over_cli",
            ratio,
            "ratio",
            f"<= {TARGET_SCRIPT_OVER_CLI:g}",
            ratio <= TARGET_SCRIPT_OVER_CLI,
            f"{rep}; script {f['script_s']:.1f} s, CLI {f['cli_s']:.1f} s"
            f" (flight {f['flight_s']:.1f} s)",
        ),
        Row(
            "client_stream.cpu_script_over_cli",
            f["cpu_script_over_cli"],
            "ratio",
            "",
            None,
            f"CPU: script {f['script_cpu_s']:.2f} s, CLI {f['cli_cpu_s']:.2f} s",
        ),
    ]
    return {key: f[key] for key in CLIENT_KEYS}, rows
