"""A fake controller for the Zenoh interface and client tests, and Zenoh test helpers.

`FakeController` mimics the contract of controller.service.loop.Controller that zenoh_io uses:
submit() queues a command that a tick thread executes (state checks, a box workspace, straight
moves at constant speed), submit_setpoint(), status(), and a `publisher` receiving poses and
states.
"""

from __future__ import annotations

import concurrent.futures
import json
import math
import queue
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from controller.core.commands import (
    Arm,
    Command,
    CommandRefused,
    Disarm,
    Estop,
    Home,
    Move,
    Path,
    Reset,
    Stop,
)


@dataclass
class ZCfg:
    """A stand-in for controller.service.config.ZenohConfig."""

    prefix: str = "cablebot/test"
    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    config_file: str | None = None


@dataclass(frozen=True)
class FakePose:
    """A pose sample with the PoseSample schema."""

    seq: int
    stamp_ns: int
    position_m: tuple[float, float, float] | None
    state: str

    def to_json_bytes(self) -> bytes:
        """The `<prefix>/pose` schema."""
        return json.dumps(
            {
                "seq": self.seq,
                "stamp_ns": self.stamp_ns,
                "position_m": None if self.position_m is None else list(self.position_m),
                "cable_lengths_m": [1.0, 1.0, 1.0, 1.0],
                "residual_m": None if self.position_m is None else 0.0,
                "valid": self.position_m is not None,
                "state": self.state,
            }
        ).encode()


class FakeWorkspace:
    """A box workspace with the `path_failure` the Zenoh interface's pre-check calls."""

    def __init__(self, box_m: Sequence[tuple[float, float]]) -> None:
        self.box_m = tuple(box_m)
        self.calls = 0

    def check_target(self, p: Sequence[float]) -> str | None:
        """The box check."""
        for i, (lo, hi) in enumerate(self.box_m):
            if not lo <= p[i] <= hi:
                return f"outside the workspace: {'xyz'[i]}={p[i]} not in [{lo}, {hi}]"
        return None

    def path_failure(
        self,
        points: Sequence[Sequence[float]],
        start_m: Sequence[float] | None = None,
        *,
        legs: bool = True,
    ) -> tuple[int, str] | None:
        """The first point outside the box (legs of a box path stay in the box)."""
        self.calls += 1
        for i, p in enumerate(points):
            reason = self.check_target(p)
            if reason is not None:
                return i, reason
        return None


class FakeController:
    """A tiny controller: box workspace, constant-speed straight moves, a tick thread."""

    BOX_M = ((-1.0, 1.0), (-1.0, 1.0), (0.5, 3.0))

    def __init__(self, rate_hz: float = 100.0, publisher: Any = None) -> None:
        self.rate_hz = rate_hz
        self.publisher = publisher
        self.state = "DISARMED"
        self.reason: str | None = None
        self.position_m = (0.0, 0.0, 2.0)
        self.target_m: list[tuple[float, float, float]] = []
        self.speed_mps = 0.5
        self.seq = 0
        self.hang = False  # never resolve futures (reply timeout test)
        self.paused = False  # queue commands but do not take them (cancellation test)
        self.submitted: list[Command] = []
        self.workspace = FakeWorkspace(self.BOX_M)
        self.setpoints: list[tuple[float, ...]] = []
        self._queue: queue.Queue[tuple[Command, concurrent.futures.Future[dict[str, Any]]]] = (
            queue.Queue(maxsize=16)
        )
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -------------------------------------------------------------- contract

    def submit(self, cmd: Command) -> concurrent.futures.Future[dict[str, Any]]:
        """Queue `cmd` for the tick thread."""
        self.submitted.append(cmd)
        fut: concurrent.futures.Future[dict[str, Any]] = concurrent.futures.Future()
        if not self.hang:
            self._queue.put((cmd, fut))
        return fut

    def submit_setpoint(self, position_m: Sequence[float]) -> None:
        """Record the set-point."""
        self.setpoints.append(tuple(position_m))

    def check_target(self, p: Sequence[float]) -> str | None:
        """The box workspace check."""
        return self.workspace.check_target(p)

    def status(self) -> dict[str, Any]:
        """A status snapshot."""
        return {
            "state": self.state,
            "reason": self.reason,
            "pose": {"valid": True, "position_m": list(self.position_m), "residual_m": 0.0},
            "axes": [
                {"node_id": i, "axis_state": 8, "axis_error": 0, "age_s": 0.001} for i in range(4)
            ],
            "loop": {
                "rate_hz": self.rate_hz,
                "ticks": self.seq,
                "overruns": 0,
                "jitter_p99_s": math.nan,
            },
        }

    # -------------------------------------------------------------- tick thread

    def start(self) -> FakeController:
        """Start the tick thread."""
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the tick thread."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)

    def _set_state(self, state: str, reason: str | None = None) -> None:
        if state != self.state:
            self.state, self.reason = state, reason
            if self.publisher is not None:
                self.publisher.publish_state(state, reason, time.time_ns())

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        next_t = time.monotonic()
        while not self._stop.is_set():
            self.tick(period)
            next_t += period
            time.sleep(max(0.0, next_t - time.monotonic()))

    def tick(self, dt: float) -> None:
        """Take commands, advance the motion, publish a pose."""
        while not self.paused:
            try:
                cmd, fut = self._queue.get_nowait()
            except queue.Empty:
                break
            if not fut.set_running_or_notify_cancel():
                continue  # cancelled by the interface after a reply timeout: never run it
            try:
                fut.set_result(self._execute(cmd))
            except CommandRefused as exc:
                fut.set_exception(exc)
        if self.target_m:
            tgt = self.target_m[0]
            d = math.dist(self.position_m, tgt)
            step = self.speed_mps * dt
            if d <= step:
                self.position_m = tgt
                self.target_m.pop(0)
                if not self.target_m:
                    self._set_state("HOLDING")
            else:
                f = step / d
                self.position_m = (
                    self.position_m[0] + (tgt[0] - self.position_m[0]) * f,
                    self.position_m[1] + (tgt[1] - self.position_m[1]) * f,
                    self.position_m[2] + (tgt[2] - self.position_m[2]) * f,
                )
        self.seq += 1
        if self.publisher is not None:
            self.publisher.publish_pose(
                FakePose(self.seq, time.time_ns(), self.position_m, self.state)
            )

    def _need(self, *states: str) -> None:
        if self.state not in states:
            raise CommandRefused(f"not allowed in {self.state} (needs {'/'.join(states)})")

    def _execute(self, cmd: Command) -> dict[str, Any]:
        if isinstance(cmd, Arm):
            self._need("DISARMED")
            self._set_state("HOLDING")
        elif isinstance(cmd, Disarm):
            self._need("HOLDING")
            self._set_state("DISARMED")
        elif isinstance(cmd, Reset):
            self._need("FAULT", "ESTOPPED")
            self._set_state("DISARMED")
        elif isinstance(cmd, Estop):
            self.target_m = []
            self._set_state("ESTOPPED", "estop")
        elif isinstance(cmd, Stop):
            self._need("HOLDING", "MOVING")
            self.target_m = []
            self._set_state("HOLDING")
        elif isinstance(cmd, Move | Path):
            self._need("HOLDING", "MOVING")
            points = [cmd.position_m] if isinstance(cmd, Move) else list(cmd.points_m)
            for p in points:
                reason = self.check_target(p)
                if reason:
                    raise CommandRefused(reason)
            self.target_m = points
            if cmd.speed_mps is not None:
                self.speed_mps = cmd.speed_mps
            self._set_state("MOVING")
        elif isinstance(cmd, Home):
            self._need("DISARMED")
            reason = self.check_target(cmd.position_m)
            if reason:
                raise CommandRefused(reason)
            self.position_m = cmd.position_m
        return {"ok": True, "state": self.state}
