"""The robot under test of a chaos worker: its robot file, the daemon as a child process, and the
host-level equipment around it (a network namespace for a client that can be cut off, a state
file directory that can be made read-only or full, a memory cgroup).

Everything stays on this host: the bus is udp_multicast with TTL 0, Zenoh listens on loopback
and on a veth into a namespace this worker made, with addresses of that link only.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]
CABLEBOT = [sys.executable, "-m", "controller.cli"]

ROBOTS: dict[str, dict[str, Any]] = {
    # The desk rig's geometry (config/desk.toml) on ODrives, and its CiA 402 twin
    # (config/cia402-sim.toml), each on a udp_multicast bus of its own.
    "odrive": {"drive": {"kind": "odrive"}, "nodes": (0, 1, 2, 3)},
    "cia402": {
        "drive": {"kind": "cia402", "counts_per_rev": 131072, "heartbeat_period_s": 0.1},
        "nodes": (1, 2, 3, 4),
    },
}
ANCHORS = ((-0.5, -0.5, 0.8), (-0.5, 0.5, 0.8), (0.5, 0.5, 0.8), (0.5, -0.5, 0.8))
POWER_UP_M = (0.0, 0.0, 0.3)


def die_with_parent(signum: int = signal.SIGKILL) -> None:
    """In a child before exec: send it `signum` when the process that started it dies (Linux
    PR_SET_PDEATHSIG), so a worker that is killed leaves no daemon or busy loop behind."""
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(1, signum)  # PR_SET_PDEATHSIG = 1


def free_tcp_port() -> int:
    """A TCP port free on loopback now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _toml(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(value)


def robot_toml(family: str, name: str, workdir: Path, listen: list[str], rng: random.Random) -> str:
    """The robot file of a chaos worker: the desk rig on `family` drives, a udp_multicast bus of
    its own (random group and port), a 100 Hz loop with real-time scheduling where permitted,
    fault timeouts for a machine other people use, the state file in `workdir`/state, Zenoh on
    `listen`."""
    spec = ROBOTS[family]
    tables: dict[str, dict[str, Any]] = {
        "bus": {
            "interface": "udp_multicast",
            "channel": f"239.74.{rng.randint(1, 254)}.{rng.randint(1, 254)}",
        },
        "bus.options": {"port": rng.randint(40000, 49000)},
        "drive": dict(spec["drive"]),
        # The loop as a rig runs it: SCHED_FIFO where permitted (root), so a machine loaded by
        # others (and by the run's busy loops) delays it no more than it would a real robot.
        "loop": {"rate_hz": 100.0, "realtime": True, "publish_every": 2},
        "limits": {
            "xy_margin_m": 0.05,
            "floor_z_m": 0.01,
            "top_margin_m": 0.1,
            "min_cable_m": 0.1,
            "max_cable_m": 1.6,
            "max_cable_speed_mps": 0.5,
            "max_speed_mps": 0.3,
            "max_accel_mps2": 1.0,
            "default_speed_mps": 0.1,
        },
        # A machine shared with other work (and the chaos run's own busy loops): the drives are
        # judged stale after a quarter second, as the project's cross-process tests do.
        "faults": {
            "stale_timeout_s": 0.25,
            "heartbeat_timeout_s": 1.0,
            "residual_max_m": 0.005,
            "tracking_max_m": 0.02,
            "arm_timeout_s": 5.0,
        },
        "homing": {
            "power_up_position_m": list(POWER_UP_M),
            "state_file": str(workdir / "state" / "{name}-offsets.json"),
        },
        "zenoh": {
            "prefix": f"cablebot/{name}",
            "mode": "peer",
            "listen": listen,
            "multicast_scouting": False,
        },
        "sim": {
            "enabled": False,
            "max_velocity_rps": 20.0,
            "max_accel_rps2": 200.0,
            "tick_s": 0.002,
        }
        | ({"watchdog_timeout_s": 0.5, "encoder_period_s": 0.01} if family == "odrive" else {}),
    }
    lines = [f"name = {_toml(name)}"]
    for table, keys in tables.items():
        lines.append(f"\n[{table}]")
        lines.extend(f"{k} = {_toml(v)}" for k, v in keys.items())
    for i, (node, anchor) in enumerate(zip(spec["nodes"], ANCHORS, strict=True)):
        lines.append("\n[[reels]]")
        lines.append(f"node_id = {node}")
        lines.append(f"anchor_m = {_toml(anchor)}")
        lines.append("drum_radius_m = 0.015")
        if i >= 2:
            lines.append("direction = -1")
    return "\n".join(lines) + "\n"


class Daemon:
    """`cablebot run --config FILE` as a child process; its stderr goes to a log file."""

    def __init__(self, config: Path, log_path: Path) -> None:
        self.config = config
        self.log_path = log_path
        self.proc: subprocess.Popen[bytes] | None = None
        self.starts = 0

    @property
    def pid(self) -> int:
        """The running daemon's process id. Raises RuntimeError if none runs."""
        if self.proc is None or self.proc.poll() is not None:
            raise RuntimeError("the daemon is not running")
        return self.proc.pid

    def alive(self) -> bool:
        """True while the daemon process runs."""
        return self.proc is not None and self.proc.poll() is None

    def start(self) -> None:
        """Start the daemon (its log appended to `log_path`)."""
        env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONPATH=str(REPO))
        env.pop("NOTIFY_SOCKET", None)
        with open(self.log_path, "ab") as log:
            log.write(f"--- chaos: daemon start {self.starts + 1}\n".encode())
            self.proc = subprocess.Popen(
                [*CABLEBOT, "run", "--config", str(self.config), "--status-every", "0"],
                cwd=REPO,
                env=env,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=log,
                preexec_fn=die_with_parent,
            )
        self.starts += 1

    def kill9(self) -> None:
        """SIGKILL the daemon and reap it."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)

    def stop(self) -> int | None:
        """SIGTERM (then SIGKILL after 10 s); the exit status."""
        p = self.proc
        if p is None:
            return None
        if p.poll() is None:
            p.send_signal(signal.SIGCONT)
            p.send_signal(signal.SIGTERM)
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(10)
        return p.returncode

    def rss_bytes(self) -> int | None:
        """The daemon's resident set size now (None if it is not running)."""
        try:
            for line in Path(f"/proc/{self.pid}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
        except (OSError, RuntimeError, ValueError):
            return None
        return None


def run_root(cmd: list[str]) -> bool:
    """Run a system command (ip, mount) quietly; True if it succeeded."""
    try:
        return subprocess.run(cmd, capture_output=True, timeout=20).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


class ClientNet:
    """A network namespace with a veth link to this host, for a client that can be cut off.

    Addresses: a /30 of 10.213.X.0 on the veth pair this worker made (the namespace's test host
    only, as the project's off-host guard test does). `cut()` takes the host's end down,
    `restore()` brings it back. Needs root (`available` says whether it was made)."""

    def __init__(self, tag: str, subnet: int) -> None:
        self.ns = f"cbchaos-{tag}"
        self.host_if = f"cbh{tag}"[:15]
        self.ns_if = f"cbn{tag}"[:15]
        self.host_addr = f"10.213.{subnet}.1"
        self.ns_addr = f"10.213.{subnet}.2"
        self.available = False

    def setup(self) -> bool:
        """Make the namespace and the link; True if it worked (root and iproute2)."""
        if os.geteuid() != 0:
            return False
        self.teardown()
        steps = [
            ["ip", "netns", "add", self.ns],
            ["ip", "link", "add", self.host_if, "type", "veth", "peer", "name", self.ns_if],
            ["ip", "link", "set", self.ns_if, "netns", self.ns],
            ["ip", "addr", "add", f"{self.host_addr}/30", "dev", self.host_if],
            ["ip", "link", "set", self.host_if, "up"],
            ["ip", "-n", self.ns, "addr", "add", f"{self.ns_addr}/30", "dev", self.ns_if],
            ["ip", "-n", self.ns, "link", "set", self.ns_if, "up"],
            ["ip", "-n", self.ns, "link", "set", "lo", "up"],
        ]
        self.available = all(run_root(s) for s in steps)
        if not self.available:
            self.teardown()
        return self.available

    def cut(self) -> None:
        """Cut the link between the client and the daemon."""
        run_root(["ip", "link", "set", self.host_if, "down"])

    def restore(self) -> None:
        """Restore the link."""
        run_root(["ip", "link", "set", self.host_if, "up"])

    def teardown(self) -> None:
        """Remove the link and the namespace (idempotent)."""
        run_root(["ip", "link", "del", self.host_if])
        run_root(["ip", "netns", "del", self.ns])

    def popen(self, args: list[str], log: Any) -> subprocess.Popen[bytes]:
        """Start `args` inside the namespace."""
        env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONPATH=str(REPO))
        return subprocess.Popen(
            ["ip", "netns", "exec", self.ns, *args],
            cwd=REPO,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=log,
        )


class StateDir:
    """The state file's directory on a small tmpfs of its own, so it can be made read-only or
    full while offsets are saved (needs root and mount; else a plain directory, `available`
    False)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.available = False
        self._filler = path / "filler"

    def setup(self) -> bool:
        """Mount the tmpfs; True if it worked."""
        self.path.mkdir(parents=True, exist_ok=True)
        if os.geteuid() == 0:
            self.available = run_root(
                ["mount", "-t", "tmpfs", "-o", "size=256k", "cbchaos", str(self.path)]
            )
        return self.available

    def read_only(self) -> None:
        """Remount it read-only."""
        run_root(["mount", "-o", "remount,ro", str(self.path)])

    def fill(self) -> None:
        """Fill it up (ENOSPC for the next write)."""
        with contextlib.suppress(OSError), open(self._filler, "wb") as f:
            while True:
                f.write(b"\0" * 65536)
                f.flush()

    def restore(self) -> None:
        """Writable again and with room."""
        run_root(["mount", "-o", "remount,rw", str(self.path)])
        with contextlib.suppress(OSError):
            self._filler.unlink()

    def teardown(self) -> None:
        """Unmount it (idempotent)."""
        if self.available:
            run_root(["umount", "-l", str(self.path)])
            self.available = False


class MemoryCage:
    """A memory cgroup (v2, else v1) the daemon can be moved into and limited by, for a while."""

    def __init__(self, tag: str) -> None:
        self.tag = tag
        self.dir: Path | None = None
        self._limit_file = ""
        self._procs: Path | None = None
        self._parent_procs: Path | None = None

    def setup(self) -> bool:
        """Make the cgroup; True if this host lets us."""
        if os.geteuid() != 0:
            return False
        v2 = Path("/sys/fs/cgroup/cgroup.controllers")
        candidates: list[tuple[Path, str]] = []
        if v2.exists():
            candidates.append((Path("/sys/fs/cgroup"), "memory.max"))
        own = _own_v1_memory_cgroup()
        if own is not None:
            candidates.append((own, "memory.limit_in_bytes"))
        for parent, limit in candidates:
            d = parent / f"cbchaos-{self.tag}"
            try:
                d.mkdir(exist_ok=True)
            except OSError:
                continue
            if (d / limit).exists():
                self.dir, self._limit_file = d, limit
                self._procs = d / "cgroup.procs"
                self._parent_procs = parent / "cgroup.procs"
                return True
        return False

    def limit(self, pid: int, limit_bytes: int) -> bool:
        """Move `pid` in and cap its memory at `limit_bytes`; True if it worked."""
        if self.dir is None or self._procs is None:
            return False
        try:
            (self.dir / self._limit_file).write_text(str(limit_bytes))
            self._procs.write_text(str(pid))
            return True
        except OSError:
            return False

    def release(self, pid: int | None) -> None:
        """Lift the limit and move `pid` back out."""
        if self.dir is None:
            return
        with contextlib.suppress(OSError):
            (self.dir / self._limit_file).write_text(
                "max" if self._limit_file == "memory.max" else "-1"
            )
        if pid is not None and self._parent_procs is not None:
            with contextlib.suppress(OSError):
                self._parent_procs.write_text(str(pid))

    def teardown(self) -> None:
        """Remove the cgroup (after `release`)."""
        if self.dir is not None:
            with contextlib.suppress(OSError):
                self.dir.rmdir()
            self.dir = None


def _own_v1_memory_cgroup() -> Path | None:
    for line in Path("/proc/self/cgroup").read_text().splitlines():
        parts = line.split(":", 2)
        if len(parts) == 3 and "memory" in parts[1].split(","):
            p = Path("/sys/fs/cgroup/memory") / parts[2].lstrip("/")
            return p if p.is_dir() else None
    return None


def busy_loops(n: int) -> list[subprocess.Popen[bytes]]:
    """`n` processes that spin on a core until killed (the CPU taken from the daemon)."""
    return [
        subprocess.Popen(
            [sys.executable, "-c", "while True: pass"],
            stdin=subprocess.DEVNULL,
            preexec_fn=die_with_parent,
        )
        for _ in range(n)
    ]


def end_all(procs: list[subprocess.Popen[bytes]]) -> None:
    """Kill and reap the processes this worker started."""
    for p in procs:
        if p.poll() is None:
            p.kill()
    for p in procs:
        with contextlib.suppress(subprocess.TimeoutExpired):
            p.wait(5)


def wait_for(pred: Any, timeout_s: float, step_s: float = 0.02) -> bool:
    """Poll `pred()` until true or `timeout_s` passes."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(step_s)
    return bool(pred())
