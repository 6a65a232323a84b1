"""The faults a chaos worker injects, one function per kind.

Each takes the worker (`chaos.worker.Worker`: the daemon, the equipment, the client) and a
random generator, injects its fault (and undoes it when the fault is a period), and returns a
note for the log, or raises `Unavailable` when this host cannot do it (no root for a namespace,
a mount or a cgroup). The worker then watches what the daemon did, and brings the robot back
(`Worker.recover`) when it faulted. `expect` names the outcome some kinds must have.
"""

from __future__ import annotations

import random
import signal
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import can

from chaos.equipment import error_frame, foreign_frames
from chaos.robot import busy_loops, end_all, wait_for

if TYPE_CHECKING:
    from chaos.worker import Worker


class Unavailable(RuntimeError):
    """This host cannot inject the fault (the message says why)."""


def drive_reboot(w: Worker, rng: random.Random) -> str:
    """A drive reboots mid-move: ODrive goes silent for a heartbeat gap and comes back IDLE;
    a CiA 402 drive sends its boot-up and has lost its set-up."""
    i = rng.randrange(len(w.drives.node_ids))
    if w.family == "odrive":
        gap_s = rng.uniform(0.2, 0.8)
        w.drives.silence(i, True)
        time.sleep(gap_s)
        w.drives.reboot(i)
        w.drives.silence(i, False)
        return f"node {w.drives.node_ids[i]} rebooted ({gap_s:.2f} s heartbeat gap)"
    w.drives.reboot(i)
    return f"node {w.drives.node_ids[i]} NMT boot-up"


def drive_silent(w: Worker, rng: random.Random) -> str:
    """A drive goes silent for a while, then speaks again."""
    i = rng.randrange(len(w.drives.node_ids))
    quiet_s = rng.uniform(0.1, 1.0)
    w.drives.silence(i, True)
    time.sleep(quiet_s)
    w.drives.silence(i, False)
    return f"node {w.drives.node_ids[i]} silent {quiet_s:.2f} s"


def drive_error(w: Worker, rng: random.Random) -> str:
    """A drive reports an error (ODrive axis error; CiA 402 EMCY and Fault)."""
    i = rng.randrange(len(w.drives.node_ids))
    return f"node {w.drives.node_ids[i]} {w.drives.report_error(i, rng)}"


def frames_lost_burst(w: Worker, rng: random.Random) -> str:
    """Every frame lost for 20-200 ms."""
    burst_s = rng.uniform(0.02, 0.2)
    w.chaos_bus.blackout_until_s = time.monotonic() + burst_s
    time.sleep(burst_s)
    return f"{burst_s * 1e3:.0f} ms of frames lost"


def frames_lost_1pct(w: Worker, rng: random.Random) -> str:
    """A steady 1 % of frames lost for a few seconds."""
    span_s = rng.uniform(3.0, 6.0)
    lost = w.chaos_bus.lost
    w.chaos_bus.loss = 0.01
    time.sleep(span_s)
    w.chaos_bus.loss = 0.0
    return f"1 % for {span_s:.1f} s ({w.chaos_bus.lost - lost} frames)"


def frames_corrupt(w: Worker, rng: random.Random) -> str:
    """Some of the drives' frames cut short (malformed on arrival)."""
    n = rng.randint(3, 12)
    w.chaos_bus.corrupt_left = n
    wait_for(lambda: w.chaos_bus.corrupt_left == 0, 2.0)
    return f"{n} frames cut short"


def frames_duplicated(w: Worker, rng: random.Random) -> str:
    """Some of the drives' frames sent twice."""
    n = rng.randint(5, 30)
    w.chaos_bus.duplicate_left = n
    wait_for(lambda: w.chaos_bus.duplicate_left == 0, 2.0)
    return f"{n} frames duplicated"


def foreign_node(w: Worker, rng: random.Random) -> str:
    """Another node talks on the bus for a second."""
    sent = 0
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        for msg in foreign_frames(w.family, rng):
            w.inject_bus.send(msg)
            sent += 1
        time.sleep(0.02)
    return f"{sent} frames of a foreign node"


def second_master(w: Worker, rng: random.Random) -> str:
    """Another CANopen master produces SYNCs on the bus (CiA 402 only)."""
    n = rng.randint(1, 5)
    for _ in range(n):
        w.inject_bus.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
        time.sleep(0.01)
    return f"{n} SYNC of another master"


def bus_off(w: Worker, rng: random.Random) -> str:
    """A bus-off period: nothing gets through, error frames say why."""
    span_s = rng.uniform(0.1, 0.6)
    w.chaos_bus.blackout_until_s = time.monotonic() + span_s
    end = time.monotonic() + span_s
    while time.monotonic() < end:
        w.inject_bus.send(error_frame("bus_off"))
        time.sleep(0.02)
    return f"bus-off {span_s * 1e3:.0f} ms"


def error_passive(w: Worker, rng: random.Random) -> str:
    """An error-passive period: frames still flow, error frames report the controller state."""
    span_s = rng.uniform(0.1, 0.5)
    end = time.monotonic() + span_s
    n = 0
    while time.monotonic() < end:
        w.inject_bus.send(error_frame("passive"))
        n += 1
        time.sleep(0.02)
    return f"error-passive {span_s * 1e3:.0f} ms ({n} error frames)"


def daemon_stall(w: Worker, rng: random.Random) -> str:
    """The daemon's process stopped (SIGSTOP) for 50-500 ms."""
    stall_s = rng.uniform(0.05, 0.5)
    pid = w.daemon.pid
    t0 = time.monotonic()
    import os

    os.kill(pid, signal.SIGSTOP)
    try:
        time.sleep(stall_s)
    finally:
        os.kill(pid, signal.SIGCONT)
    w.checker.stall(t0, time.monotonic())
    return f"SIGSTOP {stall_s * 1e3:.0f} ms"


def cpu_hog(w: Worker, rng: random.Random) -> str:
    """Busy loops take the CPU for a few seconds."""
    n = 2
    span_s = rng.uniform(1.5, 3.0)
    procs = busy_loops(n)
    t0 = time.monotonic()
    try:
        time.sleep(span_s)
    finally:
        end_all(procs)
    w.checker.stall(t0, time.monotonic())
    return f"{n} busy loops for {span_s:.1f} s"


def memory_limit(w: Worker, rng: random.Random) -> str:
    """The daemon's memory capped just above what it uses, for a few seconds."""
    if not w.cage_ready:
        raise Unavailable("no memory cgroup on this host")
    pid = w.daemon.pid
    rss = w.daemon.rss_bytes() or 0
    headroom = rng.choice((16, 32, 64)) << 20
    span_s = rng.uniform(2.0, 4.0)
    if not w.cage.limit(pid, rss + headroom):
        raise Unavailable("the memory cgroup refused the daemon")
    t0 = time.monotonic()
    try:
        time.sleep(span_s)
    finally:
        w.cage.release(pid)
    w.checker.stall(t0, time.monotonic())
    return f"memory capped at RSS + {headroom >> 20} MiB for {span_s:.1f} s"


def zenoh_flood(w: Worker, rng: random.Random) -> str:
    """A hostile client (a process of its own, connected for the whole run) floods malformed
    and oversized commands for a second and a half (`chaos.hostile`)."""
    return w.hostile_flood("flood", 1.5, rng.randrange(1 << 30))


def zenoh_flood_reconnect(w: Worker, rng: random.Random) -> str:
    """The flood from a new session each time, closed after it. Not in the default set: every
    such session leaves about 16 MiB in the daemon's Zenoh (docs/chaos.md), a defect of the
    Zenoh library reproduced without cablebot."""
    return w.hostile_flood("flood_new", 1.5, rng.randrange(1 << 30))


_CHURN = """
import json, sys, time, zenoh
from controller.service.zenoh_io import client_config
s = zenoh.open(client_config([sys.argv[1]]))
sub = s.declare_subscriber(sys.argv[2] + "/pose", lambda sample: None)
while True:
    for _ in s.get(sys.argv[2] + "/status", timeout=1.0):
        pass
    time.sleep(0.05)
"""


def client_churn(w: Worker, rng: random.Random) -> str:
    """Clients appear and vanish (killed while connected, mid-query)."""
    import subprocess

    n = rng.randint(2, 4)
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _CHURN, w.endpoint, w.prefix],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=w.child_env,
        )
        for _ in range(n)
    ]
    try:
        time.sleep(rng.uniform(1.0, 2.5))
    finally:
        for p in procs:
            p.send_signal(signal.SIGKILL)
        end_all(procs)
    return f"{n} clients came and were killed"


def network_cut(w: Worker, rng: random.Random) -> str:
    """The network between a jogging client (in a namespace of its own) and the daemon is cut,
    then restored; the velocity dead-man must brake the robot to a hold meanwhile."""
    if not w.net_ready:
        raise Unavailable("no network namespace (needs root and iproute2)")
    return w.jog_and_cut(rng)


def state_dir_readonly(w: Worker, rng: random.Random) -> str:
    """The state file's directory is read-only when the offsets are saved."""
    if not w.state_dir.available:
        raise Unavailable("no tmpfs for the state directory (needs root and mount)")
    return w.save_offsets_with(w.state_dir.read_only, "read-only")


def state_dir_full(w: Worker, rng: random.Random) -> str:
    """The state file's directory is full when the offsets are saved."""
    if not w.state_dir.available:
        raise Unavailable("no tmpfs for the state directory (needs root and mount)")
    return w.save_offsets_with(w.state_dir.fill, "full")


def daemon_kill9(w: Worker, rng: random.Random) -> str:
    """`kill -9` of the daemon and a restart: the pose comes back from the persisted offsets."""
    return w.kill_and_restart()


def estop(w: Worker, rng: random.Random) -> str:
    """An e-stop from the client at a random moment: confirmed, every drive out of closed loop."""
    return w.estop_and_time()


Fault = Callable[["Worker", random.Random], str]

KINDS: dict[str, Fault] = {
    "drive_reboot": drive_reboot,
    "drive_silent": drive_silent,
    "drive_error": drive_error,
    "frames_lost_burst": frames_lost_burst,
    "frames_lost_1pct": frames_lost_1pct,
    "frames_corrupt": frames_corrupt,
    "frames_duplicated": frames_duplicated,
    "foreign_node": foreign_node,
    "second_master": second_master,
    "bus_off": bus_off,
    "error_passive": error_passive,
    "daemon_stall": daemon_stall,
    "cpu_hog": cpu_hog,
    "memory_limit": memory_limit,
    "zenoh_flood": zenoh_flood,
    "zenoh_flood_reconnect": zenoh_flood_reconnect,
    "client_churn": client_churn,
    "network_cut": network_cut,
    "state_dir_readonly": state_dir_readonly,
    "state_dir_full": state_dir_full,
    "daemon_kill9": daemon_kill9,
    "estop": estop,
}
FAMILY_ONLY = {"second_master": "cia402"}
NOT_BY_DEFAULT = {"zenoh_flood_reconnect"}
LATE_KINDS = {"daemon_kill9"}
"""Kinds injected only late in a run (`chaos.worker.LATE_FRACTION`)."""
"""Kinds run only when asked for (`--kinds`)."""
OUTCOME = {
    "state_dir_readonly": "named_error",
    "state_dir_full": "named_error",
    "daemon_kill9": "restored",
}
"""Kinds whose outcome is theirs, not the state the robot is left in (they disarm or restart it
on purpose)."""
EXPECT_FAULT = {"second_master": "bus_conflict", "drive_error": "axis_error"}
"""Kinds that must end in a fault of this name (when the robot was armed)."""
