"""Operator commands: frozen dataclasses and their JSON parsing.

This module is the contract between whoever receives commands (the Zenoh interface, tests, the
demo) and the control loop that executes them. Parsing checks the schema and that every number
is finite; it knows nothing of the robot's state or workspace: the loop checks those and refuses
with `CommandRefused`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from controller.motion import check_speed

Vec3 = tuple[float, float, float]


class CommandError(ValueError):
    """A malformed command payload: bad JSON, missing or unknown fields, NaN, wrong type."""


class CommandRefused(RuntimeError):
    """A well-formed command that the robot refuses in its current state or workspace."""


@dataclass(frozen=True, slots=True)
class Move:
    """Straight-line move to `position_m` with a trapezoidal profile."""

    position_m: Vec3
    speed_mps: float | None = None


@dataclass(frozen=True, slots=True)
class Path:
    """Multi-point path through `points_m`, each leg a straight line."""

    points_m: tuple[Vec3, ...]
    speed_mps: float | None = None


@dataclass(frozen=True, slots=True)
class Stop:
    """Decelerate to a hold."""


@dataclass(frozen=True, slots=True)
class Estop:
    """Emergency stop: disarm the motors at once."""


@dataclass(frozen=True, slots=True)
class Arm:
    """Arm the motors and hold the current pose."""


@dataclass(frozen=True, slots=True)
class Disarm:
    """Disarm the motors (they go idle: only do this with the load supported)."""


@dataclass(frozen=True, slots=True)
class Reset:
    """Clear a FAULT or ESTOPPED state back to DISARMED."""


@dataclass(frozen=True, slots=True)
class Home:
    """Declare that the effector is now at `position_m`; sets and saves the reel offsets."""

    position_m: Vec3


@dataclass(frozen=True, slots=True)
class Setpoint:
    """A streamed target position (joystick, external planner)."""

    position_m: Vec3


Command = Move | Path | Stop | Estop | Arm | Disarm | Reset | Home | Setpoint

VERBS: tuple[str, ...] = ("move", "path", "stop", "estop", "arm", "disarm", "reset", "home")

_MAX_PATH_POINTS = 10_000


def _finite(value: Any, field: str) -> float:
    """Return `value` as a finite float or raise CommandError naming `field`."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise CommandError(f"{field}: expected a number, got {type(value).__name__}")
    try:
        out = float(value)
    except OverflowError:  # an integer beyond the float range
        raise CommandError(f"{field}: must be a finite number, got an integer too large") from None
    if not math.isfinite(out):
        raise CommandError(f"{field}: must be a finite number, got {value!r}")
    return out


def _vec3(value: Any, field: str) -> Vec3:
    """Return `value` as a 3-tuple of finite floats or raise CommandError naming `field`."""
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise CommandError(f"{field}: expected [x, y, z], got {value!r}")
    return (
        _finite(value[0], f"{field}[0]"),
        _finite(value[1], f"{field}[1]"),
        _finite(value[2], f"{field}[2]"),
    )


def _speed(obj: dict[str, Any]) -> float | None:
    """Return the optional `speed_mps` field or raise CommandError.

    The speed rule is `controller.motion.check_speed` (at least `MIN_SPEED_MPS`); a speed above
    the robot's maximum is not an error here: the loop runs at the maximum and says so.
    """
    if obj.get("speed_mps") is None:
        return None
    speed = _finite(obj["speed_mps"], "speed_mps")
    reason = check_speed(speed)
    if reason is not None:
        raise CommandError(f"speed_mps: {reason}")
    return speed


def _object(payload: bytes | str | None, allowed: set[str], required: set[str]) -> dict[str, Any]:
    """Decode a JSON object, refusing unknown and missing keys."""
    if payload is None or (isinstance(payload, bytes | str) and len(payload.strip()) == 0):
        obj: Any = {}
    else:
        try:
            obj = json.loads(payload, parse_constant=_reject_constant)
        except (ValueError, UnicodeDecodeError) as exc:
            raise CommandError(f"malformed JSON: {exc}") from None
    if not isinstance(obj, dict):
        raise CommandError(f"expected a JSON object, got {type(obj).__name__}")
    unknown = set(obj) - allowed
    if unknown:
        raise CommandError(f"unknown field(s): {', '.join(sorted(unknown))}")
    missing = required - set(obj)
    if missing:
        raise CommandError(f"missing field(s): {', '.join(sorted(missing))}")
    return obj


def _reject_constant(name: str) -> Any:
    """json.loads hook: NaN, Infinity and -Infinity are not valid numbers here."""
    raise CommandError(f"non-finite number {name} is not allowed")


def parse_command(verb: str, payload: bytes | str | None) -> Command:
    """Parse the JSON `payload` of command `verb` into a Command.

    Raises CommandError (with a reason fit to send back to the client) for an unknown verb,
    malformed JSON, unknown or missing fields, non-numbers and non-finite numbers.
    """
    if verb == "move":
        obj = _object(payload, {"position_m", "speed_mps"}, {"position_m"})
        return Move(_vec3(obj["position_m"], "position_m"), _speed(obj))
    if verb == "path":
        obj = _object(payload, {"points_m", "speed_mps"}, {"points_m"})
        pts = obj["points_m"]
        if not isinstance(pts, list) or not pts:
            raise CommandError("points_m: expected a non-empty list of [x, y, z]")
        if len(pts) > _MAX_PATH_POINTS:
            raise CommandError(f"points_m: at most {_MAX_PATH_POINTS} points")
        points = tuple(_vec3(p, f"points_m[{i}]") for i, p in enumerate(pts))
        return Path(points, _speed(obj))
    if verb == "home":
        obj = _object(payload, {"position_m"}, {"position_m"})
        return Home(_vec3(obj["position_m"], "position_m"))
    if verb == "setpoint":
        obj = _object(payload, {"position_m"}, {"position_m"})
        return Setpoint(_vec3(obj["position_m"], "position_m"))
    simple: dict[str, Command] = {
        "stop": Stop(),
        "estop": Estop(),
        "arm": Arm(),
        "disarm": Disarm(),
        "reset": Reset(),
    }
    if verb in simple:
        _object(payload, set(), set())
        return simple[verb]
    raise CommandError(f"unknown command {verb!r}; known: {', '.join(VERBS)}")
