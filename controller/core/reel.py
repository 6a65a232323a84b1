"""Reel model: motor turns <-> cable length, pure math.

Units: motor position in motor turns (rev, as the ODrive reports it), cable length in metres.

Model. Let ``x = position_rev - offset_rev`` (motor turns from the reference point) and
``n = direction * x / gear_ratio`` (drum turns, positive = paying cable out). The cable paid out
from the drum over those turns is

    s(n) = metres_per_rev * n - spool_buildup_m_per_rev2 * n**2 / 2

because every turn paid out empties the spool a little, so the metres per drum turn fall by
``spool_buildup_m_per_rev2`` per turn (Hangprinter's spool build-up: the radius grows linearly
with the turns wound on; 0 = a plain drum). ``metres_per_rev`` is the metres per drum turn at the
reference point. A pulley block of mechanical advantage ``k`` turns ``s`` metres of spooled
cable into ``s / k`` metres of change in the anchor-to-effector length, so

    length_m = reference_length_m + s(n) / mechanical_advantage

``offset_rev`` is the motor position at which the cable length equals ``reference_length_m``;
homing sets it (`with_home`). With build-up, the spool's wound state at the reference point is
fixed by ``reference_length_m`` (the length at which ``metres_per_rev`` holds), and homing moves
only ``offset_rev``. The inverse solves the quadratic in closed form with the numerically stable
root; it is valid while the metres per turn stay positive (the spool is not over-emptied).

The same spool seen by its area: a radius falling linearly with the turns paid out is a radius
whose square falls linearly with the cable paid out, ``r**2 = r_ref**2 - f * s`` with
``f = spool_buildup_m_per_rev2 / (2 pi**2)`` (square ``2 pi r = metres_per_rev - b n`` and
substitute ``s(n)``). ``f`` is RepRapFirmware's Hangprinter build-up factor (M666 Q, there in
millimetres, times M666 O when several lines share one spool): the area each metre of wound
line adds to the spool's side face, divided by pi (`spool_buildup_from_factor`). Its spool model
is therefore this one, exactly.

Torque and tension (ideal reel: no friction, no inertia). The work the motor does on the cable
balances the work the cable's tension does on the effector: with the slope
``dL/drev = length_rate_mps(position_rev, 1.0)`` (metres of anchor-to-effector length per motor
turn, signed: positive when positive turns pay out), a motor torque ``tau`` (N m, positive in
the motor's positive direction) holds a tension

    tension_n = -tau * 2 pi / (dL/drev)

The torque that holds a cable winds it in: negative on a reel whose positive turns pay out
(``direction`` +1), positive on a mirrored one. Gear ratio, pulley block and spool build-up all
enter through the slope, so the tension one torque holds changes with the turns when the spool
builds up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, slots=True)
class ReelModel:
    """Motor turns <-> cable length for one reel (see the module docstring for the formula).

    Raises ValueError on construction if a parameter is out of range: non-positive or
    non-finite metres_per_rev, gear_ratio or mechanical_advantage, direction not +1/-1, negative
    or non-finite spool build-up, non-finite offset or reference length.
    """

    metres_per_rev: float
    gear_ratio: float = 1.0
    """Motor turns per drum turn."""
    direction: int = 1
    """+1: positive motor turns pay cable out (length grows); -1: they wind it in."""
    mechanical_advantage: float = 1.0
    """Metres of cable spooled per metre of anchor-to-effector length change (pulley blocks)."""
    spool_buildup_m_per_rev2: float = 0.0
    """Fall of the metres per drum turn for each drum turn paid out (0 = no build-up)."""
    offset_rev: float = 0.0
    """Motor position at which the cable length is `reference_length_m` (set by homing)."""
    reference_length_m: float = 0.0
    """Cable length at `offset_rev`; also where `metres_per_rev` is measured."""
    _k1: float = field(init=False, repr=False, compare=False, default=0.0)
    _k2: float = field(init=False, repr=False, compare=False, default=0.0)

    def __post_init__(self) -> None:
        def positive(name: str, value: float) -> None:
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"ReelModel.{name} must be finite and > 0, got {value!r}")

        positive("metres_per_rev", self.metres_per_rev)
        positive("gear_ratio", self.gear_ratio)
        positive("mechanical_advantage", self.mechanical_advantage)
        if self.direction not in (1, -1):
            raise ValueError(f"ReelModel.direction must be +1 or -1, got {self.direction!r}")
        b = self.spool_buildup_m_per_rev2
        if not (math.isfinite(b) and b >= 0.0):
            raise ValueError(
                f"ReelModel.spool_buildup_m_per_rev2 must be finite and >= 0, got {b!r}"
            )
        for name in ("offset_rev", "reference_length_m"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"ReelModel.{name} must be finite, got {value!r}")
        # length = ref + k1*x + k2*x**2 with x = position_rev - offset_rev
        k1 = self.metres_per_rev * self.direction / (self.gear_ratio * self.mechanical_advantage)
        k2 = -0.5 * b / (self.gear_ratio * self.gear_ratio * self.mechanical_advantage)
        object.__setattr__(self, "_k1", k1)
        object.__setattr__(self, "_k2", k2)

    @classmethod
    def from_drum_radius(
        cls,
        radius_m: float,
        *,
        gear_ratio: float = 1.0,
        direction: int = 1,
        mechanical_advantage: float = 1.0,
        cable_diameter_m: float = 0.0,
        turns_per_layer: float = 1.0,
        offset_rev: float = 0.0,
        reference_length_m: float = 0.0,
    ) -> ReelModel:
        """Build a model from the drum radius at the reference point (metres per turn = 2πr).

        With `cable_diameter_m` > 0 the spool build-up is on: the radius changes by one cable
        diameter every `turns_per_layer` drum turns. Raises ValueError on a non-positive or
        non-finite radius, a negative cable diameter or a non-positive turns_per_layer.
        """
        if not (math.isfinite(radius_m) and radius_m > 0.0):
            raise ValueError(f"drum radius_m must be finite and > 0, got {radius_m!r}")
        return cls(
            metres_per_rev=2.0 * math.pi * radius_m,
            gear_ratio=gear_ratio,
            direction=direction,
            mechanical_advantage=mechanical_advantage,
            spool_buildup_m_per_rev2=spool_buildup(cable_diameter_m, turns_per_layer),
            offset_rev=offset_rev,
            reference_length_m=reference_length_m,
        )

    def length_m(self, position_rev: float) -> float:
        """Cable length in metres at motor position `position_rev` (motor turns)."""
        x = position_rev - self.offset_rev
        return self.reference_length_m + (self._k1 + self._k2 * x) * x

    def position_rev(self, length_m: float) -> float:
        """Motor position (motor turns) at which the cable has length `length_m`.

        Raises ValueError if the length cannot be reached (with spool build-up: more cable than
        the spool can pay out before its metres per turn reach zero).
        """
        y = length_m - self.reference_length_m
        k1 = self._k1
        k2 = self._k2
        if k2 == 0.0:
            return self.offset_rev + y / k1
        disc = k1 * k1 + 4.0 * k2 * y
        if disc < 0.0:
            raise ValueError(f"cable length {length_m!r} m is beyond what the spool can pay out")
        # The root continuous with the linear solution y/k1, in the form without cancellation.
        root = math.sqrt(disc)
        return self.offset_rev + 2.0 * y / (k1 + root if k1 > 0.0 else k1 - root)

    def length_rate_mps(self, position_rev: float, velocity_rps: float) -> float:
        """Cable length rate (m/s) at `position_rev` when the motor turns at `velocity_rps`."""
        x = position_rev - self.offset_rev
        return (self._k1 + 2.0 * self._k2 * x) * velocity_rps

    def velocity_rps(self, position_rev: float, length_rate_mps: float) -> float:
        """Motor velocity (rev/s) giving cable length rate `length_rate_mps` at `position_rev`.

        Raises ValueError where the length no longer depends on the position (spool empty).
        """
        slope = self._k1 + 2.0 * (position_rev - self.offset_rev) * self._k2
        if slope == 0.0:
            raise ValueError("reel slope is zero at this position (spool fully paid out)")
        return length_rate_mps / slope

    def tension_n(self, position_rev: float, torque_nm: float) -> float:
        """Cable tension (N) that motor torque `torque_nm` holds at `position_rev`.

        Work balance (module docstring): ``-torque_nm * 2 pi / (dL/drev)``; a torque that pays
        the cable out gives a negative number (the cable would push). Raises ValueError where
        the length no longer depends on the position (spool empty).
        """
        slope = self._k1 + 2.0 * (position_rev - self.offset_rev) * self._k2
        if slope == 0.0:
            raise ValueError("reel slope is zero at this position (spool fully paid out)")
        return -torque_nm * _TWO_PI / slope

    def torque_nm(self, position_rev: float, tension_n: float) -> float:
        """Motor torque (N m, motor's positive direction) that holds `tension_n` at
        `position_rev`: ``-tension_n * (dL/drev) / 2 pi``, the inverse of `tension_n`.
        Raises nothing."""
        slope = self._k1 + 2.0 * (position_rev - self.offset_rev) * self._k2
        return -tension_n * slope / _TWO_PI

    def max_tension_n(
        self, max_torque_nm: float, min_length_m: float, max_length_m: float
    ) -> float:
        """The largest tension (N) `max_torque_nm` holds everywhere between the two cable lengths.

        The slope's magnitude is largest at one end of the range (it is linear in the turns),
        so that end bounds the tension. Raises ValueError on a non-positive or non-finite torque
        or a length the spool cannot reach.
        """
        if not (math.isfinite(max_torque_nm) and max_torque_nm > 0.0):
            raise ValueError(f"max_torque_nm must be finite and > 0, got {max_torque_nm!r}")
        steepest = max(
            abs(self.length_rate_mps(self.position_rev(length), 1.0))
            for length in (min_length_m, max_length_m)
        )
        return max_torque_nm * _TWO_PI / steepest

    def with_home(self, position_rev: float, length_m: float) -> ReelModel:
        """Return a model in which motor position `position_rev` has cable length `length_m`.

        Only `offset_rev` changes. Raises ValueError if a value is not finite or the length is
        unreachable for this spool.
        """
        if not (math.isfinite(position_rev) and math.isfinite(length_m)):
            raise ValueError(f"with_home needs finite values, got {position_rev!r}, {length_m!r}")
        x_home = self.position_rev(length_m) - self.offset_rev
        return replace(self, offset_rev=position_rev - x_home)


def spool_buildup(cable_diameter_m: float, turns_per_layer: float = 1.0) -> float:
    """Spool build-up in metres per turn per turn for a cable of `cable_diameter_m`.

    Each layer of `turns_per_layer` turns adds one cable diameter to the radius, so the metres
    per turn change by 2π·d / turns_per_layer per turn. Raises ValueError on a negative or
    non-finite diameter or a non-positive turns_per_layer.
    """
    if not (math.isfinite(cable_diameter_m) and cable_diameter_m >= 0.0):
        raise ValueError(f"cable_diameter_m must be finite and >= 0, got {cable_diameter_m!r}")
    if not (math.isfinite(turns_per_layer) and turns_per_layer > 0.0):
        raise ValueError(f"turns_per_layer must be finite and > 0, got {turns_per_layer!r}")
    return 2.0 * math.pi * cable_diameter_m / turns_per_layer


def spool_buildup_from_factor(factor_m: float) -> float:
    """Spool build-up in metres per turn per turn for an area build-up factor `factor_m`.

    `factor_m` is how much the spool radius squared (m²) falls per metre of cable paid out
    from the spool, RepRapFirmware's Hangprinter M666 Q in metres (times M666 O, the lines per
    spool): ``2 pi**2 * factor_m`` (module docstring). Raises ValueError on a negative or
    non-finite factor.
    """
    if not (math.isfinite(factor_m) and factor_m >= 0.0):
        raise ValueError(f"spool build-up factor_m must be finite and >= 0, got {factor_m!r}")
    return 2.0 * math.pi * math.pi * factor_m
