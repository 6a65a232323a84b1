"""The e-stop benchmark under a flood of hostile commands: the flooding client, the
daemon-like process and the e-stop timing (see `controller.cli.bench`).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import random
import socket
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from controller.cli.bench.helpers import _Child, _helper, _load_cfg, _on_term
from controller.cli.bench.loop import _state_of
from controller.cli.bench.settings import (
    CHILD_START_TIMEOUT_S,
    ESTOP_FLOOD_THREADS,
    SEED,
    BenchError,
)
from controller.cli.bench.timing import percentile


def flood_payloads() -> list[tuple[str, bytes]]:
    """What the flooding client sends, in turn: `(verb, payload)`, "setpoint" meaning a put.

    Each payload but the last is exactly its verb's byte cap (`commands.MAX_PAYLOAD_BYTES`),
    passes the size and nesting checks, and is malformed only at its very end, so the daemon
    decodes every byte before refusing it: the most GIL a single accepted message can take.
    The last is the original attack, 10 MB (2.6 million numbers), refused by its size unread.
    """
    from controller.core.commands import MAX_PAYLOAD_BYTES

    def at_cap(verb: str, head: bytes, item: bytes) -> bytes:
        cap = MAX_PAYLOAD_BYTES[verb]
        body = head + item * ((cap - len(head)) // len(item))
        return body + b" " * (cap - len(body))  # unclosed: malformed at the last byte

    return [
        ("path", at_cap("path", b'{"points_m": [', b"[1.25, -2.5, 3.75], ")),
        ("move", at_cap("move", b'{"position_m": [', b"1.2345678, ")),
        ("path", at_cap("path", b'{"points_m": [', b"[], ")),
        ("setpoint", at_cap("setpoint", b'{"position_m": [', b"1.2345678, ")),
        ("home", at_cap("home", b'{"position_m": [', b"7, ")),
        ("move", b'{"position_m": [' + b"1.0, " * 2_600_000 + b"1.0]}"),
    ]


def role_flood(endpoint: str, prefix: str, threads: int) -> int:
    """Helper process: `threads` clients sending `flood_payloads()` back to back (each waits for
    its reply, so `threads` queries are in flight), until SIGTERM; prints how many it sent."""
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
    payloads = flood_payloads()
    sent = [0] * threads
    started = threading.Event()

    def worker(k: int) -> None:
        i = k
        while not stop.is_set():
            verb, data = payloads[i % len(payloads)]
            i += 1
            if verb == "setpoint":
                session.put(f"{prefix}/setpoint", data)
            else:
                for _ in session.get(f"{prefix}/cmd/{verb}", payload=data, timeout=10.0):
                    pass
            sent[k] += 1
            started.set()

    workers = [threading.Thread(target=worker, args=(k,), daemon=True) for k in range(threads)]
    for w in workers:
        w.start()
    if started.wait(CHILD_START_TIMEOUT_S):
        print("FLOODING", flush=True)
    stop.wait()
    for w in workers:
        w.join(15.0)
    print(f"SENT {sum(sent)}", flush=True)
    with contextlib.suppress(Exception):
        session.close()  # type: ignore[no-untyped-call]
    return 0


def role_daemon(config: str) -> int:
    """Helper process: the daemon's own stack (`build_stack`, `start_loop`: bus, in-process
    simulated nodes, Controller, Zenoh) on `config`, armed as the daemon arms, until SIGTERM."""
    from controller.core.commands import Arm
    from controller.core.states import State
    from controller.service.daemon import build_stack
    from controller.service.runner import start_loop

    cfg = _load_cfg(config)
    stop = threading.Event()
    _on_term(stop)
    stack = build_stack(cfg)
    stop_loop = threading.Event()
    thread: threading.Thread | None = None
    try:
        thread, report = start_loop(stack.controller.runner(), cfg.loop, stop_loop)
        controller = stack.controller
        controller.submit(Arm())
        deadline = time.monotonic() + float(cfg.faults.arm_timeout_s) + 3.0
        while _state_of(controller) is not State.HOLDING:
            if time.monotonic() > deadline:
                print(f"ARM FAILED {controller.state.value} {controller.reason}", flush=True)
                return 1
            time.sleep(0.01)
        print(f"READY {'; '.join(report)}", flush=True)
        stop.wait()
    finally:
        stop_loop.set()
        if thread is not None:
            thread.join(2.0)
        stack.close()
    return 0


def estop_config_data(zenoh_port: int) -> dict[str, Any]:
    """The paper robot as `cablebot run` would run it with `[sim] enabled` (in-process simulated
    nodes, loop at its default rate), on its own udp_multicast bus (random group and port,
    hop limit 0: nothing leaves the host) and Zenoh port."""
    from controller.service.config import paper_robot_data

    name = f"estop-{os.getpid()}-{random.randrange(1 << 16):04x}"
    data = paper_robot_data(name)
    data["bus"] = {
        "interface": "udp_multicast",
        "channel": f"239.74.{random.randint(1, 254)}.{random.randint(1, 254)}",
        "options": {"port": random.randint(20000, 60000), "hop_limit": 0},
    }
    data["sim"] = {"enabled": True}
    data["zenoh"] = {
        "prefix": f"cablebot/{name}",
        "mode": "peer",
        "listen": [f"tcp/127.0.0.1:{zenoh_port}"],
        "multicast_scouting": False,
    }
    return data


class _EstopWatch:
    """An observer on the robot's bus: the kernel's arrival stamp (wall clock, SO_TIMESTAMPNS,
    so this process's own scheduling does not count) of every Estop frame it hears."""

    RCVBUF_BYTES = 4 << 20
    """The observer's socket buffer: a busy bus must not overflow it while this process waits
    for a CPU (the kernel caps it at net.core.rmem_max)."""

    def __init__(self, bus_cfg: dict[str, Any]) -> None:
        from drivers.bus import open_bus
        from drivers.odrive import cansimple as cs

        self._estop = cs.ESTOP
        self.bus = open_bus(bus_cfg)
        with contextlib.suppress(AttributeError, OSError):  # python-can's own socket
            sock = self.bus._multicast._socket  # type: ignore[attr-defined]
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.RCVBUF_BYTES)
        self.frames: list[tuple[float, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="estop-watch", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(timeout=0.05)
            if msg is not None and (msg.arbitration_id & 0x1F) == self._estop:
                self.frames.append((float(msg.timestamp), msg.arbitration_id >> 5))

    def heard(self, start: int, t0: float, nodes: set[int], timeout_s: float) -> tuple[float, int]:
        """Wait until every node in `nodes` has an Estop frame stamped after `t0` (wall clock;
        frames from index `start` on), at most `timeout_s`. Returns the stamp of the last of
        them (of the last heard, if not all were) and how many nodes were heard."""
        deadline = time.monotonic() + timeout_s
        while True:
            seen: dict[int, float] = {}
            for t, node in self.frames[start:]:
                if t >= t0 and node in nodes:
                    seen.setdefault(node, t)
            if len(seen) == len(nodes) or time.monotonic() > deadline:
                return (max(seen.values()) if seen else math.nan), len(seen)
            time.sleep(0.002)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1.0)
        self.bus.shutdown()


def bench_estop_flood(tries: int, flood_threads: int = ESTOP_FLOOD_THREADS) -> dict[str, Any]:
    """E-stop latency while another process floods the daemon with hostile commands.

    A daemon-like process (`role_daemon`: the daemon's own stack with in-process simulated
    nodes) is armed; a second process (`role_flood`) keeps `flood_threads` queries of
    `flood_payloads()` in flight; this process, after a second of flood, sends `tries` e-stops
    to the robot holding (`_hold` resets and re-arms it after each), each after a random
    30-80 ms pause, and measures for each the time to the e-stop's reply and the time until an
    observer on the same bus has heard an Estop frame for every axis (`_EstopWatch`; tries
    where it heard only some count in `frames_missed`). Returns milliseconds
    (`reply_p50`/`reply_p99`, `frame_p50`/`frame_p99`, nearest-rank; `reply_max`, `frame_max`;
    every try's in `reply_ms` and `frame_ms`),
    `tries`, the flood's query count and rate, the faults the robot showed and the loop
    thread's scheduling.
    Raises BenchError when a helper fails, an e-stop gets no reply, or the observer heard no
    Estop frame at all in more than a tenth of the tries.
    """
    import zenoh

    from controller.service.zenoh_io import client_config

    rng = random.Random(SEED)
    with tempfile.TemporaryDirectory(prefix="cablebot-bench-") as tmp:
        from controller.service.zenoh_io import free_tcp_port  # Zenoh only when used

        zport = free_tcp_port()
        data = estop_config_data(zport)
        cfg_path = Path(tmp) / "estop.json"
        cfg_path.write_text(json.dumps(data))
        cfg = _load_cfg(str(cfg_path))
        prefix = str(cfg.zenoh.prefix)
        endpoint = f"tcp/127.0.0.1:{zport}"
        nodes = {int(r.node_id) for r in cfg.reels}
        children: list[_Child] = []
        watch: _EstopWatch | None = None
        session: Any = None
        reply_ms: list[float] = []
        frame_ms: list[float] = []
        faults: list[str] = []
        missed = 0
        try:
            watch = _EstopWatch(cfg.bus.as_mapping())
            daemon = _Child(_helper("daemon", "--config", str(cfg_path)), "daemon")
            children.append(daemon)
            daemon.wait_line("READY", CHILD_START_TIMEOUT_S)
            sched = next((ln[6:] for ln in daemon.out if ln.startswith("READY ")), "")
            session = zenoh.open(client_config([endpoint]))
            flood = _Child(
                _helper(
                    "flood", "--connect", endpoint, "--prefix", prefix,
                    "--threads", str(flood_threads),
                ),
                "flood",
            )  # fmt: skip
            children.append(flood)
            flood.wait_line("FLOODING", CHILD_START_TIMEOUT_S)
            time.sleep(1.0)
            t_flood0 = time.monotonic()
            _hold(session, prefix, faults)
            for _ in range(tries):
                time.sleep(rng.uniform(0.03, 0.08))
                st = _query_json(session, f"{prefix}/status")
                if st.get("state") != "HOLDING":  # it left HOLDING by itself: a fault
                    faults.append(f"{st.get('state')}: {st.get('reason')}")
                start = len(watch.frames)
                t0_wall = time.time()
                t0 = time.monotonic()
                replies = list(session.get(f"{prefix}/cmd/estop", timeout=5.0))
                t1 = time.monotonic()
                if len(replies) != 1 or replies[0].ok is None:
                    raise BenchError(f"e-stop got no reply ({len(replies)})\n{daemon.tail()}")
                reply_ms.append((t1 - t0) * 1e3)
                t_frames, n_heard = watch.heard(start, t0_wall, nodes, 2.0)
                if n_heard < len(nodes):
                    missed += 1  # the observer's socket dropped some: not the daemon's doing
                if n_heard:
                    frame_ms.append((t_frames - t0_wall) * 1e3)
                _hold(session, prefix, faults)
            flood_s = time.monotonic() - t_flood0
            if len(frame_ms) < 0.9 * tries:
                raise BenchError(
                    f"the observer heard no Estop frame in {tries - len(frame_ms)} tries"
                )
            flood.stop()
            sent_line = next((ln for ln in flood.out if ln.startswith("SENT ")), "SENT 0")
            flood_n = int(sent_line.split()[1])
        finally:
            for c in reversed(children):
                c.stop()
            if session is not None:
                with contextlib.suppress(Exception):
                    session.close()
            if watch is not None:
                watch.close()
    return {
        "reply_p50": percentile(reply_ms, 0.50),
        "reply_p99": percentile(reply_ms, 0.99),
        "frame_p50": percentile(frame_ms, 0.50),
        "frame_p99": percentile(frame_ms, 0.99),
        "reply_max": max(reply_ms),
        "frame_max": max(frame_ms),
        "reply_ms": reply_ms,
        "frame_ms": frame_ms,
        "tries": len(reply_ms),
        "frames_missed": missed,
        "flood_queries": flood_n,
        "flood_per_s": flood_n / max(flood_s, 1e-9),
        "faults": len(faults),
        "fault_reasons": sorted(set(faults))[:5],
        "scheduling": sched,
    }


def _hold(session: Any, prefix: str, faults: list[str], timeout_s: float = 15.0) -> None:
    """Reset and arm the robot over Zenoh until it holds; faults met on the way are appended
    to `faults`. Raises BenchError if it does not hold within `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    last_fault = None
    while True:
        st = _query_json(session, f"{prefix}/status")
        state = st.get("state")
        if state == "HOLDING":
            return
        if state == "FAULT" and st.get("state_stamp_ns", st.get("reason")) != last_fault:
            last_fault = st.get("state_stamp_ns", st.get("reason"))  # each fault once
            faults.append(f"FAULT: {st.get('reason')}")
        if state in ("ESTOPPED", "FAULT"):
            _query_json(session, f"{prefix}/cmd/reset")
        elif state == "DISARMED":
            _query_json(session, f"{prefix}/cmd/arm")
        if time.monotonic() > deadline:
            raise BenchError(f"the robot does not hold: {state} {st.get('reason')}")
        time.sleep(0.02)


def _query_json(session: Any, key: str) -> dict[str, Any]:
    """One query; the reply's JSON object, or {} if none came."""
    for reply in session.get(key, timeout=5.0):
        if reply.ok is not None:
            out: dict[str, Any] = json.loads(reply.ok.payload.to_bytes())
            return out
    return {}
