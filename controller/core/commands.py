"""Operator commands: frozen dataclasses and their JSON parsing.

This module is the contract between whoever receives commands (the Zenoh interface, tests, the
demo) and the control loop that executes them. Parsing checks the schema and that every number
is finite; it knows nothing of the robot's state or workspace: the loop checks those and refuses
with `CommandRefused`.

Bounded cost: whoever sends a command must not be able to hold the interpreter. Python's C JSON
decoder holds the GIL for the whole document (about 35 us per KiB on a slow machine), during
which no other thread runs, the control loop and e-stop included. So before any decoding a
payload is refused when it is larger than `MAX_PAYLOAD_BYTES[verb]` (`check_payload_size`),
or when its brackets nest deeper than `MAX_JSON_DEPTH` (a byte scan at C speed; the decoder's
own recursion limit is the backstop for brackets hidden in strings). Payloads up to
`C_DECODE_MAX_BYTES` go to the C decoder (well under a millisecond); larger ones (only a path
may be larger) to the json module's pure-Python scanner, which is 6-30 times slower but is
ordinary bytecode: the interpreter hands the GIL to a waiting thread (the loop, an e-stop)
every switch interval instead of after the whole document. A path has at most
`MAX_PATH_POINTS` points. Error messages quote at most `QUOTE_CHARS` characters of the input.

Streamed samples take the same checks: a `setpoint` (`{"position_m": [x, y, z]}`) and a
`velocity` sample (`{"velocity_mps": [vx, vy, vz]}`, 1 KiB at most) parse with
`parse_command("setpoint" | "velocity", payload)`; the planner clamps a velocity's norm to the
robot's maximum speed, so any finite vector is a valid sample here.
"""

from __future__ import annotations

import json
import json.scanner
import math
import reprlib
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Final

from controller.core.motion import check_speed
from controller.core.motion.shaper import SHAPER_TYPES, check_shaper
from controller.core.suggest import closest

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
    """Multi-point path through `points_m`, flown through its points with rounded corners
    (`controller.core.motion`). `append`: add the points to the path in progress (a job longer
    than `MAX_PATH_POINTS` is sent as a path and then appended chunks) instead of replacing it."""

    points_m: tuple[Vec3, ...]
    speed_mps: float | None = None
    append: bool = False


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
class Pretension:
    """Home with pre-tension: every reel pulls in torque control with the tension statics
    gives its cable at `position_m` until the reels are still, then the effector is declared
    at `position_m` (`controller.core.pretension`)."""

    position_m: Vec3


@dataclass(frozen=True, slots=True)
class Setpoint:
    """A streamed target position (joystick, external planner)."""

    position_m: Vec3


@dataclass(frozen=True, slots=True)
class Velocity:
    """A velocity-input sample (joystick, RC stick): fly at `velocity_mps` until the next one;
    zero brakes to a hold."""

    velocity_mps: Vec3


@dataclass(frozen=True, slots=True)
class Shaper:
    """Input shaping from now on (at the next rest when moving): the train `type` ("off" for
    none; `controller.core.motion.shaper.SHAPER_TYPES`), the mode's `frequency_hz` (None: the
    model's modes at the set-point) and the modes' `damping_ratio` (None: keep the current)."""

    type: str
    frequency_hz: float | None = None
    damping_ratio: float | None = None


Command = (
    Move
    | Path
    | Stop
    | Estop
    | Arm
    | Disarm
    | Reset
    | Home
    | Pretension
    | Setpoint
    | Velocity
    | Shaper
)

VERBS: tuple[str, ...] = (
    "move",
    "path",
    "stop",
    "estop",
    "arm",
    "disarm",
    "reset",
    "home",
    "pretension",
    "shaper",
)

MAX_PATH_POINTS: Final = 1_000
"""The most points a `path` command may have (longer trajectories: stream `setpoint`s)."""

MAX_PAYLOAD_BYTES: Final[Mapping[str, int]] = MappingProxyType(
    {
        "move": 4096,
        "home": 4096,
        "pretension": 4096,
        "setpoint": 4096,
        "velocity": 1024,
        # MAX_PATH_POINTS points as json.dumps(indent=2) writes them at full precision fit.
        "path": 128 * 1024,
        "stop": 1024,
        "estop": 1024,
        "arm": 1024,
        "disarm": 1024,
        "reset": 1024,
        "shaper": 1024,
    }
)
"""The largest payload, in bytes, of each verb (and of a `setpoint` or `velocity` sample)."""

_WIDEST_FLOAT: Final = -2.2250738585072014e-308
"""A finite float whose JSON text is as long as any (24 characters)."""


def _max_path_points_sent() -> int:
    envelope = len(json.dumps({"points_m": [], "speed_mps": _WIDEST_FLOAT}))
    per_point = len(json.dumps([_WIDEST_FLOAT] * 3)) + len(", ")
    by_bytes = (MAX_PAYLOAD_BYTES["path"] - envelope) // per_point
    return min(MAX_PATH_POINTS, by_bytes)


MAX_PATH_POINTS_SENT: Final = _max_path_points_sent()
PATH_STREAM_HINT: Final = (
    f'{MAX_PATH_POINTS:,} points a command; send more as appends ("append": true)'
)
"""How a path longer than one command carries is sent (in the refusals of a longer one; a
longer path goes as a path of its first points, then chunks that append to it, as `cablebot
path FILE` streams it)."""
"""The most points one `path` command surely carries: MAX_PATH_POINTS, or fewer when that many
of the widest points (every coordinate as long as a float's JSON text gets, with a speed, as
`json.dumps` writes them) would not fit in `MAX_PAYLOAD_BYTES["path"]`. A longer path is sent
as several parts of at most this many points."""


MAX_JSON_DEPTH: Final = 8
"""The deepest nesting of brackets (`[`, `{`) accepted; a valid command needs 3."""

QUOTE_CHARS: Final = 80
"""The most characters of a client's input that an error message quotes."""

C_DECODE_MAX_BYTES: Final = 16 * 1024
"""Larger payloads are decoded by the interruptible pure-Python scanner (see above)."""

_BRACKETS = bytes.maketrans(b"{}", b"[]")
_NOT_BRACKETS = bytes(b for b in range(256) if b not in b"[]{}")
_repr = reprlib.Repr()
_repr.maxlevel = 2
_repr.maxlist = _repr.maxtuple = _repr.maxdict = _repr.maxset = 4
_repr.maxstring = _repr.maxother = _repr.maxlong = QUOTE_CHARS


def clip(text: str, limit: int = QUOTE_CHARS) -> str:
    """`text` with non-printable characters escaped, cut to at most `limit` characters
    ("..." marks a cut). Never raises."""
    head = text[: limit + 1]
    if not head.isprintable():
        head = head.encode("unicode_escape").decode("ascii")
    return head if len(head) <= limit else head[: max(0, limit - 3)] + "..."


def quote(value: object, limit: int = QUOTE_CHARS) -> str:
    """A repr of `value` of at most `limit` characters, at a bounded cost for any size of
    `value` (long lists and strings are abbreviated before they are formatted)."""
    return clip(_repr.repr(value), limit)


def check_payload_size(verb: str, size: int) -> None:
    """Refuse a payload of `size` bytes for `verb` if larger than `MAX_PAYLOAD_BYTES`.

    Meant to run before the payload is even copied. Raises CommandError (the size and the
    limit in the message; an unknown verb is refused as such).
    """
    limit = MAX_PAYLOAD_BYTES.get(verb)
    if limit is None:
        raise CommandError(f"unknown command {clip(verb)!r}; known: {', '.join(VERBS)}")
    if size > limit:
        more = f"; {PATH_STREAM_HINT}" if verb == "path" else ""
        raise CommandError(f"payload too large: {size} bytes, {verb} takes at most {limit}{more}")


def _check_depth(data: bytes) -> None:
    """Refuse brackets nested deeper than MAX_JSON_DEPTH, before decoding, at C speed.

    Brackets are counted wherever they are, strings included (no valid command has one in a
    string). Each pass deletes the innermost `[]` pairs of the bracket skeleton, so after
    MAX_JSON_DEPTH passes a remaining pair means deeper nesting; so do more unclosed openings
    than that (the decoder would recurse into them before failing). Raises CommandError.
    """
    if data.count(b"[") + data.count(b"{") <= MAX_JSON_DEPTH:
        return
    skeleton = data.translate(_BRACKETS, _NOT_BRACKETS)
    for _ in range(MAX_JSON_DEPTH):
        shorter = skeleton.replace(b"[]", b"")
        if len(shorter) == len(skeleton):
            break
        skeleton = shorter
    if b"[]" in skeleton or skeleton.count(b"[") > MAX_JSON_DEPTH:
        raise CommandError(_too_deep())


def _too_deep() -> str:
    return f"nested too deeply: at most {MAX_JSON_DEPTH} levels of [ and {{"


class _InterruptibleDecoder(json.JSONDecoder):
    """json.JSONDecoder on the pure-Python scanner (strings are still scanned in C)."""

    def __init__(self) -> None:
        super().__init__(parse_constant=_reject_constant)
        self.scan_once = json.scanner.py_make_scanner(self)  # type: ignore[attr-defined]


def _decode(data: bytes) -> Any:
    """`data` decoded as JSON (see the module docstring on which decoder). Raises ValueError
    (UnicodeDecodeError, JSONDecodeError), CommandError for a non-finite constant and
    RecursionError."""
    if len(data) <= C_DECODE_MAX_BYTES:
        return json.loads(data, parse_constant=_reject_constant)
    return _InterruptibleDecoder().decode(data.decode(json.detect_encoding(data)))


def _finite(value: Any, field: str) -> float:
    """Return `value` as a finite float or raise CommandError naming `field`."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise CommandError(f"{field}: expected a number, got {type(value).__name__}")
    try:
        out = float(value)
    except OverflowError:  # an integer beyond the float range
        raise CommandError(f"{field}: must be a finite number, got an integer too large") from None
    if not math.isfinite(out):
        raise CommandError(f"{field}: must be a finite number, got {quote(value)}")
    return out


def parse_point(value: Any, field: str) -> Vec3:
    """Return `value` (a JSON [x, y, z]) as a 3-tuple of finite floats, as every command reads
    a point; raise CommandError naming `field` (e.g. "points_m[3]")."""
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise CommandError(f"{field}: expected [x, y, z], got {quote(value)}")
    return (
        _finite(value[0], f"{field}[0]"),
        _finite(value[1], f"{field}[1]"),
        _finite(value[2], f"{field}[2]"),
    )


def _speed(obj: dict[str, Any]) -> float | None:
    """Return the optional `speed_mps` field or raise CommandError.

    The speed rule is `controller.core.motion.check_speed` (at least `MIN_SPEED_MPS`); a speed above
    the robot's maximum is not an error here: the loop runs at the maximum and says so.
    """
    if obj.get("speed_mps") is None:
        return None
    speed = _finite(obj["speed_mps"], "speed_mps")
    reason = check_speed(speed)
    if reason is not None:
        raise CommandError(f"speed_mps: {reason}")
    return speed


def _flag(obj: dict[str, Any], field: str) -> bool:
    """Return the optional boolean `field` (absent or null: False) or raise CommandError (only
    JSON `true` / `false`: a number or a string is not a flag)."""
    value = obj.get(field)
    if value is None:
        return False
    if not isinstance(value, bool):
        raise CommandError(f"{field}: expected true or false, got {quote(value)}")
    return value


def _object(data: bytes, allowed: set[str], required: set[str]) -> dict[str, Any]:
    """Decode a JSON object (size already checked), refusing deep nesting, unknown and missing
    keys."""
    if len(data.strip()) == 0:
        obj: Any = {}
    else:
        _check_depth(data)
        try:
            obj = _decode(data)
        except RecursionError:  # brackets hidden from _check_depth in strings
            raise CommandError(_too_deep()) from None
        except (ValueError, UnicodeDecodeError) as exc:
            raise CommandError(f"malformed JSON: {clip(str(exc))}") from None
    if not isinstance(obj, dict):
        raise CommandError(f"expected a JSON object, got {type(obj).__name__}")
    unknown = [name for name in obj if name not in allowed]  # in order; bytecode, no long sort
    if unknown:
        shown = ", ".join(clip(name, 24) for name in unknown[:4])
        more = f" and {len(unknown) - 4} more" if len(unknown) > 4 else ""
        raise CommandError(f"unknown field(s): {shown}{more}")
    missing = required - set(obj)
    if missing:
        raise CommandError(f"missing field(s): {', '.join(sorted(missing))}")
    return obj


def _reject_constant(name: str) -> Any:
    """json.loads hook: NaN, Infinity and -Infinity are not valid numbers here."""
    raise CommandError(f"non-finite number {name} is not allowed")


def _shaper(obj: dict[str, Any]) -> Shaper:
    """A `shaper` command from its decoded object, checked by the shaper's own rule (a type of
    `SHAPER_TYPES`, with a did-you-mean; the frequency and damping ratio in range). Raises
    CommandError."""
    kind = obj["type"]
    if not isinstance(kind, str):
        raise CommandError(f"type: expected a string, got {quote(kind)}")
    freq = None if obj.get("frequency_hz") is None else _finite(obj["frequency_hz"], "frequency_hz")
    damping = (
        None if obj.get("damping_ratio") is None else _finite(obj["damping_ratio"], "damping_ratio")
    )
    if kind not in SHAPER_TYPES:
        near = closest(kind.lower(), SHAPER_TYPES)
        hint = f" (did you mean {near!r}?)" if near else ""
        raise CommandError(
            f"type: unknown shaper type {quote(kind, 40)}{hint}; one of {', '.join(SHAPER_TYPES)}"
        )
    reason = check_shaper(kind, freq, 0.0 if damping is None else damping)
    if reason is not None:
        raise CommandError(reason)
    return Shaper(kind, freq, damping)


def parse_command(verb: str, payload: bytes | str | None) -> Command:
    """Parse the JSON `payload` of command `verb` into a Command.

    Raises CommandError (with a reason fit to send back to the client, quoting at most
    QUOTE_CHARS characters of the input) for an unknown verb, a payload larger than
    MAX_PAYLOAD_BYTES[verb] (checked before decoding), nesting deeper than MAX_JSON_DEPTH,
    malformed JSON, unknown or missing fields, more than MAX_PATH_POINTS points, non-numbers,
    non-finite numbers and a path's `append` that is not a JSON boolean.
    """
    if payload is None:
        data = b""
    elif isinstance(payload, str):
        check_payload_size(verb, len(payload))  # characters <= bytes: refuse before encoding
        data = payload.encode("utf-8", "surrogatepass")
    else:
        data = bytes(payload)
    check_payload_size(verb, len(data))
    if verb == "move":
        obj = _object(data, {"position_m", "speed_mps"}, {"position_m"})
        return Move(parse_point(obj["position_m"], "position_m"), _speed(obj))
    if verb == "path":
        obj = _object(data, {"points_m", "speed_mps", "append"}, {"points_m"})
        pts = obj["points_m"]
        if not isinstance(pts, list) or not pts:
            raise CommandError("points_m: expected a non-empty list of [x, y, z]")
        if len(pts) > MAX_PATH_POINTS:
            raise CommandError(
                f"points_m: at most {MAX_PATH_POINTS} points, got {len(pts)}; {PATH_STREAM_HINT}"
            )
        points = tuple(parse_point(p, f"points_m[{i}]") for i, p in enumerate(pts))
        return Path(points, _speed(obj), _flag(obj, "append"))
    if verb == "home":
        obj = _object(data, {"position_m"}, {"position_m"})
        return Home(parse_point(obj["position_m"], "position_m"))
    if verb == "pretension":
        obj = _object(data, {"position_m"}, {"position_m"})
        return Pretension(parse_point(obj["position_m"], "position_m"))
    if verb == "setpoint":
        obj = _object(data, {"position_m"}, {"position_m"})
        return Setpoint(parse_point(obj["position_m"], "position_m"))
    if verb == "velocity":
        obj = _object(data, {"velocity_mps"}, {"velocity_mps"})
        return Velocity(parse_point(obj["velocity_mps"], "velocity_mps"))
    if verb == "shaper":
        return _shaper(_object(data, {"type", "frequency_hz", "damping_ratio"}, {"type"}))
    simple: dict[str, Command] = {
        "stop": Stop(),
        "estop": Estop(),
        "arm": Arm(),
        "disarm": Disarm(),
        "reset": Reset(),
    }
    if verb in simple:
        _object(data, set(), set())
        return simple[verb]
    raise CommandError(f"unknown command {clip(verb)!r}; known: {', '.join(VERBS)}")
