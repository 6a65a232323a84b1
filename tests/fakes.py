"""Shared test doubles: a fake clock, a fake reel driver and a recording publisher.

`FakeDriver` behaves like an ideal set of ODrive reels by default (`follow=True`): after
`arm()` the axes report CLOSED_LOOP_CONTROL at the next poll and every commanded position is
reached at once, with fresh encoder and heartbeat stamps from the fake clock. Like the ODrive
driver it derives the generic status the loop reads (`ready`, `fault`, `state_name`) from the
axis state and error numbers, which the tests set; `read()` does it, so a test that edits the
numbers directly is seen as the driver would report them. Tests switch
parts of that off (`silent`, `axis_error`, `follow=False`, `position_rev` edits) to provoke
faults. It raises ValueError on a non-finite command, as the real driver must, and records
every commanded set-point.

It is also a `drivers.base.TorqueDriver`: in torque mode each axis turns at the velocity the
test puts in `torque_velocity_rps` (the reels wind while that is non-zero and are still when it
is zero), and every torque set-point is recorded in `torques`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from drivers.base import AxisReading, BusError, BusStats
from drivers.odrive.cansimple import axis_state_name, fault_text

CLOSED_LOOP = 8
IDLE = 1


class FakeClock:
    """A monotonic clock that only moves when told to."""

    def __init__(self, start_s: float = 1000.0) -> None:
        self.now_s = start_s

    def __call__(self) -> float:
        return self.now_s

    def advance(self, dt_s: float) -> float:
        """Move the clock forward by `dt_s` and return the new time."""
        self.now_s += dt_s
        return self.now_s

    def wall_ns(self) -> int:
        """A wall clock in ns that follows the fake clock."""
        return int(self.now_s * 1e9)


class FakeDriver:
    """An in-memory ReelDriver (see the module docstring)."""

    def __init__(
        self,
        node_ids: Sequence[int],
        clock: FakeClock,
        positions_rev: Sequence[float] | None = None,
    ) -> None:
        self.node_ids = tuple(node_ids)
        self.clock = clock
        n = len(self.node_ids)
        pos = list(positions_rev) if positions_rev is not None else [0.0] * n
        self.readings = [
            AxisReading(nid, position_rev=p, axis_state=IDLE)
            for nid, p in zip(node_ids, pos, strict=True)
        ]
        self._stats = BusStats()
        self.commands: list[tuple[float, ...]] = []
        self.command_times: list[float] = []
        self.calls: list[str] = []
        self.follow = True
        self.reading_age_s = 0.0
        """How old every reading is when it is read (a late bus, a starved driver thread)."""
        """Commanded positions become the encoder positions at the next poll."""
        self.silent: set[int] = set()
        """Node ids that send nothing (encoder and heartbeat stop)."""
        self.heartbeat_silent: set[int] = set()
        """Node ids whose heartbeats stop (encoders keep coming)."""
        self.no_closed_loop: set[int] = set()
        """Node ids that refuse to enter closed loop on arm()."""
        self.axis_error: dict[int, int] = {}
        self.raise_on_command: Exception | None = None
        self.armed = False
        self._pending_cmd: tuple[float, ...] | None = None
        self.torque_mode = False
        self.torque_velocity_rps: list[float] = [0.0] * n
        """Each axis's velocity while in torque mode (set by the test)."""
        self.torques: list[tuple[float, ...]] = []
        self.velocity_limits_rps: tuple[float, ...] | None = None
        self.limits_applied = True
        """What `enter_torque_mode` answers when given limits."""
        self._last_poll_s: float | None = None

    # ------------------------------------------------------------------ ReelDriver
    def poll(self) -> int:
        now = self.clock()
        dt = 0.0 if self._last_poll_s is None else now - self._last_poll_s
        self._last_poll_s = now
        handled = 0
        for i, r in enumerate(self.readings):
            if r.node_id in self.silent:
                continue
            if self.torque_mode and self.armed and r.axis_error == 0:
                r.velocity_rps = self.torque_velocity_rps[i]
                r.position_rev += r.velocity_rps * dt
            elif self.follow and self._pending_cmd is not None and self.armed:
                new = self._pending_cmd[i]
                r.velocity_rps = 0.0
                r.position_rev = new
            r.stamp_s = now - self.reading_age_s
            r.stamp_ns = int(r.stamp_s * 1e9)
            if r.node_id not in self.heartbeat_silent:
                r.heartbeat_stamp_s = now
            r.axis_error = self.axis_error.get(r.node_id, 0)
            if self.armed and r.node_id not in self.no_closed_loop and r.axis_error == 0:
                r.axis_state = CLOSED_LOOP
            elif r.axis_error:
                r.axis_state = IDLE
            handled += 2
        self._stats.frames_rx += handled
        return handled

    def read(self) -> Sequence[AxisReading]:
        for r in self.readings:
            r.ready = r.axis_state == CLOSED_LOOP and r.axis_error == 0
            r.fault = fault_text(r.axis_error)
            r.state_name = axis_state_name(r.axis_state)
        return self.readings

    def command(
        self, positions_rev: Sequence[float], velocity_ff_rps: Sequence[float] | None = None
    ) -> None:
        vals = tuple(float(v) for v in positions_rev)
        if len(vals) != len(self.node_ids) or not all(math.isfinite(v) for v in vals):
            raise ValueError(f"non-finite or wrong-length command {vals}")
        if self.raise_on_command is not None:
            self._stats.bus_errors += 1
            self._stats.last_error = str(self.raise_on_command)
            raise self.raise_on_command
        self.commands.append(vals)
        self.command_times.append(self.clock())
        self._pending_cmd = vals
        self._stats.frames_tx += len(vals)

    def arm(self) -> None:
        self.calls.append("arm")
        self.armed = True
        self.torque_mode = False
        self.axis_error.clear()

    # ------------------------------------------------------------------ TorqueDriver
    def _check(self, values: Sequence[float], what: str) -> tuple[float, ...]:
        vals = tuple(float(v) for v in values)
        if len(vals) != len(self.node_ids) or not all(math.isfinite(v) for v in vals):
            raise ValueError(f"non-finite or wrong-length {what} {vals}")
        return vals

    def enter_torque_mode(
        self, torques_nm: Sequence[float], velocity_limits_rps: Sequence[float] | None = None
    ) -> bool:
        vals = self._check(torques_nm, "torques")
        if velocity_limits_rps is not None:
            self.velocity_limits_rps = self._check(velocity_limits_rps, "velocity limits")
        self.calls.append("enter_torque_mode")
        self.torques.append(vals)
        if not self.armed:
            self.axis_error.clear()
        self.armed = True
        self.torque_mode = True
        self._pending_cmd = None
        return velocity_limits_rps is not None and self.limits_applied

    def command_torque(self, torques_nm: Sequence[float]) -> None:
        vals = self._check(torques_nm, "torques")
        if self.raise_on_command is not None:
            self._stats.bus_errors += 1
            self._stats.last_error = str(self.raise_on_command)
            raise self.raise_on_command
        self.torques.append(vals)

    def leave_torque_mode(self, positions_rev: Sequence[float]) -> None:
        vals = self._check(positions_rev, "positions")
        self.calls.append("leave_torque_mode")
        self.torque_mode = False
        for r in self.readings:
            r.velocity_rps = 0.0
        self._pending_cmd = vals

    def disarm(self) -> None:
        self.calls.append("disarm")
        self.armed = False
        self.torque_mode = False
        self._pending_cmd = None
        for r in self.readings:
            r.axis_state = IDLE

    def estop(self) -> None:
        self.calls.append("estop")
        self.armed = False
        self.torque_mode = False
        self._pending_cmd = None
        for r in self.readings:
            r.axis_state = IDLE

    def request_encoders(self) -> None:
        self.calls.append("request_encoders")

    @property
    def stats(self) -> BusStats:
        return self._stats

    # ------------------------------------------------------------------ test helpers
    def fail_bus(self, message: str = "bus-off") -> None:
        """Make every following command raise BusError (a bus-off)."""
        self.raise_on_command = BusError(message)


@dataclass
class RecordingPublisher:
    """A Publisher that keeps everything it is given."""

    poses: list[object] = field(default_factory=list)
    states: list[tuple[str, str | None, int]] = field(default_factory=list)

    def publish_pose(self, sample: object) -> None:
        self.poses.append(sample)

    def publish_state(self, state: str, reason: str | None, stamp_ns: int) -> None:
        self.states.append((state, reason, stamp_ns))

    def state_names(self) -> list[str]:
        return [s for s, _, _ in self.states]


def make_config(**sections: dict[str, Any]) -> Any:
    """The built-in default robot with fields of its sections replaced.

    `make_config(loop={"rate_hz": 1000}, faults={"tracking_max_m": 0.01})`; a top-level
    field is replaced with `make_config(top={"name": "x"})`. The staleness windows and the
    tracking limit are a real rig's (50 ms encoder, 0.5 s heartbeat, 0.25 m), not the built-in
    simulated robot's generous ones, so the fault tests measure what a rig does; `faults=`
    overrides them.
    """
    from controller.service.config import default_config

    cfg = default_config()
    cfg = replace(cfg, faults=replace(cfg.faults, stale_timeout_s=0.05, heartbeat_timeout_s=0.5))
    top = dict(sections.pop("top", {}))
    for name, changes in sections.items():
        top[name] = replace(getattr(cfg, name), **changes)
    return replace(cfg, **top)


def power_up_turns(cfg: Any) -> list[float]:
    """Motor turns of the config's reels at its power-up pose (what the sim starts at)."""
    from controller.core import kinematics

    lengths = kinematics.ipk_point(cfg.geometry, cfg.homing.power_up_position_m)
    return [r.reel.position_rev(L) for r, L in zip(cfg.reels, lengths, strict=True)]
