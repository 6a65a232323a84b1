"""The loop benchmark's helper processes: the simulated drives and the pose subscriber
(`python -m controller.cli.bench sim|sub`), and how they are started and stopped.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from types import FrameType
from typing import IO, Any

from controller.cli.bench.settings import CHILD_START_TIMEOUT_S, BenchError


class _Child:
    """A helper process whose stdout/stderr lines are collected by reader threads."""

    def __init__(self, args: Sequence[str], name: str) -> None:
        env = dict(os.environ)
        env["PYTHONUNBUFFERED"] = "1"
        env.pop("NOTIFY_SOCKET", None)
        self.name = name
        self.proc = subprocess.Popen(
            list(args), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self.out: list[str] = []
        self.err: list[str] = []
        for stream, sink in ((self.proc.stdout, self.out), (self.proc.stderr, self.err)):
            threading.Thread(target=self._read, args=(stream, sink), daemon=True).start()

    @staticmethod
    def _read(stream: IO[str] | None, sink: list[str]) -> None:
        if stream is None:
            return
        for line in stream:
            sink.append(line.rstrip("\n"))

    def wait_line(self, needle: str, timeout_s: float) -> None:
        """Wait for a stdout line containing `needle`; BenchError on timeout or exit."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if any(needle in line for line in list(self.out)):
                return
            if self.proc.poll() is not None:
                break
            time.sleep(0.02)
        raise BenchError(f"{self.name}: no {needle!r} line\n{self.tail()}")

    def tail(self) -> str:
        """The last lines of output, for error messages."""
        return f"--- {self.name} rc={self.proc.poll()}\n" + "\n".join(
            self.out[-10:] + self.err[-30:]
        )

    def stop(self, timeout_s: float = 10.0) -> int | None:
        """SIGTERM, wait (bounded), SIGKILL if needed; returns the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        return self.proc.returncode


def _helper(role: str, *args: str) -> list[str]:
    return [sys.executable, "-m", "controller.cli.bench", role, *args]


def _on_term(stop: threading.Event) -> None:
    def handler(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)


def _load_cfg(path: str) -> Any:
    from controller.service.config import parse_config

    with open(path, encoding="utf-8") as f:
        return parse_config(json.load(f), path)


class _RecordingBus:
    """Wraps a python-can bus; stamps `time.time_ns()` just before sending each ODrive encoder
    frame (with `record`)."""

    def __init__(self, bus: Any, *, record: bool = True) -> None:
        from drivers.odrive import cansimple as cs

        self.bus = bus
        self._encoder_cmd = cs.GET_ENCODER_ESTIMATES if record else -1
        self.sent: list[tuple[int, int, bytes]] = []

    def recv(self, timeout: float | None = None) -> Any:
        return self.bus.recv(timeout=timeout)

    def send(self, msg: Any, timeout: float | None = None) -> None:
        if (msg.arbitration_id & 0x1F) == self._encoder_cmd and not msg.is_remote_frame:
            t_ns = time.time_ns()
            self.bus.send(msg, timeout=timeout)
            self.sent.append((t_ns, msg.arbitration_id, bytes(msg.data)))
        else:
            self.bus.send(msg, timeout=timeout)


def role_sim(config: str, log: str, tick_s: float) -> int:
    """Helper process: the config's simulated drives (as `cablebot sim`), logging encoder sends
    (ODrive frames; none for other families)."""
    import dataclasses

    from controller.service.runner import RT_PRIORITY, set_realtime
    from controller.service.simulated import sim_settings
    from drivers import registry
    from drivers.bus import open_bus

    cfg = _load_cfg(config)
    stop = threading.Event()
    _on_term(stop)
    b = cfg.bus
    bus = open_bus(b.interface, b.channel, b.bitrate, **dict(b.options))
    rec = _RecordingBus(bus, record=cfg.drive.kind == "odrive")
    try:
        settings = dataclasses.replace(sim_settings(cfg), tick_s=tick_s)
        fam = registry.family(cfg.drive.kind)
        bank = fam.sim_bank(rec, cfg.node_ids, cfg.drive.options, settings)  # type: ignore[arg-type]
        bank.start()
        # The drives stand in for hardware, which a busy host does not slow down: like the
        # daemon's in-process simulator, run one priority below the loop when permitted.
        sched = "SCHED_OTHER"
        thread = bank.thread
        if thread is not None and thread.native_id is not None:
            prio = max(1, int(getattr(cfg.loop, "rt_priority", RT_PRIORITY)) - 1)
            sched = set_realtime(prio, thread.native_id)
        try:
            print(f"READY {sched}", flush=True)
            stop.wait()
        finally:
            bank.stop()
    finally:
        bus.shutdown()
        with open(log, "w", encoding="utf-8") as f:
            json.dump([[t, a, d.hex()] for t, a, d in rec.sent], f)
    return 0


def role_sub(endpoint: str, key: str, out: str) -> int:
    """Helper process: a Zenoh client subscriber stamping each sample's arrival."""
    import zenoh

    from controller.service.zenoh_io import client_config

    stop = threading.Event()
    _on_term(stop)
    deadline = time.monotonic() + CHILD_START_TIMEOUT_S
    while True:
        try:
            session = zenoh.open(client_config([endpoint]))
            break
        except Exception:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)
    got: list[tuple[int, bytes]] = []
    first = threading.Event()

    def on_sample(sample: Any) -> None:
        got.append((time.time_ns(), sample.payload.to_bytes()))
        if not first.is_set():
            first.set()
            print("FIRST", flush=True)

    sub = session.declare_subscriber(key, on_sample)
    print("READY", flush=True)
    stop.wait()
    with contextlib.suppress(Exception):
        sub.undeclare()  # type: ignore[no-untyped-call]
    with contextlib.suppress(Exception):
        session.close()  # type: ignore[no-untyped-call]
    with open(out, "w", encoding="utf-8") as f:
        json.dump([[t, p.decode()] for t, p in list(got)], f)
    return 0
