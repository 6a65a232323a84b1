"""A real daemon process for the tools' tests (view, record, replay, plot).

The paper robot with simulated ODrives inside the daemon on a python-can `virtual` bus (nothing
leaves the process), Zenoh on a free loopback port, auto-armed at (0, 0, 2) m; the same set-up
as tests/test_zenoh_daemon.py, whose config writer and `Daemon` handle it reuses.
"""

from __future__ import annotations

import math
import queue
import time
import tomllib
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from tests.daemon_procs import CABLEBOT, Proc, to_toml, zenoh_session
from tests.service.test_zenoh_daemon import RATE_HZ, Daemon, strict_json, write_config

__all__ = ["RATE_HZ", "Daemon", "live_daemon", "wait_holding_at_rest"]


@contextmanager
def live_daemon(
    tmp_path: Path, tables: Mapping[str, Any] | None = None
) -> Iterator[tuple[Daemon, Path]]:
    """Start the daemon, wait until it holds, yield (daemon, config path); stop it after.
    `tables` replace whole top-level tables of its robot file (e.g. `{"gcode": {...}}`)."""
    cfg, endpoint, prefix = write_config(tmp_path)
    if tables:
        data = tomllib.loads(cfg.read_text())
        data.update(tables)
        cfg.write_text(to_toml(data))
    proc = Proc([*CABLEBOT, "run", "--config", str(cfg), "--status-every", "0"], "daemon")
    session = None
    try:
        session = zenoh_session(endpoint, 30.0)
        poses: queue.Queue[dict[str, Any]] = queue.Queue()
        states: queue.Queue[dict[str, Any]] = queue.Queue()
        session.declare_subscriber(
            f"{prefix}/pose", lambda s: poses.put(strict_json(s.payload.to_bytes()))
        )
        session.declare_subscriber(
            f"{prefix}/state", lambda s: states.put(strict_json(s.payload.to_bytes()))
        )
        d = Daemon(proc, endpoint, prefix, session, poses, states)
        d.wait_state("HOLDING", 30.0)
        yield d, cfg
    finally:
        if session is not None:
            session.close()
        rc = proc.terminate(10.0)
        assert rc == 0, proc.log()


def wait_holding_at_rest(d: Daemon, timeout_s: float = 20.0) -> dict[str, Any]:
    """Wait until the daemon holds with its pose on the set-point; return that status."""
    deadline = time.monotonic() + timeout_s
    while True:
        st = d.status()
        pos, sp = st["pose"]["position_m"], st["setpoint_m"]
        if (
            st["state"] == "HOLDING"
            and pos is not None
            and sp is not None
            and math.dist(pos, sp) < 2e-5
        ):
            return st
        assert time.monotonic() < deadline, (st, d.proc.log())
        time.sleep(0.05)
