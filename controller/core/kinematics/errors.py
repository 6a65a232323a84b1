"""The errors of the kinematics package: every refusal is a ``KinematicsError``.

Cable *names* in messages are 1-based (``cable 1`` is row 0 of the anchors), as in the paper
(B1..B4); the bare three-spheres functions name the sphere (``r1``/``r2``/``r3``).
"""

from __future__ import annotations

__all__ = ["KinematicsError", "SingularGeometryError", "UnreachableError"]


class KinematicsError(ValueError):
    """Base class of every kinematics error."""


class SingularGeometryError(KinematicsError):
    """The anchors cannot be used: coincident, or collinear in plan view (eq. 14)."""


class UnreachableError(KinematicsError):
    """The cable lengths cannot meet in one point (negative discriminant, eq. 17).

    ``cable`` is 1-based: the cable index in the geometry for ``fpk``, the sphere number
    (1, 2, 3) for the bare three-spheres functions.  ``shortfall_m`` is the smallest change
    of that cable alone (others held) that lets the three spheres touch: > 0 means it is too
    short by that much, < 0 too long.
    """

    def __init__(self, cable: int, shortfall_m: float, what: str = "cable") -> None:
        self.cable = cable
        self.shortfall_m = shortfall_m
        name = f"r{cable}" if what == "sphere" else f"cable {cable}"
        how = "short" if shortfall_m >= 0.0 else "long"
        super().__init__(
            f"lengths cannot meet: {name} is too {how} by {abs(shortfall_m):.6g} m "
            "(negative discriminant, eq. 17)"
        )
