"""The loop's cable model: what the reels must pay out for a set-point, and the pose of what
they have paid out, with rigid cables or with cable stretch (`[[reels]] cable_ea_n`).

One object built from the configuration (`CableModel.from_config`) that the control step asks
at its three kinematic call sites: homing (the reel lengths at a known pose), the set-point's
commanded lengths (IPK) and the pose (FPK).  Rigid cables (no reel has `cable_ea_n`) give
exactly the rigid kinematics of `controller.core.kinematics`; elastic ones those of
`controller.core.stretch`: paid-out lengths under the planned tensions, and the pose whose
tensions (planned by statics at the pose, or measured by torque telemetry with
`loop.stretch_tensions = "measured"`) stretch the cables to the paid-out lengths.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from controller.core import kinematics
from controller.core.statics import TensionCheck
from controller.core.stretch import CableStretch, StretchError

__all__ = ["CableModel"]


class CableModel:
    """Rigid or elastic cables for one robot (see the module docstring).

    `stretch` is the core model (None: rigid cables); `measured` says whether the pose uses
    measured tensions when every cable has a fresh one.  Not thread-safe: the loop owns it.
    """

    __slots__ = ("geometry", "measured", "stretch")

    def __init__(
        self, geometry: kinematics.Geometry, stretch: CableStretch | None, measured: bool = False
    ) -> None:
        self.geometry = geometry
        self.stretch = stretch
        self.measured = measured and stretch is not None

    @classmethod
    def from_config(cls, cfg: Any, check: TensionCheck | None) -> CableModel:
        """The model of `cfg` (a `RobotConfig`) with the payload's tension rule `check`.

        Raises ValueError when a reel has `cable_ea_n` but there is no tension rule (the
        configuration refuses that already) and ``KinematicsError`` for an unusable EA.
        """
        ea = [r.cable_ea_n for r in cfg.reels]
        if all(e is None for e in ea):
            return cls(cfg.geometry, None)
        if check is None:
            raise ValueError("cable stretch (reels' cable_ea_n) needs [payload] mass_kg")
        return cls(
            cfg.geometry,
            CableStretch(cfg.geometry, ea, check),
            cfg.loop.stretch_tensions == "measured",
        )

    def home_lengths_m(self, position_m: Sequence[float]) -> tuple[float, ...]:
        """What the reels have paid out with the payload at rest at `position_m` (homing).

        Raises ``KinematicsError`` for a non-finite pose (``StretchError`` where statics has
        no tensions).
        """
        if self.stretch is None:
            return kinematics.ipk_point(self.geometry, position_m)
        return self.stretch.ipk(position_m)[0]

    def commanded_lengths_m(
        self, lengths_m: Sequence[float], tensions_n: Sequence[float] | None
    ) -> Sequence[float]:
        """The lengths to command for a set-point whose geometric lengths are `lengths_m` and
        planned tensions `tensions_n` (per tick; the lengths themselves for rigid cables).

        Raises ``KinematicsError`` for a non-finite result, ``StretchError`` when elastic
        cables have no planned tensions.
        """
        s = self.stretch
        if s is None:
            return lengths_m
        if tensions_n is None:
            raise StretchError("cable stretch: no planned tensions for the set-point")
        return s.paid_out_m(lengths_m, tensions_n)

    def wants_derivative(self, setpoint_m: Sequence[float]) -> bool:
        """True when the statics solve planning `setpoint_m`'s tensions should also give their
        derivative, for the FPK (``CableStretch.wants_derivative``; never with rigid cables).
        Raises nothing."""
        s = self.stretch
        return s is not None and s.wants_derivative(setpoint_m)

    def take_derivative(
        self,
        setpoint_m: Sequence[float],
        derivative: Sequence[tuple[float, float, float]] | None,
    ) -> None:
        """Hand the FPK the derivative of the tensions planned at `setpoint_m` (per tick, when
        `wants_derivative` asked for it).  Raises nothing."""
        s = self.stretch
        if s is not None:
            s.take_derivative(setpoint_m, derivative)

    def pose(
        self,
        lengths_m: Sequence[float],
        guess_m: Sequence[float] | None,
        measured_n: Sequence[float | None] | None = None,
        planned: tuple[Sequence[float], Sequence[float]] | None = None,
    ) -> tuple[tuple[float, float, float], float]:
        """(pose, RMS residual in metres) of the reel lengths `lengths_m`: the rigid FPK, or
        with stretch the pose its tensions explain, warm-started from `guess_m` (the last pose;
        a failed warm start is retried cold).  With `measured` and a fresh measured tension on
        every cable (`measured_n`), those stretch the cables instead of the planned ones.
        `planned` (the set-point and the tensions planned there) spares the FPK a statics solve
        when the pose is close to it (``CableStretch.fpk``).

        Raises ``KinematicsError`` (``StretchError`` included) when no pose explains them.
        """
        s = self.stretch
        if s is None:
            res = kinematics.fpk(self.geometry, lengths_m, guess_m)
            p = res.position_m
            return (float(p[0]), float(p[1]), float(p[2])), float(res.residual_m)
        if self.measured and measured_n is not None and None not in measured_n:
            m = s.fpk_measured(lengths_m, [float(t) for t in measured_n if t is not None], guess_m)
            return m.position_m, m.residual_m
        if guess_m is not None and all(map(math.isfinite, guess_m)):
            try:
                r = s.fpk(lengths_m, guess_m, planned)
                return r.position_m, r.residual_m
            except StretchError:
                pass
        r = s.fpk(lengths_m)
        return r.position_m, r.residual_m
