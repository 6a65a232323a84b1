"""The loop benchmark: the daemon-like process (`python -m controller.cli.bench loop`) that
runs the daemon's own stack and loop against simulated drives, and the end-to-end matching.
"""

from __future__ import annotations

import bisect
import json
import os
import random
import statistics
import struct
import subprocess
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from controller.cli.bench.helpers import _Child, _helper, _load_cfg
from controller.cli.bench.settings import (
    CHILD_START_TIMEOUT_S,
    DRAIN_PERIOD_S,
    MOVE_POINTS_M,
    MOVE_SPEED_MPS,
    SIM_TICK_S,
    BenchError,
)
from controller.cli.bench.timing import _median, percentile

CIA402_COUNTS_PER_REV = 131072.0
"""The simulated CiA 402 drives' scaling in the loop bench (a 17-bit encoder)."""


def loop_config_data(rate_hz: float, zenoh_port: int, kind: str = "odrive") -> dict[str, Any]:
    """The paper robot on its own udp_multicast bus and Zenoh port, loop at `rate_hz`, on
    drives of family `kind` ("odrive", node ids 0..3, or "cia402", node ids 1..4)."""
    from controller.service.config import paper_robot_data

    name = f"bench-{os.getpid()}-{random.randrange(1 << 16):04x}"
    data = paper_robot_data(name)
    if kind == "cia402":
        data["drive"] = {"kind": "cia402", "counts_per_rev": CIA402_COUNTS_PER_REV}
        for i, reel in enumerate(data["reels"]):
            reel["node_id"] = i + 1
    data["bus"] = {
        "interface": "udp_multicast",
        "channel": f"239.74.{random.randint(1, 254)}.{random.randint(1, 254)}",
        "options": {"port": random.randint(20000, 60000)},
    }
    data["loop"] = {
        "rate_hz": float(rate_hz),
        "realtime": True,
        "gc_freeze": True,
        "publish_every": 1,
        "encoder_rtr": False,
    }
    data["sim"] = {"enabled": False}
    data["zenoh"] = {
        "prefix": f"cablebot/{name}",
        "mode": "peer",
        "listen": [f"tcp/127.0.0.1:{zenoh_port}"],
        "multicast_scouting": False,
    }
    return data


class _RingReader:
    """Copies new values out of a loop statistics ring (`controller.service.runner.LoopStats`)."""

    def __init__(self, ring: Any) -> None:
        self.ring = ring
        self.last = int(ring.count)
        self.values: list[float] = []
        self.lost = 0

    def drain(self, keep: bool = True) -> None:
        count = int(self.ring.count)
        size = int(self.ring.size)
        start = max(self.last, count - size + 1)  # index count-size may be being overwritten
        if keep:
            self.lost += start - self.last
            buf = self.ring.buf
            self.values.extend(buf[i % size] for i in range(start, count))
        self.last = count


def loop_once(
    rate_hz: float, seconds: float, workdir: Path, kind: str = "odrive"
) -> dict[str, Any]:
    """Run the daemon's loop at `rate_hz` for `seconds` against simulated drives of family
    `kind`; its figures (the end-to-end ones None for other families than "odrive").

    Raises BenchError when a helper fails, the robot cannot be armed or faults, or (ODrive)
    no end-to-end sample was matched.
    """
    from controller.core.commands import Arm, Move, Reset
    from controller.core.states import State
    from controller.service.daemon import Stack, build_stack
    from controller.service.runner import start_loop
    from controller.service.zenoh_io import free_tcp_port  # Zenoh only when used

    zport = free_tcp_port()
    data = loop_config_data(rate_hz, zport, kind)
    cfg_path = workdir / f"loop-{int(rate_hz)}.json"
    cfg_path.write_text(json.dumps(data))
    cfg = _load_cfg(str(cfg_path))
    sim_log = workdir / f"sim-{int(rate_hz)}.json"
    sub_log = workdir / f"sub-{int(rate_hz)}.json"
    period_s = 1.0 / float(rate_hz)
    children: list[_Child] = []
    stack: Stack | None = None
    stop_loop = threading.Event()
    thread: threading.Thread | None = None
    try:
        sim = _Child(
            _helper(
                "sim", "--config", str(cfg_path), "--log", str(sim_log), "--tick-s", str(SIM_TICK_S)
            ),
            "sim",
        )
        children.append(sim)
        sim.wait_line("READY", CHILD_START_TIMEOUT_S)
        sim_sched = next((ln[6:] for ln in sim.out if ln.startswith("READY ")), "")

        # The daemon's own builder and loop thread (bus, driver, Controller, Zenoh; SCHED_FIFO,
        # timer slack, switch interval, gc freeze).
        stack = build_stack(cfg)
        controller, driver, iface = stack.controller, stack.driver, stack.zenoh
        assert iface is not None  # build_stack(zenoh=True) raises rather than give None
        thread, rt_report = start_loop(controller.runner(), cfg.loop, stop_loop)

        endpoint = f"tcp/127.0.0.1:{zport}"
        sub = _Child(
            _helper(
                "sub", "--connect", endpoint, "--key", f"{iface.prefix}/pose", "--out", str(sub_log)
            ),
            "subscriber",
        )
        children.append(sub)
        sub.wait_line("FIRST", CHILD_START_TIMEOUT_S)

        _arm_and_hold(controller, float(cfg.faults.arm_timeout_s) + 3.0)

        loop_stats = controller.loop_stats
        jitter = _RingReader(loop_stats.jitter)
        compute = _RingReader(loop_stats.compute)
        moves = 0
        faults: list[str] = []
        controller.submit(Move(MOVE_POINTS_M[0], MOVE_SPEED_MPS))
        moves += 1
        t0_ns = time.time_ns()
        ticks0, overruns0, skipped0 = controller.ticks, loop_stats.overruns, loop_stats.skipped
        bus0 = driver.stats.snapshot()
        jitter.drain(keep=False)
        compute.drain(keep=False)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            time.sleep(DRAIN_PERIOD_S)
            jitter.drain()
            compute.drain()
            state = _state_of(controller)
            if state is State.FAULT:
                # Counted and reported; reset and re-arm so the run goes on.
                faults.append(str(controller.reason))
                controller.submit(Reset())
            elif state is State.DISARMED:
                controller.submit(Arm())
            elif state is State.HOLDING:
                controller.submit(Move(MOVE_POINTS_M[moves % 2], MOVE_SPEED_MPS))
                moves += 1
        ticks = controller.ticks - ticks0
        overruns = loop_stats.overruns - overruns0
        skipped = loop_stats.skipped - skipped0
        bus1 = driver.stats.snapshot()
        jitter.drain()
        compute.drain()
        t1_ns = time.time_ns()
        zstats = iface.stats()
        bus_stats = driver.stats.snapshot()
        reels = list(controller.reels)
        node_ids = controller.node_ids

        sub.stop()
        stop_loop.set()
        thread.join(2.0)
    finally:
        stop_loop.set()
        for c in reversed(children):
            c.stop()
        if stack is not None:
            stack.close()

    if not jitter.values or not compute.values:
        raise BenchError("no loop statistics were collected")
    sent = json.loads(sim_log.read_text())
    poses = json.loads(sub_log.read_text())
    e2e = match_e2e(sent, poses, reels, node_ids, t0_ns, t1_ns)
    if kind == "odrive" and not e2e["total_us"]:
        raise BenchError(f"no end-to-end sample matched ({e2e['unmatched']} unmatched changes)")

    pct = _percentile_or_none
    put = zstats["pose_publish_tick"]
    return {
        "rate_hz": float(rate_hz),
        "seconds": (t1_ns - t0_ns) / 1e9,
        "ticks": ticks,
        "overruns": overruns,
        "overrun_frac": overruns / max(ticks, 1),
        "skipped": skipped,
        "jitter_p50_frac": percentile(jitter.values, 0.50) / period_s,
        "jitter_p99_frac": percentile(jitter.values, 0.99) / period_s,
        "compute_p50_frac": percentile(compute.values, 0.50) / period_s,
        "compute_p99_frac": percentile(compute.values, 0.99) / period_s,
        "stat_samples": len(compute.values),
        "stat_lost": jitter.lost + compute.lost,
        "zenoh_put_us": put["p50_us"],
        "zenoh_put_p99_us": put["p99_us"],
        "zenoh_put_n": min(int(zstats["poses_published"]), 4096),
        "e2e_p50_us": pct(e2e["total_us"], 0.50),
        "e2e_p99_us": pct(e2e["total_us"], 0.99),
        "e2e_n": len(e2e["total_us"]),
        "e2e_unmatched": e2e["unmatched"],
        "send_to_publish_p50_us": pct(e2e["to_publish_us"], 0.50),
        "send_to_publish_p99_us": pct(e2e["to_publish_us"], 0.99),
        "publish_to_arrival_p50_us": pct(e2e["after_publish_us"], 0.50),
        "publish_to_arrival_p99_us": pct(e2e["after_publish_us"], 0.99),
        "moves": moves,
        "faults": len(faults),
        "fault_reasons": sorted(set(faults))[:5],
        "frames_rx": bus_stats.frames_rx,
        "frames_rx_per_tick": (bus1.frames_rx - bus0.frames_rx) / max(ticks, 1),
        "frames_tx_per_tick": (bus1.frames_tx - bus0.frames_tx) / max(ticks, 1),
        "kind": kind,
        "scheduling": "; ".join(rt_report),
        "sim_scheduling": sim_sched,
    }


def _arm_and_hold(controller: Any, timeout_s: float) -> None:
    """Arm the robot and wait until it holds. Raises BenchError if it faults or `timeout_s`
    passes first."""
    from controller.core.commands import Arm
    from controller.core.states import State

    controller.submit(Arm())
    deadline = time.monotonic() + timeout_s
    while controller.state is not State.HOLDING:
        if time.monotonic() > deadline or controller.state is State.FAULT:
            raise BenchError(f"arming failed: {controller.state.value} {controller.reason}")
        time.sleep(0.01)


def _percentile_or_none(values: Sequence[float], q: float) -> float | None:
    return percentile(values, q) if values else None


def _state_of(controller: Any) -> Any:
    """The controller's state, read afresh (another thread changes it)."""
    return controller.state


def match_e2e(
    sent: Sequence[Sequence[Any]],
    poses: Sequence[Sequence[Any]],
    reels: Sequence[Any],
    node_ids: Sequence[int],
    t0_ns: int,
    t1_ns: int,
) -> dict[str, Any]:
    """Relate pose arrivals to encoder-frame sends by value (see the module docstring).

    `sent`: (send_ns, arbitration id, data hex) per encoder frame; `poses`: (arrival_ns, JSON)
    in arrival order; `reels`: the controller's homed reel models in cable order. Only frames
    sent within [t0_ns, t1_ns] count. Returns lists of microseconds (`total_us`, `to_publish_us`
    = frame send to the daemon's publish stamp, `after_publish_us`) and the `unmatched` count.
    """
    cable_of = {n: i for i, n in enumerate(node_ids)}
    sends: list[dict[float, list[int]]] = [{} for _ in node_ids]
    for t_ns, arb, data_hex in sent:
        i = cable_of.get(int(arb) >> 5)
        if i is None:
            continue
        (pos,) = struct.unpack_from("<f", bytes.fromhex(data_hex))
        sends[i].setdefault(reels[i].length_m(pos), []).append(int(t_ns))
    for table in sends:
        for times in table.values():
            times.sort()
    total: list[float] = []
    to_pub: list[float] = []
    after_pub: list[float] = []
    unmatched = 0
    prev: list[float | None] = [None] * len(node_ids)
    for t_arr, payload in poses:
        d = json.loads(payload)
        lengths = d.get("cable_lengths_m") or []
        for i, v in enumerate(lengths[: len(node_ids)]):
            if v is None:
                prev[i] = None
                continue
            changed = prev[i] is not None and v != prev[i]
            prev[i] = v
            if not changed:
                continue
            times = sends[i].get(float(v), [])
            k = bisect.bisect_right(times, int(t_arr)) - 1
            if k < 0:
                unmatched += 1
                continue
            t_send = times[k]
            if not t0_ns <= t_send <= t1_ns:
                continue
            total.append((int(t_arr) - t_send) / 1e3)
            to_pub.append((int(d["stamp_ns"]) - t_send) / 1e3)
            after_pub.append((int(t_arr) - int(d["stamp_ns"])) / 1e3)
    return {
        "total_us": total,
        "to_publish_us": to_pub,
        "after_publish_us": after_pub,
        "unmatched": unmatched,
    }


_SUMMED = ("faults", "e2e_n", "e2e_unmatched", "stat_samples", "stat_lost", "moves", "frames_rx")


def merge_runs(runs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """One figure set from several `loop_once` results: the median of each number (counts in
    `_SUMMED` are summed, fault reasons joined); `runs` says how many. Raises ValueError on
    no runs."""
    if not runs:
        raise ValueError("no loop runs to merge")
    out: dict[str, Any] = {"runs": len(runs)}
    for key, first in runs[0].items():
        values = [r[key] for r in runs]
        if key in _SUMMED:
            out[key] = sum(values)
        elif key == "fault_reasons":
            out[key] = sorted({x for v in values for x in v})[:5]
        elif isinstance(first, bool) or not isinstance(first, int | float):
            out[key] = first
        elif isinstance(first, int):
            out[key] = int(statistics.median_low(values))
        else:
            out[key] = _median(values)
    return out


def role_loop(rate_hz: float, seconds: float, out: str, kind: str = "odrive") -> int:
    """Helper process: `loop_once` in a fresh, daemon-like process; writes its figures as JSON."""
    with tempfile.TemporaryDirectory(prefix="cablebot-bench-") as tmp:
        try:
            result: dict[str, Any] = loop_once(rate_hz, seconds, Path(tmp), kind)
        except BenchError as exc:
            result = {"error": str(exc)}
    Path(out).write_text(json.dumps(result))
    return 0


def bench_loop(rate_hz: int, seconds: float, kind: str = "odrive") -> dict[str, Any]:
    """Run `loop_once` in its own process (`python -m controller.cli.bench loop`) on drives of
    family `kind`; its figures.

    Raises BenchError when that process fails or reports an error.
    """
    with tempfile.TemporaryDirectory(prefix="cablebot-bench-") as tmp:
        out = Path(tmp) / "loop.json"
        args = _helper(
            "loop",
            "--rate-hz",
            str(rate_hz),
            "--seconds",
            str(seconds),
            "--out",
            str(out),
            "--drive",
            kind,
        )
        try:
            proc = subprocess.run(
                args, capture_output=True, text=True, timeout=seconds + 90.0, check=False
            )
        except subprocess.TimeoutExpired as exc:
            raise BenchError(f"loop bench at {rate_hz} Hz timed out") from exc
        if proc.returncode != 0 or not out.exists():
            raise BenchError(
                f"loop bench at {rate_hz} Hz failed (rc {proc.returncode}):\n{proc.stderr[-3000:]}"
            )
        result: dict[str, Any] = json.loads(out.read_text())
    if "error" in result:
        raise BenchError(f"loop bench at {rate_hz} Hz: {result['error']}")
    return result
