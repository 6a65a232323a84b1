"""The physical plant's input checks: its parameters, states and inputs are numbers, finite
where they must be, positive or non-negative where they must be, and `PlantError` names the
one that is not (``controller.core.plant``).

Pure module (``math``), no I/O, no threads.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["PlantError", "finite", "non_negative", "number", "positive", "vec3"]


class PlantError(ValueError):
    """A plant parameter, state or input is out of range (not finite, non-positive, wrong size)."""


def number(name: str, value: float) -> float:
    """`value` as a float; raises PlantError naming `name` when it is not a number."""
    try:
        return float(value)
    except (TypeError, ValueError):
        raise PlantError(f"{name} must be a number, got {value!r}") from None


def finite(name: str, value: float) -> float:
    """`value` as a finite float; raises PlantError naming `name` otherwise."""
    v = number(name, value)
    if not math.isfinite(v):
        raise PlantError(f"{name} must be finite, got {value!r}")
    return v


def positive(name: str, value: float) -> float:
    """`value` as a finite float > 0; raises PlantError naming `name` otherwise."""
    v = number(name, value)
    if not (math.isfinite(v) and v > 0.0):
        raise PlantError(f"{name} must be finite and > 0, got {value!r}")
    return v


def non_negative(name: str, value: float) -> float:
    """`value` as a finite float >= 0; raises PlantError naming `name` otherwise."""
    v = number(name, value)
    if not (math.isfinite(v) and v >= 0.0):
        raise PlantError(f"{name} must be finite and >= 0, got {value!r}")
    return v


def vec3(name: str, value: Sequence[float]) -> tuple[float, float, float]:
    """`value` as three finite coordinates; raises PlantError naming `name` otherwise."""
    try:
        x, y, z = value
    except (TypeError, ValueError):
        raise PlantError(f"{name} must be 3 coordinates, got {value!r}") from None
    return (finite(name, x), finite(name, y), finite(name, z))
