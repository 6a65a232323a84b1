"""Helpers for the cross-process daemon tests: config files, processes, Zenoh queries.

Used by tests/test_daemon.py (udp_multicast) and tests/test_daemon_vcan.py (vcan0).
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, Any

from controller.service.config.tomltext import to_toml
from controller.service.zenoh_io import free_tcp_port

REPO = Path(__file__).resolve().parents[1]
CABLEBOT = [sys.executable, "-m", "controller.cli"]


def udp_bus() -> dict[str, Any]:
    """A `[bus]` table of a udp_multicast bus of its own: a random group and port (the port
    isolates it: udp_multicast binds it); frames never leave the host (TTL 0, the default)."""
    group = f"239.74.{random.randint(1, 254)}.{random.randint(1, 254)}"
    return {
        "interface": "udp_multicast",
        "channel": group,
        "options": {"port": random.randint(40000, 49000)},
    }


def write_config(
    tmp_path: Path,
    bus: Mapping[str, Any],
    *,
    rate_hz: float = 250.0,
    sim_enabled: bool = False,
    faults: Mapping[str, Any] | None = None,
    sim: Mapping[str, Any] | None = None,
    loop: Mapping[str, Any] | None = None,
    base: Path | None = None,
    drive: Mapping[str, Any] | None = None,
) -> tuple[Path, dict[str, Any]]:
    """Write a config for a test (own bus, own Zenoh port, state file in tmp): the paper robot,
    or the robot file `base` (its drive, reels, limits, power-up pose and [sim] kept);
    `drive` keys go over its [drive] table."""
    import tomllib

    from controller.service.config import paper_robot_data

    name = f"t{uuid.uuid4().hex[:8]}"
    if base is None:
        data = paper_robot_data(name)
        power_up: Any = [0.0, 0.0, 2.0]
        base_sim: dict[str, Any] = {}
    else:
        data = tomllib.loads(base.read_text())
        data["name"] = name
        power_up = data.get("homing", {}).get("power_up_position_m")
        base_sim = {k: v for k, v in data.get("sim", {}).items() if k != "enabled"}
    if drive:
        data["drive"] = {**data.get("drive", {}), **drive}
    data["bus"] = dict(bus)
    data["loop"] = {"rate_hz": rate_hz, "realtime": False, "publish_every": 5, **(loop or {})}
    data["sim"] = {**base_sim, "enabled": sim_enabled, **(sim or {})}
    data["homing"] = {
        "power_up_position_m": power_up,
        "state_file": str(tmp_path / "{name}-offsets.json"),
    }
    port = free_tcp_port()
    data["zenoh"] = {
        "prefix": f"cablebot/{name}",
        "mode": "peer",
        "listen": [f"tcp/127.0.0.1:{port}"],
        "multicast_scouting": False,
    }
    # The host is shared and loaded: a starved simulator process must not look like a stale
    # node here (the stale-node fault itself is tested in test_loop*.py).
    data["faults"] = {**data["faults"], "stale_timeout_s": 0.25, **(faults or {})}
    path = tmp_path / f"{name}.toml"
    path.write_text(to_toml(data))
    info = {
        "name": name,
        "endpoint": f"tcp/127.0.0.1:{port}",
        "prefix": f"cablebot/{name}",
        "state_file": tmp_path / f"{name}-offsets.json",
    }
    return path, info


class Proc:
    """A child process whose stdout/stderr lines are collected by a reader thread."""

    def __init__(self, args: Sequence[str], name: str, env: Mapping[str, str] | None = None):
        e = dict(os.environ)
        e["PYTHONUNBUFFERED"] = "1"
        e.pop("NOTIFY_SOCKET", None)
        if env:
            e.update(env)
        self.name = name
        self.p = subprocess.Popen(
            list(args),
            cwd=REPO,
            env=e,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.out: list[str] = []
        self.err: list[str] = []
        self._threads = [
            threading.Thread(target=self._read, args=(self.p.stdout, self.out), daemon=True),
            threading.Thread(target=self._read, args=(self.p.stderr, self.err), daemon=True),
        ]
        for t in self._threads:
            t.start()

    @staticmethod
    def _read(stream: IO[str] | None, sink: list[str]) -> None:
        if stream is None:
            return
        for line in stream:
            sink.append(line.rstrip("\n"))

    def wait_line(self, needle: str, timeout_s: float, *, stderr: bool = False) -> str:
        """The first line containing `needle`; AssertionError after `timeout_s`."""
        sink = self.err if stderr else self.out
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for line in list(sink):
                if needle in line:
                    return line
            if self.p.poll() is not None:
                time.sleep(0.1)
                for line in list(sink):
                    if needle in line:
                        return line
                break
            time.sleep(0.02)
        raise AssertionError(f"{self.name}: no line with {needle!r}\n{self.log()}")

    def log(self) -> str:
        return (
            f"--- {self.name} rc={self.p.poll()} stdout:\n"
            + "\n".join(self.out[-40:])
            + f"\n--- {self.name} stderr:\n"
            + "\n".join(self.err[-60:])
        )

    def terminate(self, timeout_s: float = 5.0) -> int | None:
        if self.p.poll() is None:
            self.p.send_signal(signal.SIGTERM)
            try:
                self.p.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait(5)
        return self.p.returncode

    def kill(self) -> None:
        if self.p.poll() is None:
            self.p.kill()
        self.p.wait(5)


def zenoh_session(endpoint: str, timeout_s: float = 20.0) -> Any:
    """A Zenoh client session to the daemon at `endpoint` (retried until it listens)."""
    import zenoh

    from controller.service.zenoh_io import client_config

    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return zenoh.open(client_config([endpoint]))
        except Exception:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


def zquery(session: Any, key: str, payload: Any = None, timeout_s: float = 5.0) -> dict[str, Any]:
    """Query `key` once and return the JSON reply; an error reply gives {"error": ...}."""
    body = None if payload is None else json.dumps(payload)
    replies = session.get(key, payload=body, timeout=timeout_s)
    for reply in replies:
        if reply.ok is not None:
            out: dict[str, Any] = json.loads(reply.ok.payload.to_bytes())
            return out
        err = reply.err.payload.to_bytes()
        try:
            e: dict[str, Any] = json.loads(err)
            return e if "error" in e else {"error": e}
        except ValueError:
            return {"error": err.decode(errors="replace")}
    return {"error": "no reply"}


OBSERVER = r"""
import json, math, sys, threading, time
sys.path.insert(0, ".")
from tests.daemon_procs import zenoh_session, zquery

endpoint, prefix, slow = sys.argv[1], sys.argv[2], float(sys.argv[3])
dx = float(sys.argv[4]) if len(sys.argv) > 4 else 1.0
speed = float(sys.argv[5]) if len(sys.argv) > 5 else 1.0
estop = len(sys.argv) > 6 and sys.argv[6] == "estop"
s = zenoh_session(endpoint, 20.0 * slow)
latest = {}
ev = threading.Event()
def on_pose(sample):
    latest["pose"] = json.loads(sample.payload.to_bytes())
    ev.set()
sub = s.declare_subscriber(prefix + "/pose", on_pose)

def wait(pred, timeout, what):
    deadline = time.monotonic() + timeout * slow
    while time.monotonic() < deadline:
        p = latest.get("pose")
        if p is not None and pred(p):
            return p
        time.sleep(0.01)
    print("TIMEOUT " + what + " " + json.dumps(latest.get("pose")), flush=True)
    sys.exit(3)

p = wait(lambda p: p["valid"], 10, "valid pose")
print("POSE " + json.dumps(p), flush=True)
r = zquery(s, prefix + "/cmd/arm", {}, 5 * slow)
print("ARM " + json.dumps(r), flush=True)
wait(lambda p: p["state"] == "HOLDING", 10, "HOLDING")
start = p["position_m"]
target = [start[0] + dx, start[1], start[2]]
r = zquery(s, prefix + "/cmd/move", {"position_m": target, "speed_mps": speed}, 5 * slow)
print("MOVE " + json.dumps(r), flush=True)
wait(lambda p: p["state"] == "MOVING", 5, "MOVING")
p = wait(
    lambda p: p["state"] == "HOLDING" and math.dist(p["position_m"], target) < 1e-3,
    20,
    "arrival",
)
print("ARRIVED %.6f %s" % (math.dist(p["position_m"], target), json.dumps(p)), flush=True)
st = zquery(s, prefix + "/status", None, 5 * slow)
print("STATUS " + json.dumps(st), flush=True)
if estop:
    r = zquery(s, prefix + "/cmd/estop", {}, 5 * slow)
    print("ESTOP " + json.dumps(r), flush=True)
    wait(lambda p: p["state"] == "ESTOPPED", 5, "ESTOPPED")
    deadline = time.monotonic() + 5 * slow
    while True:
        st = zquery(s, prefix + "/status", None, 5 * slow)
        if (st.get("estop") or {}).get("confirmed"):
            break
        if time.monotonic() > deadline:
            print("TIMEOUT estop confirmation " + json.dumps(st), flush=True)
            sys.exit(3)
        time.sleep(0.05)
    print("CONFIRMED " + json.dumps(st), flush=True)
sub.undeclare()
s.close()
"""
