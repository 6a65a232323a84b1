"""The torque mode of `drivers.odrive.driver.ODriveReels` (`drivers.base.TorqueDriver`: the
pre-tension before homing) and the velocity limits it lowers and restores (see the driver
module's docstring).

`ODriveTorqueMode` is a mixin: `ODriveReels` owns the state it works on (declared below) and its
send path.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from drivers.base import AxisReading
from drivers.odrive import cansimple as cs

F32_MAX = 3.4028234663852886e38
"""The largest finite float32."""


def as_float(value: object) -> float | None:
    """`value` as a float, None if it is not a number (NaN stays NaN: the caller's range
    check refuses it)."""
    if isinstance(value, bool):
        return None
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None


class ODriveTorqueMode:
    """Torque mode of `ODriveReels` (a mixin: the driver owns the state below)."""

    node_ids: tuple[int, ...]
    velocity_limit_rps: float | None
    current_limit_a: float | None
    _limits_lowered: bool
    _readings: tuple[AxisReading, ...]

    if TYPE_CHECKING:

        def _send_all(self, frames: Sequence[cs.Frame], what: str) -> None: ...

        def _commanded(self, readings: Sequence[AxisReading]) -> None: ...

    def _check_values(self, values: Sequence[float], what: str, *, positive: bool) -> None:
        """ValueError naming the node unless `values` has one finite float32 per axis (> 0
        with `positive`)."""
        ids = self.node_ids
        if len(values) != len(ids):
            raise ValueError(f"{what} needs {len(ids)} values, got {len(values)}")
        for node, v in zip(ids, values, strict=True):
            f = as_float(v)
            if f is None or not -F32_MAX <= f <= F32_MAX:
                raise ValueError(f"{what} for node {node} is not a finite float32: {v!r}")
            if positive and not f > 0.0:
                raise ValueError(f"{what} for node {node} must be > 0, got {v!r}")

    def _restore_limit_frames(self) -> list[cs.Frame]:
        v = self.velocity_limit_rps
        c = self.current_limit_a
        if not self._limits_lowered or v is None or c is None:
            return []
        return [cs.encode_set_limits(n, v, c) for n in self.node_ids]

    def enter_torque_mode(
        self, torques_nm: Sequence[float], velocity_limits_rps: Sequence[float] | None = None
    ) -> bool:
        """Select TORQUE_CONTROL + PASSTHROUGH with `torques_nm` on every axis, in closed loop.

        Per axis: Clear_Errors if it is not ready (not in closed loop without error);
        Set_Limits(limit, current_limit_a) when `velocity_limits_rps` is given and both
        configured limits are known (Set_Limits sets both at once, and only known values can
        be restored); Set_Input_Torque(torque) before the mode changes (an axis holding a
        suspended load never pulls with zero); Set_Controller_Mode; Set_Axis_State
        CLOSED_LOOP_CONTROL if it is not ready. Returns True if the velocity limits were
        applied. Raises ValueError (nothing sent) on a torque that is not a finite float32, a
        limit that is not finite and > 0, or a wrong count, BusError if a send fails (after
        trying every frame).
        """
        self._check_values(torques_nm, "torque", positive=False)
        if velocity_limits_rps is not None:
            self._check_values(velocity_limits_rps, "velocity limit", positive=True)
        current = self.current_limit_a
        limits = velocity_limits_rps if self.velocity_limit_rps is not None else None
        frames: list[cs.Frame] = []
        changed = [r for r in self._readings if not r.ready]
        for i, r in enumerate(self._readings):
            n = r.node_id
            if not r.ready:
                frames.append(cs.encode_clear_errors(n))
            if limits is not None and current is not None:
                frames.append(cs.encode_set_limits(n, limits[i], current))
            frames.append(cs.encode_set_input_torque(n, torques_nm[i]))
            frames.append(
                cs.encode_set_controller_mode(
                    n, cs.ControlMode.TORQUE_CONTROL, cs.InputMode.PASSTHROUGH
                )
            )
            if not r.ready:
                frames.append(cs.encode_set_axis_state(n, cs.AxisState.CLOSED_LOOP_CONTROL))
        applied = limits is not None and current is not None
        if applied:
            self._limits_lowered = True  # before sending: a partial failure may have lowered some
        try:
            self._send_all(frames, "torque mode")
        finally:
            self._commanded(changed)
        return applied

    def command_torque(self, torques_nm: Sequence[float]) -> None:
        """Send Set_Input_Torque to every axis (N m, motor's positive direction, `node_ids`
        order). Raises ValueError (nothing sent) on a value that is not a finite float32 or a
        wrong count, BusError if a send fails (after trying every axis)."""
        self._check_values(torques_nm, "torque", positive=False)
        ids = self.node_ids
        self._send_all(
            [cs.encode_set_input_torque(ids[i], torques_nm[i]) for i in range(len(ids))],
            "Set_Input_Torque",
        )

    def leave_torque_mode(self, positions_rev: Sequence[float]) -> None:
        """Hold `positions_rev` in POSITION_CONTROL + PASSTHROUGH; restore lowered limits.

        Per axis: Set_Input_Pos(p), Set_Controller_Mode, Set_Input_Pos(p) again (the firmware
        may reset input_pos on the mode change; the second one makes sure it holds `p`); then,
        if `enter_torque_mode` lowered the velocity limits, Set_Limits with the configured
        ones on every axis. Raises ValueError (nothing sent) on a position that is not a
        finite float32 or a wrong count, BusError if a send fails (after trying every frame).
        """
        self._check_values(positions_rev, "position", positive=False)
        frames: list[cs.Frame] = []
        for n, p in zip(self.node_ids, positions_rev, strict=True):
            hold = cs.encode_set_input_pos(n, p)
            frames.append(hold)
            frames.append(
                cs.encode_set_controller_mode(
                    n, cs.ControlMode.POSITION_CONTROL, cs.InputMode.PASSTHROUGH
                )
            )
            frames.append(hold)
        frames.extend(self._restore_limit_frames())
        self._send_all(frames, "position mode")
        self._limits_lowered = False
