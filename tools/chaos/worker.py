"""One chaos worker: a daemon of one drive family, its equipment, a client flying paths and jobs,
faults injected one after another at random moments, the robot brought back after each, and
the invariants checked all along. `run_worker` returns the report (a JSON-able dict).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import random
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from chaos import faults as fk
from chaos.checks import TRACKING_STATES, Checker
from chaos.equipment import ChaosBus, Drives, Tap, fpk
from chaos.robot import (
    REPO,
    ClientNet,
    Daemon,
    MemoryCage,
    StateDir,
    free_tcp_port,
    robot_toml,
    wait_for,
)

ESTOP_TARGET_S = 0.05
"""Target: every drive's e-stop frame on the bus this soon after the client's request (the
figures are reported against it)."""
ESTOP_END_TO_END_S = 0.2
"""Pass bound on a loaded shared machine (the project's e-stop flood test keeps the same)."""
STOP = threading.Event()
"""Set by a signal: the run stops injecting, tears down and reports what it has."""
LATE_FRACTION = 0.7
"""Kinds that restart the daemon come only in the last 30 % of the run, so one daemon lives
through the rest and its memory over minutes can be judged."""
DEADMAN_S = 1.0
"""A jogging client cut off: the robot holds within this (0.25 s velocity timeout, braking)."""

_JOG = """
import json, sys, time, zenoh
from controller.service.zenoh_io import client_config
endpoint, prefix, speed = sys.argv[1], sys.argv[2], float(sys.argv[3])
s = zenoh.open(client_config([endpoint]))
pub = s.declare_publisher(prefix + "/velocity")
t0 = time.monotonic()
while True:
    sign = 1.0 if int((time.monotonic() - t0) / 0.6) % 2 == 0 else -1.0
    pub.put(json.dumps({"velocity_mps": [sign * speed, 0.0, 0.0]}))
    time.sleep(0.04)
"""


class StallWatch(threading.Thread):
    """A thread that only sleeps 10 ms at a time: a gap of 100 ms or more between its wake-ups
    is a stall of the whole machine (another job took the CPUs), not of the daemon alone."""

    def __init__(self) -> None:
        super().__init__(name="chaos-stall-watch", daemon=True)
        self.stalls: list[tuple[float, float]] = []

    def run(self) -> None:
        last = time.monotonic()
        while True:
            time.sleep(0.01)
            now = time.monotonic()
            if now - last >= 0.1:
                self.stalls.append((last, now))
            last = now

    def overlapping(self, start_s: float, end_s: float) -> list[tuple[float, float]]:
        """The stalls that overlap [start_s, end_s]."""
        return [(a, b) for a, b in list(self.stalls) if a <= end_s and b >= start_s]

    def summary(self) -> dict[str, Any]:
        """How many stalls, and the longest (seconds)."""
        gaps = [b - a for a, b in list(self.stalls)]
        return {"count": len(gaps), "longest_s": round(max(gaps), 3) if gaps else 0.0}


class Worker:
    """The chaos run of one drive family (see the module docstring)."""

    def __init__(self, family: str, duration_s: float, seed: int, workdir: Path, tag: str) -> None:
        self.family = family
        self.duration_s = duration_s
        self.rng = random.Random(seed)
        self.seed = seed
        self.workdir = workdir
        self.tag = tag
        self.name = f"chaos{family}{uuid.uuid4().hex[:6]}"
        self.prefix = f"cablebot/{self.name}"
        self.port = free_tcp_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.child_env = dict(os.environ, PYTHONPATH=str(REPO))
        self.net = ClientNet(tag, subnet=self.rng.randint(1, 250))
        self.state_dir = StateDir(workdir / "state")
        self.cage = MemoryCage(tag)
        self.records: list[dict[str, Any]] = []
        self.unprovoked: list[dict[str, Any]] = []
        self.excused: list[dict[str, Any]] = []
        """Deadlines missed while the whole machine stalled (reported, not violations)."""
        self.stall_watch = StallWatch()
        """Faults no injection caused (the machine's own stalls): named, and recovered."""
        self.unavailable: dict[str, str] = {}
        self.flights = {"paths": 0, "jobs": 0, "moves": 0, "refused": 0}
        self.estop_times: list[tuple[float, float]] = []
        self.fly = threading.Event()
        self._stop = threading.Event()
        self._session: Any = None
        self._subs: list[Any] = []
        self._hostile: Any = None
        self.overwritten: dict[int, int] = {}
        """The daemon's `pose_overwritten` (poses it did not publish), per daemon start."""
        self._daemon_ran_s = time.monotonic()

    # --- set-up and tear-down --------------------------------------------------------------

    def setup(self) -> None:
        """Make the equipment, write the robot file, start the drives, the tap and the daemon."""
        from controller.service.config import load_config
        from controller.service.simulated import sim_bank
        from drivers.bus import open_bus

        self.net_ready = self.net.setup()
        self.state_dir.setup()
        self.cage_ready = self.cage.setup()
        listen = [self.endpoint]
        if self.net_ready:
            listen.append(f"tcp/{self.net.host_addr}:{self.port}")
        self.config = self.workdir / f"{self.name}.toml"
        self.config.write_text(robot_toml(self.family, self.name, self.workdir, listen, self.rng))
        self.cfg = load_config(str(self.config))
        b = self.cfg.bus
        opts = dict(b.options)
        self.sim_bus = open_bus(b.interface, b.channel, **opts)
        self.tap_bus = open_bus(b.interface, b.channel, **opts)
        self.inject_bus = open_bus(b.interface, b.channel, **opts)
        self.chaos_bus = ChaosBus(self.sim_bus, random.Random(self.seed + 1))
        self.bank = sim_bank(self.cfg, self.chaos_bus)
        self.bank.start()
        # The drives' thread gets the loop's scheduling one step below, as `cablebot sim` does:
        # a starved simulator looks like a stale drive.
        from controller.service.simulated import schedule_sim_thread

        self.sim_scheduling = schedule_sim_thread(self.cfg, getattr(self.bank, "_thread", None))
        self.drives = Drives(self.family, self.bank, self.cfg)
        self.anchors = np.array(self.cfg.anchors_m, dtype=float)
        self._residual_home_m = 0.8 * float(self.cfg.faults.residual_max_m)
        self.checker = Checker(self.anchors, float(self.cfg.faults.tracking_max_m))
        self.tap = Tap(
            self.tap_bus,
            self.family,
            self.cfg,
            self.drives.encoder_offset_rev,
            self.checker.violation,
            self.drives.new_count,
        )
        self.tap.start()
        self.daemon = Daemon(self.config, self.workdir / f"{self.name}-daemon.log")
        self.daemon.start()
        self._connect()

    def teardown(self) -> None:
        """Stop everything this worker started, undo the host changes (every step tried)."""
        self._stop.set()
        self.fly.clear()
        daemon = getattr(self, "daemon", None)
        steps: list[Any] = []
        if daemon is not None:
            steps.append(lambda: self.cage.release(daemon.pid if daemon.alive() else None))
            steps.append(lambda: setattr(self, "exit_status", daemon.stop()))
        steps.append(self._close_session)
        steps.append(self.drop_hostile_session)
        for name in ("tap", "bank"):
            part = getattr(self, name, None)
            if part is not None:
                steps.append(part.stop)
        for name in ("sim_bus", "tap_bus", "inject_bus"):
            bus = getattr(self, name, None)
            if bus is not None:
                steps.append(bus.shutdown)
        steps += [self.net.teardown, self.state_dir.teardown, self.cage.teardown]
        for step in steps:
            try:
                step()
            except Exception as exc:  # the rest still has to be undone
                print(
                    f"chaos: {self.family}: teardown: {type(exc).__name__}: {exc}", file=sys.stderr
                )

    # --- the client ------------------------------------------------------------------------

    def open_session(self, timeout_s: float = 30.0) -> Any:
        """A Zenoh client session to the daemon (retried until it listens)."""
        import zenoh

        from controller.service.zenoh_io import client_config

        deadline = time.monotonic() + timeout_s
        while True:
            try:
                return zenoh.open(client_config([self.endpoint]))
            except Exception:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)

    def _connect(self) -> None:
        self._close_session()
        s = self.open_session()
        self._subs = [
            s.declare_subscriber(
                f"{self.prefix}/pose", lambda x: self.checker.pose_sample(x.payload.to_bytes())
            ),
            s.declare_subscriber(
                f"{self.prefix}/state", lambda x: self.checker.state_sample(x.payload.to_bytes())
            ),
        ]
        self._session = s

    def hostile_flood(self, verb: str, seconds: float, seed: int) -> str:
        """Have the hostile client (`chaos.hostile`, started once, kept) flood the daemon."""
        import subprocess

        from chaos.robot import die_with_parent

        p = self._hostile
        if p is None or p.poll() is not None:
            p = self._hostile = subprocess.Popen(
                [sys.executable, "-m", "chaos.hostile", self.endpoint, self.prefix],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                env=dict(self.child_env, PYTHONPATH=f"{REPO / 'tools'}{os.pathsep}{REPO}"),
                preexec_fn=die_with_parent,
            )
        assert p.stdin is not None and p.stdout is not None
        p.stdin.write(f"{verb} {seconds} {seed}\n".encode())
        p.stdin.flush()
        line = p.stdout.readline().decode().strip()  # it answers after the flood (or dies)
        return f"{line.removeprefix('sent ') or 'no'} malformed or oversized commands" + (
            " from a new session" if verb == "flood_new" else ""
        )

    def drop_hostile_session(self) -> None:
        """End the hostile client."""
        p = self._hostile
        if p is not None and p.poll() is None:
            p.kill()
            with contextlib.suppress(Exception):
                p.wait(5)
        self._hostile = None

    def _close_session(self) -> None:
        for sub in self._subs:
            with contextlib.suppress(Exception):
                sub.undeclare()
        self._subs = []
        if self._session is not None:
            with contextlib.suppress(Exception):
                self._session.close()
            self._session = None

    def q(self, key: str, payload: Any = None, timeout_s: float = 5.0) -> dict[str, Any]:
        """Query `<prefix>/<key>` once; the JSON reply, or {"error": ...}."""
        body = None if payload is None else json.dumps(payload)
        try:
            for reply in self._session.get(f"{self.prefix}/{key}", payload=body, timeout=timeout_s):
                if reply.ok is not None:
                    out: dict[str, Any] = json.loads(reply.ok.payload.to_bytes())
                    return out
                err = reply.err.payload.to_bytes()
                with contextlib.suppress(ValueError):
                    e = json.loads(err)
                    return e if isinstance(e, dict) and "error" in e else {"error": e}
                return {"error": err.decode(errors="replace")}
        except Exception as exc:
            return {"error": f"query failed: {exc}"}
        return {"error": "no reply"}

    def state(self) -> str:
        """The daemon's state as its latest pose sample says (the state key if none yet)."""
        return self.checker.current_state()

    def truth_pose(self) -> list[float]:
        """Where the effector truly is (the simulated drives' positions, FPK written here)."""
        guess = np.array(self.checker.last_tracking_pose_m or [0.0, 0.0, 0.3])
        p, _ = fpk(self.anchors, self.drives.true_lengths_m(), guess)
        return [round(float(v), 5) for v in p]

    def _fly(self) -> None:
        """The client: paths, jobs (a path and appended chunks) and moves, whenever holding."""
        rng = random.Random(self.seed + 2)

        def point() -> list[float]:
            return [rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(0.12, 0.55)]

        while not self._stop.is_set():
            if not self.fly.is_set() or self.state() != "HOLDING":
                time.sleep(0.05)
                continue
            speed = rng.uniform(0.1, 0.3)
            kind = rng.choice(("path", "job", "move"))
            if kind == "move":
                r = self.q("cmd/move", {"position_m": point(), "speed_mps": speed})
            else:
                r = self.q(
                    "cmd/path",
                    {"points_m": [point() for _ in range(rng.randint(2, 6))], "speed_mps": speed},
                )
                if kind == "job" and "error" not in r:
                    for _ in range(rng.randint(1, 3)):
                        if not self.fly.is_set():
                            break
                        time.sleep(rng.uniform(0.2, 0.8))
                        a = self.q(
                            "cmd/path", {"points_m": [point() for _ in range(3)], "append": True}
                        )
                        if "error" in a:
                            break
            self.flights[kind + "s"] += 1
            if "error" in r:
                self.flights["refused"] += 1
            wait_for(lambda: self.state() != "HOLDING" or not self.fly.is_set(), 1.0)
            wait_for(lambda: self.state() != "MOVING" or not self.fly.is_set(), 30.0, 0.05)

    # --- the monitor -------------------------------------------------------------------------

    def _monitor(self) -> None:
        """Tracking every 50 ms, RSS every 2 s, the daemon's life."""
        next_rss = 0.0
        next_status = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if self.daemon.alive():
                ran = now - self._daemon_ran_s > 0.5 and not self._in_stall(now)
                self.checker.tracking(
                    self.drives.true_lengths_m(),
                    self.tap.commanded_lengths(0.2),
                    ran,
                    self.stall_watch.overlapping,
                )
                if now >= next_rss:
                    self.checker.sample_rss(self.daemon.rss_bytes(), self.daemon.starts)
                    next_rss = now + 2.0
                if now >= next_status:
                    self._note_overwritten()
                    next_status = now + 3.0
            time.sleep(0.05)

    def _late(self, start_s: float, end_s: float, kind: str, what: str) -> None:
        """A deadline missed: a violation, unless the whole machine stalled meanwhile (this
        worker's own clock thread saw a gap of 100 ms or more): then noted as excused."""
        stalls = self.stall_watch.overlapping(start_s, end_s)
        if stalls:
            worst = max(b - a for a, b in stalls)
            self.excused.append({"kind": kind, "what": what, "machine_stall_s": round(worst, 3)})
        else:
            self.checker.violation(kind, what)

    def _note_overwritten(self) -> None:
        start = self.daemon.starts
        z = self.q("status", timeout_s=2.0).get("zenoh") or {}
        n = z.get("pose_overwritten")
        if isinstance(n, int) and start == self.daemon.starts:
            self.overwritten[start] = max(n, self.overwritten.get(start, 0))

    def _in_stall(self, now: float) -> bool:
        return any(a - 0.5 <= now <= b + 0.5 for a, b in self.checker._stalls)

    # --- bringing the robot back -------------------------------------------------------------

    def home_at_truth(self) -> dict[str, Any]:
        """`home` at the true pose (an operator puts the effector on a known mark)."""
        return self.q("cmd/home", {"position_m": self.truth_pose()})

    def recover(self, deadline_s: float = 40.0) -> dict[str, Any]:
        """Reset and arm until the robot holds again, as an operator would: re-home first when
        the daemon's pose disagrees with where the robot is (a drive that lost its count).
        Returns what it took."""
        t0 = time.monotonic()
        steps: list[str] = []
        rehomed = False
        while time.monotonic() - t0 < deadline_s and not STOP.is_set():
            st = self.state()
            if st in TRACKING_STATES:
                return {
                    "ok": True,
                    "s": round(time.monotonic() - t0, 2),
                    "steps": steps,
                    "rehomed": rehomed,
                }
            if st in ("FAULT", "ESTOPPED"):
                steps.append("reset")
                self.q("cmd/reset")
                wait_for(lambda: self.state() not in ("FAULT", "ESTOPPED"), 2.0)
            elif st == "DISARMED":
                fresh = time.monotonic()
                wait_for(lambda f=fresh: self.checker.pose_t > f + 0.1, 1.0)  # a pose since reset
                pose = self._pose().get("position_m")
                residual = float(self._pose().get("residual_m") or 0.0)
                truth = self.truth_pose()
                # Home again where the daemon's pose is off, or its cables disagree (a drive
                # that stopped while the others moved on: the kinematic simulator has no cable
                # to go slack, so the turns stay apart and every arm faults `residual`).
                off_m = math.inf if pose is None else math.dist(pose, truth)
                if off_m > 0.002 or residual > self._residual_home_m:
                    steps.append(
                        f"home ({1e3 * off_m:.1f} mm off, residual {1e3 * residual:.1f} mm)"
                    )
                    self.home_at_truth()
                    rehomed = True
                    wait_for(lambda p=truth: self._pose_near(p, 0.002), 2.0)
                steps.append("arm")
                r = self.q("cmd/arm")
                if "error" in r:
                    steps.append(f"refused: {str(r['error'])[:60]}")
                    time.sleep(0.3)
                    continue
                wait_for(lambda: self.state() not in ("DISARMED", "ARMING"), 8.0)
            elif st == "ARMING":
                wait_for(lambda: self.state() != "ARMING", 8.0)
            elif st == "PRETENSIONING":
                self.q("cmd/stop")
                time.sleep(0.2)
            else:
                time.sleep(0.1)
        return {
            "ok": False,
            "s": round(time.monotonic() - t0, 2),
            "steps": steps[-12:],
            "rehomed": rehomed,
        }

    def _brake(self) -> None:
        """No more flights; brake what is flying to a hold."""
        self.fly.clear()
        time.sleep(0.1)  # a flight being sent now is taken before the stop
        if self.state() == "MOVING":
            self.q("cmd/stop")
            wait_for(lambda: self.state() != "MOVING", 5.0)

    def _pose(self) -> dict[str, Any]:
        """The latest pose sample ({} before the first)."""
        return self.checker.last_pose or {}

    def _pose_near(self, p: list[float], tol_m: float) -> bool:
        pose = self._pose().get("position_m")
        return pose is not None and math.dist(pose, p) <= tol_m

    # --- faults that need the worker's hands ----------------------------------------------

    def estop_and_time(self) -> str:
        """E-stop at a random moment: the e-stop frame of every drive on the bus (kernel
        receive stamps), every drive out of closed loop, the daemon's confirmation."""
        self.tap.estop_stamps = {}
        was = self.drives.closed_loop()
        t0_wall = time.time()
        t0 = time.monotonic()
        r = self.q("cmd/estop")
        out_s = None
        while time.monotonic() - t0 < 2.0:
            if not any(self.drives.closed_loop()):
                out_s = time.monotonic() - t0
                break
            time.sleep(0.001)
        # The tap reads the bus in this process: on a stalled machine it may be behind. Its
        # stamps are the kernel's, so waiting for it changes no figure.
        wait_for(lambda: len(self.tap.estop_stamps) >= len(self.drives.node_ids), 3.0)
        stamps = dict(self.tap.estop_stamps)
        if out_s is None:
            self.checker.violation(
                "estop", f"a drive still in closed loop 2 s after the e-stop ({r})"
            )
        if any(was):
            missing = [n for n in self.drives.node_ids if n not in stamps]
            if missing:
                self.checker.violation(
                    "estop", f"no e-stop frame for nodes {missing} on the bus ({r})"
                )
            else:
                frames_s = max(stamps.values()) - t0_wall
                self.estop_times.append((frames_s, out_s if out_s is not None else math.inf))
                what = f"the last drive's e-stop frame {1e3 * frames_s:.1f} ms after the request"
                if frames_s > ESTOP_END_TO_END_S:
                    self._late(t0, t0 + frames_s, "estop", what)
        confirmed = wait_for(
            lambda: bool((self.q("status").get("estop") or {}).get("confirmed")), 2.0, 0.1
        )
        if not confirmed:
            self.checker.violation(
                "estop", f"not confirmed within 2 s: {self.q('status').get('estop')}"
            )
        idle = "" if any(was) else "(drives not in closed loop) "
        return f"e-stop {idle}{r.get('state', r.get('error'))}"

    def save_offsets_with(self, spoil: Any, what: str) -> str:
        """Disarm, spoil the state directory, home (the save must fail by name and the daemon go
        on), restore it, home again (saved), arm."""
        self._brake()
        spoil()
        try:
            r = self._home_disarmed()
        finally:
            self.state_dir.restore()
        err = str(r.get("error", ""))
        if r.get("saved") is not False or not err:
            self.checker.violation("state_file", f"home with the state directory {what}: {r}")
        r2 = self._home_disarmed()
        if r2.get("saved") is not True:
            self.checker.violation("state_file", f"home after the directory was restored: {r2}")
        return f"save into a {what} directory: {err[:80] or r}"

    def _home_disarmed(self) -> dict[str, Any]:
        """Disarm (after a reset if a stall of the machine faulted it meanwhile) and home at the
        true pose; the reply of the home that was taken (a refusal for the state is retried)."""
        r: dict[str, Any] = {}
        for _ in range(5):
            if self.state() in ("FAULT", "ESTOPPED"):
                self.q("cmd/reset")
            self.q("cmd/disarm")
            wait_for(lambda: self.state() == "DISARMED", 3.0)
            r = self.home_at_truth()
            if not str(r.get("error", "")).startswith("not allowed in"):
                break
        return r

    def _cable_offsets_m(self) -> list[float] | None:
        """Each cable's length as the daemon says, less its true length, from a pose sample
        taken after this call, the robot standing still (None without one)."""
        t = time.monotonic()
        if not wait_for(lambda: self.checker.pose_t > t + 0.05, 2.0):
            return None
        cables = self._pose().get("cable_lengths_m") or []
        true_l = self.drives.true_lengths_m()
        if len(cables) != len(true_l):
            return None
        return [float(a) - float(b) for a, b in zip(cables, true_l, strict=True)]

    def kill_and_restart(self) -> str:
        """Holding still, kill -9 and restart: homed from the state file, each cable's length
        as before (against its true length: a re-home at a true pose where the cables
        disagreed leaves each one its own small offset from the truth)."""
        self._brake()
        time.sleep(0.3)
        before = self._cable_offsets_m()
        self._note_overwritten()
        t0 = time.monotonic()
        self.daemon.kill9()
        self.checker.last_pose = None
        time.sleep(self.rng.uniform(0.2, 1.0))
        self.daemon.start()
        self._daemon_ran_s = time.monotonic()
        self._connect()
        self.drop_hostile_session()
        ok = wait_for(lambda: bool(self._pose().get("valid")), 30.0, 0.05)
        self.tap.forget_history()
        if not ok:
            self.checker.violation("restart", "no valid pose within 30 s of the restart")
            return "restart: no valid pose"
        time.sleep(0.3)  # the drives stop where the watchdog left them
        pose = self._pose()["position_m"]
        truth = self.truth_pose()
        err = math.dist(pose, truth)
        source = self.q("status").get("home_source")
        after = self._cable_offsets_m()
        worst = (
            math.inf
            if before is None or after is None
            else max(abs(a - b) for a, b in zip(after, before, strict=True))
        )
        if worst > 1e-4:
            self.checker.violation(
                "restart", f"cable lengths after restart {worst * 1e3:.3f} mm from before"
            )
        if source != "state_file":
            self.checker.violation("restart", f"homed from {source!r}, not the state file")
        self.checker.stall(t0, time.monotonic())
        return (
            f"restarted in {time.monotonic() - t0:.1f} s, cables within {worst * 1e3:.4f} mm of"
            f" before, pose {err * 1e3:.3f} mm from the truth"
        )

    def jog_and_cut(self, rng: random.Random) -> str:
        """A jogging client in the namespace; cut; the robot holds within DEADMAN_S; restore."""
        import subprocess

        self._brake()
        endpoint = f"tcp/{self.net.host_addr}:{self.port}"
        with open(self.workdir / f"{self.name}-jog.log", "ab") as log:
            proc = self.net.popen([sys.executable, "-c", _JOG, endpoint, self.prefix, "0.05"], log)
        try:
            moving = wait_for(lambda: self.state() == "MOVING", 8.0)
            time.sleep(rng.uniform(0.2, 1.0))
            cut_s = rng.uniform(1.0, 3.0)
            t_cut = time.monotonic()
            self.net.cut()
            held = wait_for(lambda: self.state() != "MOVING", DEADMAN_S + 2.0, 0.005)
            held_s = time.monotonic() - t_cut
            if moving and (not held or held_s > DEADMAN_S):
                what = f"still {self.state()} {held_s:.2f} s after the cut"
                self._late(t_cut, t_cut + held_s, "deadman", what)
            time.sleep(max(0.0, cut_s - held_s))
            self.net.restore()
            resumed = wait_for(lambda: self.state() == "MOVING", 10.0)
        finally:
            proc.kill()
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(5)
            self.net.restore()
        wait_for(lambda: self.state() != "MOVING", 5.0)
        if not moving:
            return "the jog client never moved the robot"
        again = "resumed" if resumed else "not resumed"
        return f"cut {cut_s:.1f} s: held after {held_s * 1e3:.0f} ms; {again} when restored"

    # --- the run -------------------------------------------------------------------------------

    only: list[str] | None = None

    def _kinds(self) -> list[str]:
        kinds = [k for k in fk.KINDS if fk.FAMILY_ONLY.get(k, self.family) == self.family]
        if self.only is not None:
            return [k for k in kinds if k in self.only] or kinds
        return [k for k in kinds if k not in fk.NOT_BY_DEFAULT]

    def run(self) -> dict[str, Any]:
        """The whole run; the report."""
        t_start = time.monotonic()
        self.setup()
        try:
            self._run_body(t_start)
        finally:
            self.teardown()
        return self.report(time.monotonic() - t_start)

    def _run_body(self, t_start: float) -> None:
        if not wait_for(lambda: bool(self._pose().get("valid")), 60.0, 0.05):
            raise RuntimeError(f"{self.family}: the daemon published no valid pose in 60 s")
        self.home_at_truth()  # writes the state file the restart test reads
        rec = self.recover()
        if not rec["ok"]:
            raise RuntimeError(f"{self.family}: could not arm at the start: {rec}")
        threading.Thread(target=self._monitor, name="chaos-monitor", daemon=True).start()
        self.stall_watch.start()
        threading.Thread(target=self._fly, name="chaos-client", daemon=True).start()
        bag: list[str] = []
        end_s = t_start + self.duration_s
        while time.monotonic() < end_s - 3.0 and not STOP.is_set():
            self.fly.set()
            time.sleep(self.rng.uniform(0.5, 2.0))
            if not bag:
                bag = self._kinds()
                self.rng.shuffle(bag)
            kind = bag.pop()
            if (
                kind in fk.LATE_KINDS
                and time.monotonic() < t_start + LATE_FRACTION * self.duration_s
            ):
                continue  # one daemon lives through most of the run: its memory is judged
            self._inject(kind)
            if not self.daemon.alive():
                self.checker.violation(
                    "daemon_died",
                    f"after {kind}: exit {self.daemon.stop()}",
                )
                self.daemon.start()
                self._daemon_ran_s = time.monotonic()
                self._connect()
                wait_for(lambda: bool(self._pose().get("valid")), 30.0)
                self.recover()
        self._brake()
        self.checker.check_memory()
        self._note_overwritten()
        lost = self.checker.seq_lost
        overwritten = sum(self.overwritten.values())
        if lost > overwritten:
            self.checker.violation(
                "pose_sequence",
                f"{lost} pose samples missing outside stalls, the daemon overwrote {overwritten}",
            )

    def _inject(self, kind: str) -> None:
        if self.state() not in TRACKING_STATES:
            self._unprovoked()
        armed = self.state() in TRACKING_STATES
        t0 = time.monotonic()
        n_transitions = len(self.checker.transitions)
        record: dict[str, Any] = {
            "kind": kind,
            "t_s": round(t0 - self.checker.started_s, 2),
            "armed": armed,
        }
        try:
            record["note"] = fk.KINDS[kind](self, self.rng)
        except fk.Unavailable as exc:
            self.unavailable[kind] = str(exc)
            return
        except Exception as exc:  # the equipment failed: the run says so and goes on
            record["note"] = f"injection failed: {type(exc).__name__}: {exc}"
            record["equipment_error"] = True
        expect = fk.EXPECT_FAULT.get(kind)
        wait_for(
            lambda: any(
                s in ("FAULT", "ESTOPPED") for _, s, _ in self.checker.transitions[n_transitions:]
            ),
            2.0 if expect is not None and armed else 1.0,
        )
        faulted = [
            (s, r)
            for _, s, r in self.checker.transitions[n_transitions:]
            if s in ("FAULT", "ESTOPPED")
        ]
        if kind in fk.OUTCOME and not record.get("equipment_error"):
            record["outcome"] = fk.OUTCOME[kind]
        elif faulted:
            record["outcome"] = "named_fault"
            record["reason"] = faulted[0][1]
        else:
            record["outcome"] = "rode_through" if self.state() in TRACKING_STATES else "not_armed"
        if expect is not None and armed and not faulted:
            # (Another fault first, a stall of the machine, hides the expected one: noted.)
            self.checker.violation(
                "expected_fault", f"{kind}: expected a {expect} fault, the robot rode through"
            )
        elif expect is not None and faulted and not str(faulted[0][1]).startswith(expect):
            record["masked_by"] = faulted[0][1]
        rec = self.recover()
        record["recovered"] = rec["ok"]
        record["recovery"] = rec
        if not rec["ok"]:
            self.checker.violation(
                "recovery", f"{kind}: reset and arm did not bring the robot back: {rec}"
            )
        self.records.append(record)

    def _unprovoked(self) -> None:
        """The robot left tracking between injections (a stall of this shared machine): note the
        fault, check it was named (the state key did), bring the robot back."""
        faults = [(s, r) for _, s, r in self.checker.transitions if s in ("FAULT", "ESTOPPED")]
        rec: dict[str, Any] = {
            "t_s": round(time.monotonic() - self.checker.started_s, 2),
            "state": self.state(),
            "reason": faults[-1][1] if faults else None,
        }
        rec["recovery"] = self.recover()
        if not rec["recovery"]["ok"]:
            self.checker.violation("recovery", f"after an unprovoked {rec}")
        self.unprovoked.append(rec)

    def report(self, elapsed_s: float) -> dict[str, Any]:
        """The worker's report."""
        by_kind: dict[str, dict[str, int]] = {}
        for r in self.records:
            k = by_kind.setdefault(
                r["kind"],
                {
                    "injected": 0,
                    "while_armed": 0,
                    "rode_through": 0,
                    "named_fault": 0,
                    "recovered": 0,
                    "rehomed": 0,
                },
            )
            k["injected"] += 1
            k["while_armed"] += int(r["armed"])
            k["rode_through"] += int(r["outcome"] == "rode_through")
            k["named_fault"] += int(r["outcome"] == "named_fault")
            k["recovered"] += int(bool(r.get("recovered")) and r["outcome"] == "named_fault")
            k["rehomed"] += int(bool(r.get("recovery", {}).get("rehomed")))
        c = self.checker
        est = sorted(self.estop_times)
        return {
            "family": self.family,
            "seed": self.seed,
            "elapsed_s": round(elapsed_s, 1),
            "faults": by_kind,
            "unavailable": self.unavailable,
            "violations": [
                {"kind": v.kind, "text": v.text, "t_s": round(v.at_s, 2)} for v in c.violations
            ],
            "poses": c.poses,
            "pose_seq_lost": c.seq_lost,
            "pose_seq_lost_in_stalls": c.seq_lost_in_stalls,
            "pose_overwritten": sum(self.overwritten.values()),
            "daemon_starts": self.daemon.starts,
            "rss": c.rss_summary(),
            "rss_samples_mib": [
                (round(t, 1), round(r / 2**20, 1), s)
                for t, r, s in c.rss[:: max(1, len(c.rss) // 60)]
            ],
            "tracking_checks": c.tracking_checks,
            "tap": {"frames": self.tap.frames, "setpoints": self.tap.setpoints},
            "link": {
                "lost": self.chaos_bus.lost,
                "corrupted": self.chaos_bus.corrupted,
                "duplicated": self.chaos_bus.duplicated,
            },
            "flights": self.flights,
            "estop_frames_ms": _percentiles([1e3 * t for t, _ in est]),
            "estop_drives_out_ms": _percentiles(sorted(1e3 * t for _, t in est)),
            "estop_over_target": sum(1 for t, _ in est if t > ESTOP_TARGET_S),
            "unprovoked": self.unprovoked,
            "excused": self.excused
            + [
                {"kind": "tracking", "what": t, "machine_stall_s": None} for t in c.tracking_excused
            ],
            "machine_stalls": self.stall_watch.summary(),
            "records": self.records,
            "daemon_log": str(self.daemon.log_path),
            "exit_status": getattr(self, "exit_status", None),
        }


def _percentiles(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    v = sorted(values)
    return {
        "n": len(v),
        "p50": round(v[len(v) // 2], 1),
        "p99": round(v[min(len(v) - 1, int(0.99 * len(v)))], 1),
        "max": round(v[-1], 1),
    }


def run_worker(
    family: str,
    duration_s: float,
    seed: int,
    workdir: str | None,
    tag: str,
    kinds: list[str] | None = None,
) -> dict[str, Any]:
    """Run one worker in a fresh directory (kept under `workdir` if given); `kinds`: only these
    fault kinds (default: all of the family's)."""
    base = Path(workdir) if workdir else Path(tempfile.mkdtemp(prefix=f"cbchaos-{family}-"))
    base.mkdir(parents=True, exist_ok=True)
    w = Worker(family, duration_s, seed, base, tag)
    if kinds:
        unknown = sorted(set(kinds) - set(fk.KINDS))
        if unknown:
            raise ValueError(f"unknown fault kinds {unknown}: choose from {sorted(fk.KINDS)}")
        w.only = kinds
    return w.run()
