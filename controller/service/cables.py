"""The loop's cable model: what the reels must pay out for a set-point, and the pose of what
they have paid out, with rigid cables, with cable stretch (`[[reels]] cable_ea_n`) or with
heavy cables that sag (`[[reels]] cable_mass_kg_per_m`).

One object built from the configuration (`CableModel.from_config`) that the control step asks
at its three kinematic call sites: homing (the reel lengths at a known pose), the set-point's
commanded lengths (IPK) and the pose (FPK).  Rigid cables (no reel has `cable_ea_n` or
`cable_mass_kg_per_m`) give exactly the rigid kinematics of `controller.core.kinematics`;
elastic ones those of `controller.core.stretch`: paid-out lengths under the planned tensions,
and the pose whose tensions (planned by statics at the pose, or measured by torque telemetry
with `loop.stretch_tensions = "measured"`) stretch the cables to the paid-out lengths; heavy
ones those of `controller.core.sag_plan`: the paid-out lengths of the catenaries the loop's
tension plan solved at the set-point (the tension rule is then the one with the cables'
weight, `SagTensionCheck`, whose plans this model reads), and the pose from the paid-out
lengths with sag and stretch linearised about that plan.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from controller.core import kinematics
from controller.core.sag_plan import SagKinematicsError, SagPlanner, SagTensionCheck
from controller.core.statics import StaticsError, TensionCheck
from controller.core.stretch import CableStretch, StretchError

__all__ = ["CableModel"]


class CableModel:
    """Rigid, elastic or heavy cables for one robot (see the module docstring).

    `stretch` is the core stretch model (None: rigid or heavy cables); `sag` the planner of
    heavy cables (None: none has mass); `measured` says whether the pose uses measured
    tensions when every cable has a fresh one.  Not thread-safe: the loop owns it.
    """

    __slots__ = ("_last_lengths", "geometry", "measured", "sag", "stretch")

    def __init__(
        self,
        geometry: kinematics.Geometry,
        stretch: CableStretch | None,
        measured: bool = False,
        sag: SagPlanner | None = None,
    ) -> None:
        self.geometry = geometry
        self.stretch = stretch
        self.sag = sag
        self.measured = measured and stretch is not None
        self._last_lengths: Sequence[float] = ()

    @classmethod
    def from_config(cls, cfg: Any, check: TensionCheck | None) -> CableModel:
        """The model of `cfg` (a `RobotConfig`) with the payload's tension rule `check`.

        Raises ValueError when a reel has `cable_ea_n` but there is no tension rule (the
        configuration refuses that already) and ``KinematicsError`` for an unusable EA.
        """
        if any(r.cable_mass_kg_per_m for r in cfg.reels):
            if not isinstance(check, SagTensionCheck):
                raise ValueError(
                    "heavy cables (reels' cable_mass_kg_per_m) need the tension rule with "
                    "their weight ([payload] mass_kg)"
                )
            return cls(cfg.geometry, None, sag=check.planner)
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

        Raises ``KinematicsError`` for a non-finite pose (``StretchError`` or
        ``SagKinematicsError`` where statics has no tensions).
        """
        if self.sag is not None:
            try:
                return self.sag.exact(position_m).paid_out_m
            except StaticsError as exc:
                raise SagKinematicsError(f"no cable tensions with sag there: {exc}") from None
        if self.stretch is None:
            return kinematics.ipk_point(self.geometry, position_m)
        return self.stretch.ipk(position_m)[0]

    def commanded_lengths_m(
        self, lengths_m: Sequence[float], tensions_n: Sequence[float] | None
    ) -> Sequence[float]:
        """The lengths to command for a set-point whose geometric lengths are `lengths_m` and
        planned tensions `tensions_n` (per tick; the lengths themselves for rigid cables).

        Heavy cables: the paid-out lengths of the tension rule's plan for the set-point
        (`SagTensionCheck.solve`, which the loop calls first), matched by its chords; when the
        set-point is the last call's (held), that plan made exact (`SagPlanner.refine`).

        Raises ``KinematicsError`` for a non-finite result, ``StretchError`` when elastic
        cables have no planned tensions, ``SagKinematicsError`` when heavy ones have no plan.
        """
        if self.sag is not None:
            held = lengths_m == self._last_lengths
            self._last_lengths = lengths_m
            try:
                # a set-point held for a second tick gets an exact plan (once)
                plan = self.sag.refine(lengths_m) if held else self.sag.planned(lengths_m)
            except StaticsError as exc:
                raise SagKinematicsError(f"cable sag: {exc}") from None
            if plan is None:
                raise SagKinematicsError("cable sag: no tension plan for the set-point")
            return plan.paid_out_m
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

        Heavy cables: ``SagPlanner.fpk`` about the plan made at the set-point (`planned`'s
        point), warm-started from `guess_m` (a failed warm start is retried cold).

        Raises ``KinematicsError`` (``StretchError``, ``SagKinematicsError`` included) when no
        pose explains them.
        """
        if self.sag is not None:
            guess = guess_m if guess_m is not None and all(map(math.isfinite, guess_m)) else None
            at = None if planned is None else planned[0]
            if guess is not None:
                try:
                    return self.sag.fpk(lengths_m, guess, at)
                except SagKinematicsError:
                    pass
            return self.sag.fpk(lengths_m, None, at)
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
