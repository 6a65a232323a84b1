"""A real daemon for the client library's tests: the built-in robot (the paper's acre robot on
four simulated ODrives inside the daemon, on a python-can `virtual` bus of its own), Zenoh on a
free loopback port, auto-armed at its power-up pose (0, 0, 2) m.

The fault timeouts are generous: these tests exercise the client, not fault detection, and on
a loaded 2-core machine the daemon's process can be starved for longer than the defaults.
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from controller.client import ClientError, Robot
from controller.service.config import paper_robot_data
from controller.service.zenoh_io import free_tcp_port
from tests.daemon_procs import CABLEBOT, Proc, to_toml

START_S = 60.0
"""How long a daemon may take to hold its power-up pose on a busy machine."""


@dataclass
class ClientDaemon:
    """A running daemon: its process, endpoint, prefix and robot file."""

    proc: Proc
    endpoint: str
    prefix: str
    config: Path

    def robot(self, **kwargs: Any) -> Robot:
        """A Robot on this daemon (the caller closes it)."""
        return Robot(self.endpoint, self.prefix, **kwargs)


def robot_data(name: str, *, sim: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The built-in robot's data, named `name`, on a bus of its own, Zenoh on a free port."""
    data: dict[str, Any] = paper_robot_data(name)
    data["bus"] = {"interface": "virtual", "channel": f"client-test-{name}"}
    data["loop"] = {"rate_hz": 100.0, "realtime": False, "publish_every": 1}
    data["sim"] = {"enabled": True, "watchdog_timeout_s": 2.0, **(sim or {})}
    data["faults"] = {**data["faults"], "stale_timeout_s": 2.0, "heartbeat_timeout_s": 4.0}
    data["zenoh"] = {
        "prefix": f"cablebot/{name}",
        "mode": "peer",
        "listen": [f"tcp/127.0.0.1:{free_tcp_port()}"],
        "multicast_scouting": False,
    }
    return data


@contextmanager
def client_daemon(
    tmp_path: Path, *, name: str | None = None, sim: Mapping[str, Any] | None = None
) -> Iterator[ClientDaemon]:
    """Start a daemon of `robot_data`, wait until it holds; stop it after (exit 0)."""
    name = name or f"c{uuid.uuid4().hex[:8]}"
    data = robot_data(name, sim=sim)
    data["homing"] = {"power_up_position_m": [0.0, 0.0, 2.0]}
    path = tmp_path / f"{name}.toml"
    path.write_text(to_toml(data))
    proc = Proc([*CABLEBOT, "run", "--config", str(path), "--status-every", "0"], "daemon")
    d = ClientDaemon(proc, data["zenoh"]["listen"][0], data["zenoh"]["prefix"], path)
    try:
        wait_holding(d)
        yield d
    finally:
        rc = proc.terminate(10.0)
        assert rc == 0, proc.log()


def wait_holding(d: ClientDaemon, timeout_s: float = START_S) -> None:
    """Wait until the daemon answers and holds a valid pose."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with d.robot(timeout_s=2.0) as robot:
                while time.monotonic() < deadline:
                    st = robot.status()
                    if st.state == "HOLDING" and st.position_m is not None:
                        return
                    time.sleep(0.1)
        except ClientError:
            pass
        assert time.monotonic() < deadline, d.proc.log()
        time.sleep(0.2)


def ready(robot: Robot, timeout_s: float = 30.0) -> None:
    """Bring the robot back to HOLDING at rest (after a test that stopped, e-stopped or
    disarmed it)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        st = robot.status()
        if st.state in ("FAULT", "ESTOPPED"):
            robot.reset()
        elif st.state == "DISARMED":
            robot.arm()
        elif st.state == "MOVING":
            robot.stop()
        elif (
            st.state == "HOLDING"
            and st.setpoint_m is not None
            and st.position_m is not None
            and max(abs(a - b) for a, b in zip(st.position_m, st.setpoint_m, strict=True)) < 2e-5
        ):
            return
        time.sleep(0.1)
    raise AssertionError(f"the robot did not come back to HOLDING: {robot.status()}")
