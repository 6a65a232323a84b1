"""The controller's status: the JSON-ready snapshot served on `<prefix>/status`, with its
statics and pre-tension parts. Thread-safe: reads only.
"""

from __future__ import annotations

import math
from typing import Any

from controller.core.states import State
from controller.service.control.base import ControllerState, _finite_or_none


class StatusReport(ControllerState):
    """The controller's `status()` snapshot."""

    def _setpoint_and_stamp(self) -> tuple[Any, int | None]:
        """The set-point and the wall-clock time (ns) of the tick that computed it, read
        together: the tick writes the set-point, then its time, so a time that changed while
        the set-point was read is read again with it. A reply that arrives late (a loaded
        machine, a busy network) still dates its set-point right. (None, None) without one."""
        t = self._setpoint_tick_s
        sp = self.setpoint_m
        if self._setpoint_tick_s != t:
            t, sp = self._setpoint_tick_s, self.setpoint_m
        if sp is None or t is None:
            return sp, None
        wall_ns = self._wall_ns()
        return sp, wall_ns - round((self._clock() - t) * 1e9)

    def status(self) -> dict[str, Any]:
        """A JSON-ready snapshot of the controller (thread-safe, for `<prefix>/status`)."""
        now = self._clock()
        axes = []
        for r in self.driver.read():
            r = r.snapshot()
            axes.append(
                {
                    "node_id": r.node_id,
                    "ready": r.ready,
                    "fault": r.fault,
                    "state": r.state_name,
                    "axis_state": r.axis_state,
                    "axis_error": r.axis_error,
                    "position_rev": r.position_rev,
                    "age_s": _finite_or_none(now - r.stamp_s),
                    "heartbeat_age_s": _finite_or_none(now - r.heartbeat_stamp_s),
                }
            )
        bs = self.driver.stats.snapshot()
        valid = self.pose_valid
        pose = self.pose_m
        sp, sp_stamp_ns = self._setpoint_and_stamp()
        return {
            "state": self.state.value,
            "reason": self.reason,
            "state_stamp_ns": self.state_stamp_ns,
            "homed": self.homed,
            "home_source": self.home_source,
            "pose": {
                "valid": valid,
                "position_m": list(pose) if valid and pose is not None else None,
                "residual_m": self.residual_m if valid else None,
                "cable_lengths_m": [_finite_or_none(v) for v in self.lengths_m],
            },
            "setpoint_m": list(sp) if sp is not None else None,
            "setpoint_stamp_ns": sp_stamp_ns,
            "tensions": self._tension_status(sp is not None),
            "pretension": self._pretension_status(now),
            "axes": axes,
            "loop": {
                "rate_hz": 1.0 / self.period_s,
                "ticks": self.ticks,
                **self.loop_stats.figures(),
                "dt_clamped": self.dt_clamped,
            },
            "stream": {
                "refused": self.stream_refused,
                "last_refusal": self.stream_last_refusal,
                "discarded": self.stream_discarded,
                "last_discard": self.stream_last_discard,
            },
            "path": {
                "queued_points": self.planner.queued_points,
                "queued_s": self.planner.queued_s,
                "queue_full": self.planner.queue_full,
                "appendable": self.planner.appendable,
                "blends_dropped": self.planner.blends_dropped,
                "speed_mps": self.path_speed_mps if self.planner.mode == "move" else None,
            },
            "shaper": self.shaping.describe(),
            "velocity": {
                "command_mps": list(self.planner.velocity_command_mps),
                "discarded": self.velocity_discarded,
                "deadman_stops": self.planner.deadman_stops,
                "boundary_brakes": self.planner.boundary_brakes,
            },
            "estop": (
                {
                    "confirmed": self._estop_confirmed,
                    "unconfirmed_nodes": list(self._estop_unconfirmed),
                    "repeats": self.estop_repeats,
                }
                if self.state is State.ESTOPPED
                else None
            ),
            "bus": {
                "frames_rx": bs.frames_rx,
                "frames_tx": bs.frames_tx,
                "decode_errors": bs.decode_errors,
                "dropped": bs.dropped,
                "commands_heard": bs.commands_heard,
                "conflicts": bs.conflicts,
                "last_conflict": bs.last_conflict,
                "bus_errors": bs.bus_errors,
                "ff_clamped": bs.ff_clamped,
                "last_error": bs.last_error,
                "errors_by_kind": dict(bs.errors_by_kind),
            },
            "config": self.cfg.summary(),
        }

    def _tension_status(self, commanded: bool) -> dict[str, Any] | None:
        """The statics part of `status()`: None without `[payload]`."""
        chk = self.tension
        if chk is None:
            return None
        planned = self.planned_tensions_n if commanded else None
        return {
            "mass_kg": chk.mass_kg,
            "min_n": chk.statics.t_min_n,
            "max_n": chk.statics.t_max_n,
            "margin_required_n": chk.margin_n,
            "planned_n": list(planned) if planned is not None else None,
            "planned_margin_n": self.planned_margin_n if planned is not None else None,
            "measured_n": list(self.measured_tensions_n) if self._measure else None,
            "telemetry": self.cfg.loop.torque_telemetry,
        }

    def _pretension_status(self, now_s: float) -> dict[str, Any]:
        """The pre-tension part of `status()`."""
        run = self._pretension
        active = run is not None
        return {
            "active": active,
            "position_m": list(self._pretension_at) if active else None,
            "tensions_n": list(run.tensions_n) if run is not None else None,
            "elapsed_s": now_s - run.start_s if run is not None else None,
            "fastest_cable_mps": (
                run.worst_mps if run is not None and math.isfinite(run.worst_mps) else None
            ),
            "result": self.pretension_result,
        }
