"""The SocketCAN I/O benchmark: the fast path against python-can's stock SocketCAN path.

`python -m controller.cli.bench_vcan [--channel vcan0] [--out bench-vcan.json]` (what
`make bench-vcan` runs, inside the virtme-ng VM when this kernel has no vcan) measures, as
ratios of one run with the two paths interleaved round by round:

* `rx_us_per_frame`: CPU time (the thread's) of `ODriveReels.poll()` per received frame,
  draining a burst of encoder (90 %) and heartbeat (10 %) frames of 4 nodes that another socket
  queued on the interface: receive, decode, reading update;
* `tx_us_per_frame`: CPU time of `ODriveReels.command()` per sent frame (4 Set_Input_Pos);
* `loop_compute_p50_s`: the median compute time of the control step (`Controller.tick`: poll,
  kinematics, motion, command) at 500 Hz, moving, with four simulated ODrives in another process
  on the same interface.

* `no_transport`: the controller's own compute per tick without any transport, on the same
  machine, as the baseline of `loop_compute_p50_s`: `controller.cli.bench.compute.bench_compute`
  (the `compute_per_tick` section of `cablebot bench`; CPU time of `Controller.tick` at 1 kHz,
  moving, on a driver that hands in readings from memory), p50 and p99 in seconds.

* `cia402`: the same receive and send figures for `CiA402Reels` (four drives), its own "fast"
  and "stock" rounds interleaved the same way: `rx_us_per_frame` drains a burst of TPDO1 (90 %)
  and heartbeat (10 %) frames of 4 drives (TPDOs decoded by the driver, heartbeats handed to
  canopen), with a `command()` before each `poll()` as in the loop's rhythm (not timed);
  `tx_us_per_frame` is `command()` per sent frame (4 RPDO1, 4 RPDO2 and the SYNC per tick).
  The drives are taken as holding the mapping `configure` writes (no SDO exchange).

`--socketpair` measures instead, on any Linux host (no AF_CAN needed), the fast path's CPU per
received and sent frame for both drivers with an AF_UNIX datagram pair standing in for the CAN
socket: the same `recvmmsg`/`sendmmsg` and the same decoding (`socketpair_figures`).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import socket
import statistics
import struct
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import can

from controller.cli.bench.compute import bench_compute
from drivers.bus import open_bus
from drivers.cia402.driver import CiA402Reels
from drivers.cia402.sdo_config import local_mapping
from drivers.odrive import cansimple as cs
from drivers.odrive.driver import ODriveReels
from drivers.socketcan_fast import FastSocketCan, socket_of

NODES = (0, 1, 2, 3)
CIA402_NODES = (1, 2, 3, 4)
CIA402_CPR = 4096
CIA402_FRAMES_PER_TICK = 2 * len(CIA402_NODES) + 1
_TPDO1 = struct.Struct("<Hih")  # statusword, position actual, torque actual
_SW_OPERATION_ENABLED = 0x0237
MODES = ("stock", "fast")
NO_TRANSPORT_TICKS = 2000
"""Ticks of the no-transport baseline (`bench_compute`; a few seconds under the emulated VM)."""


def _burst(n: int) -> list[cs.Frame]:
    out: list[cs.Frame] = []
    for i in range(n):
        node = NODES[i % 4]
        if i % 10:
            out.append(cs.encode_encoder_estimates(node, i * 1e-3, 1.0))
        else:
            out.append(cs.encode_heartbeat(node, 0, cs.AxisState.CLOSED_LOOP_CONTROL))
    return out


def hold_armed(controller: Any, timeout_s: float) -> None:
    """Arm `controller` and wait until it holds (resetting and re-arming after a fault).
    Raises RuntimeError after `timeout_s`."""
    from controller.core.commands import Arm, Reset
    from controller.core.states import State

    controller.submit(Arm())
    deadline = time.monotonic() + timeout_s
    while (state := _state(controller)) is not State.HOLDING:
        if time.monotonic() > deadline:
            raise RuntimeError(f"arming failed: {state.value} {controller.reason}")
        if state is State.FAULT:
            controller.submit(Reset())
        elif state is State.DISARMED:
            controller.submit(Arm())
        time.sleep(0.05)


def hold(controller: Any, seconds: float, compute: Any) -> int:
    """Let the armed robot hold its pose for `seconds` (every tick still reads, solves the
    pose, limits and commands), re-arming after a fault; drains the compute ring `compute`.
    Returns the faults seen."""
    from controller.core.states import State

    faults = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        time.sleep(0.05)
        compute.drain()
        if _state(controller) is not State.HOLDING:
            faults += 1
            compute.drain(keep=False)
            hold_armed(controller, 180.0)
            compute.drain(keep=False)
    compute.drain()
    return faults


def _state(controller: Any) -> Any:
    return controller.state


def _driver(bus: can.BusABC, mode: str) -> ODriveReels:
    driver = ODriveReels(bus, NODES, max_frames_per_poll=4096, fast_path=mode == "fast")
    if driver.fast_path != (mode == "fast"):
        raise RuntimeError(f"the {mode} path is not available on this bus")
    return driver


def rx_round(channel: str, sender: FastSocketCan, mode: str, frames: int) -> tuple[float, int]:
    """One receive round: queue `frames` on `channel`, drain them through the `mode` path;
    returns (CPU seconds of the polls, frames taken). Raises RuntimeError if frames were lost
    or a frame was not decoded cleanly."""
    bus = open_bus("socketcan", channel)
    try:
        driver = _driver(bus, mode)
        burst = _burst(frames)
        if sender.send_frames(burst) is not None:
            raise RuntimeError("the sender could not queue the burst")
        handled = 0
        deadline = time.monotonic() + 30.0
        cpu = 0.0
        while handled < frames and time.monotonic() < deadline:
            t0 = time.thread_time()
            got = driver.poll()
            cpu += time.thread_time() - t0
            handled += got
        s = driver.stats
        if handled != frames or s.decode_errors or s.dropped or s.bus_errors:
            raise RuntimeError(f"{mode}: took {handled}/{frames} frames, stats {s}")
        return cpu, handled
    finally:
        bus.shutdown()


def tx_round(channel: str, mode: str, ticks: int) -> tuple[float, int]:
    """One send round: `ticks` calls of `command()` for 4 axes; (CPU seconds, frames sent)."""
    bus = open_bus("socketcan", channel)
    try:
        driver = _driver(bus, mode)
        positions = [0.0, 1.0, 2.0, 3.0]
        ff = [0.1, 0.1, 0.1, 0.1]
        t0 = time.thread_time()
        for i in range(ticks):
            positions[0] = i * 1e-4
            driver.command(positions, ff)
        cpu = time.thread_time() - t0
        if driver.stats.frames_tx != 4 * ticks or driver.stats.bus_errors:
            raise RuntimeError(f"{mode}: sent {driver.stats.frames_tx}/{4 * ticks} frames")
        return cpu, 4 * ticks
    finally:
        bus.shutdown()


def floor_round(channel: str, sender: FastSocketCan | None, frames: int, ticks: int) -> float:
    """The kernel's share: CPU seconds per frame of `recvmmsg` + unpacking of `frames` queued
    frames (with `sender`), or of `sendmmsg` of `ticks` prebuilt 4-frame ticks (without)."""
    bus = open_bus("socketcan", channel)
    try:
        sock = socket_of(bus)
        if sock is None:
            raise RuntimeError(f"{channel} did not open as a SocketCAN bus")
        fast = FastSocketCan(sock)
        if sender is not None:
            if sender.send_frames(_burst(frames)) is not None:
                raise RuntimeError("the sender could not queue the burst")
            got = 0
            deadline = time.monotonic() + 30.0
            t0 = time.thread_time()
            while got < frames and time.monotonic() < deadline:
                n = fast.recv_batch(frames - got)
                for i in range(n):
                    fast.frame(i)
                got += n
            cpu = time.thread_time() - t0
            return cpu / max(got, 1)
        tick = [cs.encode_set_input_pos(n, 1.0, 0.1, 0.0) for n in NODES]
        t0 = time.thread_time()
        for _ in range(ticks):
            if fast.send_frames(tick) is not None:
                raise RuntimeError("sendmmsg failed")
        return (time.thread_time() - t0) / (4 * ticks)
    finally:
        bus.shutdown()


def io_figures(channel: str, rounds: int, frames: int, ticks: int) -> dict[str, dict[str, Any]]:
    """Per-frame CPU of the receive and send paths, stock and fast interleaved round by round
    (after one warm-up round each; the median round), and the kernel's share (`floor_round`).
    The send rounds run with no other socket open, as a real interface's local echo does not
    run on the sender's time. Raises RuntimeError as `rx_round` / `tx_round`."""
    # CPU seconds per frame of each round; the figures are the medians over the rounds (the
    # guest's CPU time also counts the moments its host ran something else).
    rx: dict[str, list[float]] = {m: [] for m in MODES}
    tx: dict[str, list[float]] = {m: [] for m in MODES}
    floors: dict[str, list[float]] = {"rx": [], "tx": []}
    send_bus = open_bus("socketcan", channel)
    try:
        sock = socket_of(send_bus)
        if sock is None:
            raise RuntimeError(f"{channel} did not open as a SocketCAN bus")
        sender = FastSocketCan(sock)
        for r in range(rounds + 1):
            for mode in MODES if r % 2 else tuple(reversed(MODES)):
                cpu, n = rx_round(channel, sender, mode, frames)
                if r:  # round 0 warms up both paths
                    rx[mode].append(cpu / n)
            if r:
                floors["rx"].append(floor_round(channel, sender, frames, ticks))
    finally:
        send_bus.shutdown()
    for r in range(rounds + 1):
        for mode in MODES if r % 2 else tuple(reversed(MODES)):
            cpu_t, n_t = tx_round(channel, mode, ticks)
            if r:
                tx[mode].append(cpu_t / n_t)
        if r:
            floors["tx"].append(floor_round(channel, None, frames, ticks))
    out: dict[str, dict[str, Any]] = {
        m: {
            "rx_us_per_frame": statistics.median(rx[m]) * 1e6,
            "tx_us_per_frame": statistics.median(tx[m]) * 1e6,
            "rx_rounds_us_per_frame": [round(v * 1e6, 2) for v in rx[m]],
            "tx_rounds_us_per_frame": [round(v * 1e6, 2) for v in tx[m]],
            "rx_frames_per_round": frames,
            "tx_frames_per_round": 4 * ticks,
        }
        for m in MODES
    }
    out["kernel"] = {
        "rx_us_per_frame": statistics.median(floors["rx"]) * 1e6,
        "tx_us_per_frame": statistics.median(floors["tx"]) * 1e6,
    }
    return out


# --------------------------------------------------------------------------------------------
# The CiA 402 driver's receive and send paths


def _cia402_burst(n: int) -> list[cs.Frame]:
    out: list[cs.Frame] = []
    for i in range(n):
        node = CIA402_NODES[i % 4]
        if i % 10:
            out.append((0x180 + node, _TPDO1.pack(_SW_OPERATION_ENABLED, i, 0), False))
        else:
            out.append((0x700 + node, b"\x05", False))  # heartbeat: OPERATIONAL
    return out


def _cia402_driver(bus: can.BusABC, mode: str, fast: FastSocketCan | None = None) -> CiA402Reels:
    driver = CiA402Reels(
        bus,
        CIA402_NODES,
        counts_per_rev=CIA402_CPR,
        period_s=0.002,
        max_frames_per_poll=4096,
        fast_path=fast if fast is not None else mode == "fast",
    )
    if driver.fast_path != (mode == "fast"):
        raise RuntimeError(f"the {mode} path is not available on this bus")
    # The drives hold the mapping `configure` writes: taken without the SDO exchange, which
    # is not what is measured (and takes seconds in the emulated VM).
    for n in CIA402_NODES:
        d = driver._by_node[n]
        driver._use_mapping(d, *local_mapping(d.node, n, velocity_offset=True, torque=True))
    return driver


def cia402_rx_round(
    channel: str, sender: FastSocketCan, mode: str, frames: int
) -> tuple[float, int]:
    """One CiA 402 receive round: queue `frames` TPDO and heartbeat frames on `channel`, drain
    them through the `mode` path (a `command()` before each `poll()`, not timed); returns (CPU
    seconds of the polls, frames taken). Raises RuntimeError if frames were lost or a frame was
    not taken cleanly."""
    bus = open_bus("socketcan", channel)
    try:
        driver = _cia402_driver(bus, mode)
        positions = [0.0, 1.0, 2.0, 3.0]
        if sender.send_frames(_cia402_burst(frames)) is not None:
            raise RuntimeError("the sender could not queue the burst")
        handled = 0
        deadline = time.monotonic() + 30.0
        cpu = 0.0
        while handled < frames and time.monotonic() < deadline:
            driver.command(positions)
            t0 = time.thread_time()
            got = driver.poll()
            cpu += time.thread_time() - t0
            handled += got
        s = driver.stats
        if handled != frames or s.decode_errors or s.dropped or s.bus_errors:
            raise RuntimeError(f"cia402 {mode}: took {handled}/{frames} frames, stats {s}")
        return cpu, handled
    finally:
        bus.shutdown()


def cia402_tx_round(channel: str, mode: str, ticks: int) -> tuple[float, int]:
    """One CiA 402 send round: `ticks` calls of `command()` for 4 drives (RPDOs and SYNC);
    (CPU seconds, frames sent). Raises RuntimeError if a frame was not sent."""
    bus = open_bus("socketcan", channel)
    try:
        driver = _cia402_driver(bus, mode)
        positions = [0.0, 1.0, 2.0, 3.0]
        ff = [0.1, 0.1, 0.1, 0.1]
        t0 = time.thread_time()
        for i in range(ticks):
            positions[0] = i * 1e-4
            driver.command(positions, ff)
        cpu = time.thread_time() - t0
        want = CIA402_FRAMES_PER_TICK * ticks
        if driver.stats.frames_tx != want or driver.stats.bus_errors:
            raise RuntimeError(f"cia402 {mode}: sent {driver.stats.frames_tx}/{want} frames")
        return cpu, want
    finally:
        bus.shutdown()


def cia402_io_figures(channel: str, rounds: int, frames: int, ticks: int) -> dict[str, Any]:
    """`io_figures` for the CiA 402 driver: per-frame CPU of its receive and send paths, stock
    and fast interleaved round by round after one warm-up round each (the median round, and
    the ratios of the medians and of the sums over the rounds). Raises RuntimeError as
    `cia402_rx_round` / `cia402_tx_round`."""
    rx: dict[str, list[float]] = {m: [] for m in MODES}
    tx: dict[str, list[float]] = {m: [] for m in MODES}
    send_bus = open_bus("socketcan", channel)
    try:
        sock = socket_of(send_bus)
        if sock is None:
            raise RuntimeError(f"{channel} did not open as a SocketCAN bus")
        sender = FastSocketCan(sock)
        for r in range(rounds + 1):
            for mode in MODES if r % 2 else tuple(reversed(MODES)):
                cpu, n = cia402_rx_round(channel, sender, mode, frames)
                if r:
                    rx[mode].append(cpu / n)
    finally:
        send_bus.shutdown()
    for r in range(rounds + 1):
        for mode in MODES if r % 2 else tuple(reversed(MODES)):
            cpu_t, n_t = cia402_tx_round(channel, mode, ticks)
            if r:
                tx[mode].append(cpu_t / n_t)
    out: dict[str, Any] = {
        m: {
            "rx_us_per_frame": statistics.median(rx[m]) * 1e6,
            "tx_us_per_frame": statistics.median(tx[m]) * 1e6,
            "rx_rounds_us_per_frame": [round(v * 1e6, 2) for v in rx[m]],
            "tx_rounds_us_per_frame": [round(v * 1e6, 2) for v in tx[m]],
            "rx_frames_per_round": frames,
            "tx_frames_per_round": CIA402_FRAMES_PER_TICK * ticks,
        }
        for m in MODES
    }
    out["ratio_stock_over_fast"] = {
        k: out["stock"][k] / out["fast"][k]
        for k in ("rx_us_per_frame", "tx_us_per_frame")
        if out["fast"][k] > 0
    }
    out["ratio_of_sums_stock_over_fast"] = {
        f"{k}_us_per_frame": sum(d["stock"]) / sum(d["fast"])
        for k, d in (("rx", rx), ("tx", tx))
        if sum(d["fast"]) > 0
    }
    return out


def socketpair_figures(rounds: int, frames: int, ticks: int) -> dict[str, dict[str, float]]:
    """The fast path's CPU per frame with an AF_UNIX datagram pair standing in for the CAN
    socket, for the ODrive and the CiA 402 driver: `poll()` per received frame (a burst of
    `frames`) and `command()` per sent frame (`ticks` calls, the peer drained between calls,
    not timed); medians over `rounds` after a warm-up round. Raises RuntimeError if a frame
    was lost."""
    out: dict[str, dict[str, float]] = {}
    for family in ("odrive", "cia402"):
        rx: list[float] = []
        tx: list[float] = []
        for r in range(rounds + 1):
            peer, mine = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
            bus = can.Bus(interface="virtual", channel=f"bench-socketpair-{family}-{r}")
            try:
                peer.setblocking(False)
                fast = FastSocketCan(mine)
                driver: ODriveReels | CiA402Reels
                if family == "odrive":
                    driver = ODriveReels(bus, NODES, max_frames_per_poll=4096, fast_path=fast)
                    burst = _burst(frames)
                else:
                    driver = _cia402_driver(bus, "fast", fast)
                    burst = _cia402_burst(frames)
                if FastSocketCan(peer).send_frames(burst) is not None:
                    raise RuntimeError("the peer could not queue the burst")
                positions = [0.0, 1.0, 2.0, 3.0]
                t0 = time.thread_time()
                got = driver.poll()
                rx_cpu = time.thread_time() - t0
                if got != frames or driver.stats.decode_errors or driver.stats.dropped:
                    raise RuntimeError(f"{family}: took {got}/{frames}, {driver.stats}")
                tx_cpu = 0.0
                sent0 = driver.stats.frames_tx
                for i in range(ticks):
                    positions[0] = i * 1e-4
                    t0 = time.thread_time()
                    driver.command(positions, [0.1] * 4)
                    tx_cpu += time.thread_time() - t0
                    with contextlib.suppress(BlockingIOError):
                        while peer.recv(64):
                            pass
                sent = driver.stats.frames_tx - sent0
                if r:
                    rx.append(rx_cpu / got)
                    tx.append(tx_cpu / max(sent, 1))
            finally:
                bus.shutdown()
                peer.close()
                mine.close()
        out[family] = {
            "rx_us_per_frame": statistics.median(rx) * 1e6,
            "tx_us_per_frame": statistics.median(tx) * 1e6,
        }
    return out


# --------------------------------------------------------------------------------------------
# The control step at 500 Hz with simulated ODrives in another process


def _loop_config(channel: str, rate_hz: float, workdir: Path) -> Path:
    from controller.service.config import paper_robot_data

    data = paper_robot_data("bench-vcan")
    data["bus"] = {"interface": "socketcan", "channel": channel}
    data["loop"] = {
        "rate_hz": float(rate_hz),
        "realtime": True,
        "gc_freeze": True,
        "publish_every": 1,
        "encoder_rtr": False,
    }
    period_s = 1.0 / rate_hz
    data["sim"] = {
        "enabled": False,
        "tick_s": period_s,
        "encoder_period_s": period_s,
        "heartbeat_period_s": 0.1,
        "watchdog_timeout_s": 0.0,  # off: the emulated VM stalls the loop for seconds
    }
    # Generous fault windows: under the emulated VM the simulated drives lag.
    data["faults"] = {
        "stale_timeout_s": 2.0,
        "heartbeat_timeout_s": 10.0,
        "arm_timeout_s": 60.0,
        "tracking_max_m": 1.0,
    }
    path = workdir / "bench-vcan-loop.json"
    path.write_text(json.dumps(data))
    return path


def loop_compute(
    channel: str, mode: str, rate_hz: float, seconds: float, workdir: Path
) -> dict[str, float]:
    """The control step's compute per tick at `rate_hz` over `seconds` of holding the pose
    (each tick reads, solves the pose, limits and commands), on the `mode` path, simulated
    ODrives in another process. Raises RuntimeError if the robot
    cannot be armed or no tick was measured."""
    from controller.cli.bench.helpers import _Child, _helper, _load_cfg
    from controller.cli.bench.loop import _RingReader
    from controller.service.loop import Controller
    from controller.service.runner import start_loop

    cfg_path = _loop_config(channel, rate_hz, workdir)
    cfg = _load_cfg(str(cfg_path))
    sim = _Child(
        _helper(
            "sim",
            "--config",
            str(cfg_path),
            "--log",
            str(workdir / "sim.json"),
            "--tick-s",
            str(1.0 / rate_hz),
        ),
        "sim",
    )
    bus = open_bus("socketcan", channel)
    stop = threading.Event()
    thread = None
    try:
        sim.wait_line("READY", 120.0)
        driver = ODriveReels(
            bus,
            cfg.node_ids,
            catch_up_age_s=float(cfg.faults.stale_timeout_s) / 2.0,
            fast_path=mode == "fast",
        )
        controller = Controller(cfg, driver)
        thread, _report = start_loop(controller.runner(), cfg.loop, stop)
        hold_armed(controller, 180.0)
        compute = _RingReader(controller.loop_stats.compute)
        compute.drain(keep=False)
        ticks0 = controller.ticks
        rx0, tx0 = driver.stats.frames_rx, driver.stats.frames_tx
        faults = hold(controller, seconds, compute)
        ticks = max(controller.ticks - ticks0, 1)
        rx_per_tick = (driver.stats.frames_rx - rx0) / ticks
        tx_per_tick = (driver.stats.frames_tx - tx0) / ticks
    finally:
        stop.set()
        if thread is not None:
            thread.join(5.0)
        sim.stop()
        bus.shutdown()
    if not compute.values:
        raise RuntimeError(f"{mode}: no tick was measured")
    return {
        "loop_compute_p50_s": statistics.median(compute.values),
        "loop_ticks": float(ticks),
        "loop_frames_rx_per_tick": rx_per_tick,
        "loop_frames_tx_per_tick": tx_per_tick,
        "loop_faults": float(faults),
    }


# --------------------------------------------------------------------------------------------


def _progress(text: str) -> None:
    print(f"bench-vcan: {text}", file=sys.stderr, flush=True)


def run_io_bench(
    channel: str,
    out: Path | None,
    rounds: int,
    frames: int,
    ticks: int,
    seconds: float,
    cia402_ticks: int = 50,
) -> dict[str, Any]:
    """All SocketCAN figures, stock and fast (ODrive, then CiA 402 with `cia402_ticks` per send
    round), and the no-transport baseline; written as JSON to `out` when given. Raises
    RuntimeError as `io_figures`, BenchError if the baseline's robot does not fly its path."""
    _progress(f"receive and send paths on {channel}: {rounds} rounds")
    figures = io_figures(channel, rounds, frames, ticks)
    _progress(json.dumps(figures))
    _progress(f"the CiA 402 driver's receive and send paths: {rounds} rounds")
    cia402 = cia402_io_figures(channel, rounds, frames, cia402_ticks)
    _progress(json.dumps(cia402))
    with tempfile.TemporaryDirectory(prefix="cablebot-bench-vcan-") as tmp:
        for mode in ("stock", "fast", "fast", "stock"):
            _progress(f"the control step at 500 Hz, {mode} path, {seconds:g} s")
            try:
                lp = loop_compute(channel, mode, 500.0, seconds, Path(tmp))
            except Exception as exc:  # the I/O figures are still worth writing
                figures[mode]["loop_error"] = f"{type(exc).__name__}: {exc}"[:2000]
                continue
            key = figures[mode]
            runs = key.setdefault("loop_runs", [])
            runs.append(lp)
            key["loop_compute_p50_s"] = statistics.mean(r["loop_compute_p50_s"] for r in runs)
    _progress(f"the controller without transport: {NO_TRANSPORT_TICKS} ticks")
    base = bench_compute(NO_TRANSPORT_TICKS)
    figures["no_transport"] = {
        "compute_p50_s": base["p50_us"] * 1e-6,
        "compute_p99_s": base["p99_us"] * 1e-6,
        "ticks": base["ticks"],
    }
    result: dict[str, Any] = {
        "channel": channel,
        "machine": f"{platform.machine()} {platform.release()}, {os.cpu_count()} CPU(s)",
        "under_vm": os.environ.get("CABLEBOT_UNDER_VM") == "1",
        **figures,
        "cia402": cia402,
        "ratio_stock_over_fast": {
            k: figures["stock"][k] / figures["fast"][k]
            for k in ("rx_us_per_frame", "tx_us_per_frame", "loop_compute_p50_s")
            if k in figures["stock"] and k in figures["fast"] and figures["fast"][k] > 0
        },
    }
    if out is not None:
        out.write_text(json.dumps(result, indent=2) + "\n")
    return result


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark named on the command line and print its figures as JSON."""
    p = argparse.ArgumentParser(prog="python -m controller.cli.bench_vcan", description=__doc__)
    p.add_argument("--channel", default="vcan0")
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("--rounds", type=int, default=10)
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--ticks", type=int, default=100)
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--cia402-ticks", type=int, default=50)
    p.add_argument(
        "--socketpair",
        action="store_true",
        help="only the fast path's cost per frame on this host, an AF_UNIX pair for the socket",
    )
    args = p.parse_args(argv)
    if args.socketpair:
        print(json.dumps(socketpair_figures(30, args.frames, args.ticks), indent=2))
        return 0
    result = run_io_bench(
        args.channel,
        args.out,
        args.rounds,
        args.frames,
        args.ticks,
        args.seconds,
        args.cia402_ticks,
    )
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
