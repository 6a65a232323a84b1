"""What the daemon says, as typed objects: a pose sample, the status, a command's reply, the
end of a pre-tension, a live daemon, the simulator's ground truth.

Each is read from the daemon's JSON (docs/zenoh.md) by a `from_...` constructor that never
raises for a missing or odd field: a number that is absent, not a number or not finite reads as
None, so a pose that is not valid has `position_m` None, never NaN. The JSON as the daemon sent
it stays available (`raw`) for the fields not typed here and for printing or forwarding it.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

Vec3 = tuple[float, float, float]

_EMPTY: Mapping[str, Any] = MappingProxyType({})


def number(value: Any) -> float | None:
    """`value` as a finite float; None when it is absent, not a number (a bool is not) or not
    finite."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    out = float(value)
    return out if math.isfinite(out) else None


def vec3(value: Any) -> Vec3 | None:
    """`value` as (x, y, z) of finite floats; None unless it is a list of three such."""
    if not isinstance(value, list | tuple) or len(value) != 3:
        return None
    x, y, z = number(value[0]), number(value[1]), number(value[2])
    if x is None or y is None or z is None:
        return None
    return (x, y, z)


def numbers(value: Any) -> tuple[float | None, ...] | None:
    """`value` as a tuple of `number`s (None where one is not a finite number); None unless it
    is a list."""
    if not isinstance(value, list | tuple):
        return None
    return tuple(number(v) for v in value)


def _int(value: Any, default: int = 0) -> int:
    return value if isinstance(value, int) and not isinstance(value, bool) else default


def _str(value: Any) -> str | None:
    return value if isinstance(value, str) else None


def _section(data: Mapping[str, Any], name: str) -> Mapping[str, Any]:
    value = data.get(name)
    return value if isinstance(value, Mapping) else _EMPTY


def _reject_constant(name: str) -> Any:
    raise ValueError(f"non-finite number {name}")


def decode_object(data: bytes | str) -> dict[str, Any]:
    """A JSON object from the daemon. Raises ValueError when `data` is not a JSON object (or
    holds NaN or infinity, which no daemon sends)."""
    obj = json.loads(data, parse_constant=_reject_constant)
    if not isinstance(obj, dict):
        raise ValueError(f"expected a JSON object, got {type(obj).__name__}")
    return obj


# --------------------------------------------------------------------------------------------
# The pose


@dataclass(frozen=True, slots=True)
class Pose:
    """One sample of `<prefix>/pose`: where the effector is, in which state.

    `position_m` is None while the pose is not valid (never NaN); `residual_m` is the forward
    kinematics' residual (None when not valid); `tensions_n` the set-point's planned cable
    tensions (with `[payload]`), `measured_tensions_n` those from torque telemetry (None per
    cable without a fresh reading); `queued_points` the path points still queued.
    `received_s` is `time.monotonic()` when this client received the sample; `raw` the sample
    as the daemon sent it (`as_dict()` decodes it).
    """

    seq: int
    stamp_ns: int
    state: str
    position_m: Vec3 | None
    residual_m: float | None = None
    cable_lengths_m: tuple[float | None, ...] = ()
    tensions_n: tuple[float | None, ...] | None = None
    measured_tensions_n: tuple[float | None, ...] | None = None
    queued_points: int = 0
    received_s: float = field(default=0.0, compare=False)
    raw: bytes = field(default=b"", repr=False, compare=False)

    @property
    def valid(self) -> bool:
        """True when the pose is known (`position_m` is not None)."""
        return self.position_m is not None

    @classmethod
    def from_json(cls, data: bytes, received_s: float | None = None) -> Pose:
        """The pose of a `<prefix>/pose` sample. Raises ValueError when it is not a JSON object
        with an integer `seq` and a string `state`."""
        obj = decode_object(data)
        return cls.from_mapping(obj, received_s, raw=data)

    @classmethod
    def from_mapping(
        cls, obj: Mapping[str, Any], received_s: float | None = None, *, raw: bytes | None = None
    ) -> Pose:
        """The pose of a decoded sample. Raises ValueError when `seq` is not an integer or
        `state` not a string."""
        seq, state = obj.get("seq"), obj.get("state")
        if not isinstance(seq, int) or isinstance(seq, bool) or not isinstance(state, str):
            raise ValueError("a pose sample needs an integer seq and a string state")
        position = vec3(obj.get("position_m")) if obj.get("valid", True) is not False else None
        return cls(
            seq=seq,
            stamp_ns=_int(obj.get("stamp_ns")),
            state=state,
            position_m=position,
            residual_m=number(obj.get("residual_m")) if position is not None else None,
            cable_lengths_m=numbers(obj.get("cable_lengths_m")) or (),
            tensions_n=numbers(obj.get("tensions_n")),
            measured_tensions_n=numbers(obj.get("measured_tensions_n")),
            queued_points=_int(obj.get("queued_points")),
            received_s=time.monotonic() if received_s is None else received_s,
            raw=raw if raw is not None else json.dumps(dict(obj)).encode(),
        )

    def as_dict(self) -> dict[str, Any]:
        """The sample as the daemon sent it, decoded."""
        return decode_object(self.raw)

    def text(self) -> str:
        """One line for a person: sequence, state, position (or "not valid"), residual."""
        return pose_text(self.seq, self.state, self.position_m, self.residual_m)


def xyz_text(p: Sequence[Any], digits: int = 3) -> str:
    """`x=+1.000 y=+2.000 z=+3.000 m` for a point."""
    return " ".join(f"{a}={float(v):+.{digits}f}" for a, v in zip("xyz", p, strict=False)) + " m"


def pose_text(seq: Any, state: Any, position_m: Sequence[float] | None, residual_m: Any) -> str:
    """One line for a pose sample: `seq N  state S  x=... m  resid R mm`."""
    if position_m is None:
        where = "x=   ---  y=   ---  z=   ---  m (pose not valid)"
    else:
        where = f"x={position_m[0]:+.3f} y={position_m[1]:+.3f} z={position_m[2]:+.3f} m"
    resid = "" if residual_m is None else f"  resid {residual_m * 1e3:.1f} mm"
    return f"seq {seq}  state {state}  {where}{resid}"


@dataclass(frozen=True, slots=True)
class StateChange:
    """One sample of `<prefix>/state`, published on every change of state: the new state, why
    (a fault's reason; None when there is none) and when (`stamp_ns`, wall clock)."""

    state: str
    reason: str | None
    stamp_ns: int
    received_s: float = field(default=0.0, compare=False)

    @classmethod
    def from_json(cls, data: bytes, received_s: float | None = None) -> StateChange:
        """The change of one sample. Raises ValueError when it is not a JSON object with a
        string `state`."""
        obj = decode_object(data)
        state = obj.get("state")
        if not isinstance(state, str):
            raise ValueError("a state sample needs a string state")
        return cls(
            state=state,
            reason=_str(obj.get("reason")),
            stamp_ns=_int(obj.get("stamp_ns")),
            received_s=time.monotonic() if received_s is None else received_s,
        )


# --------------------------------------------------------------------------------------------
# The status


@dataclass(frozen=True, slots=True)
class AxisStatus:
    """One reel's drive as the status gives it: its node, whether it follows set-points, its
    state and fault by the drive's names, its motor turns and the age of its last readings."""

    node_id: int
    ready: bool
    state: str | None
    fault: str | None
    position_rev: float | None
    age_s: float | None
    heartbeat_age_s: float | None

    @classmethod
    def from_mapping(cls, ax: Mapping[str, Any]) -> AxisStatus:
        """The axis of one entry of the status's `axes`."""
        return cls(
            node_id=_int(ax.get("node_id"), -1),
            ready=ax.get("ready") is True,
            state=_str(ax.get("state")),
            fault=_str(ax.get("fault")),
            position_rev=number(ax.get("position_rev")),
            age_s=number(ax.get("age_s")),
            heartbeat_age_s=number(ax.get("heartbeat_age_s")),
        )


@dataclass(frozen=True, slots=True)
class PathQueue:
    """The daemon's path queue: points and seconds of motion queued (a lower bound), whether it
    is full, whether an append would continue the path in progress."""

    queued_points: int = 0
    queued_s: float = 0.0
    queue_full: bool = False
    appendable: bool = False

    @classmethod
    def from_mapping(cls, p: Mapping[str, Any]) -> PathQueue:
        """The queue of the status's `path` section (or of a path command's reply)."""
        return cls(
            queued_points=_int(p.get("queued_points")),
            queued_s=number(p.get("queued_s")) or 0.0,
            queue_full=p.get("queue_full") is True,
            appendable=p.get("appendable") is True,
        )


@dataclass(frozen=True, slots=True)
class PretensionStatus:
    """The pre-tension as the status gives it: whether one runs, for how long, the fastest
    cable's speed, where it homes, and the result of the last one (`PretensionResult`)."""

    active: bool = False
    elapsed_s: float | None = None
    fastest_cable_mps: float | None = None
    position_m: Vec3 | None = None
    result: PretensionResult | None = None

    @classmethod
    def from_mapping(cls, p: Mapping[str, Any]) -> PretensionStatus:
        """The pre-tension of the status's `pretension` section."""
        res = p.get("result")
        return cls(
            active=p.get("active") is True,
            elapsed_s=number(p.get("elapsed_s")),
            fastest_cable_mps=number(p.get("fastest_cable_mps")),
            position_m=vec3(p.get("position_m")),
            result=PretensionResult.from_mapping(res) if isinstance(res, Mapping) else None,
        )


@dataclass(frozen=True, slots=True)
class Status:
    """The daemon's status (`<prefix>/status`), its main parts typed.

    `position_m` and `residual_m` are the pose (None while not valid), `setpoint_m` where the
    robot is commanded to be; `robot_name`, `node_ids` and `max_speed_mps` come from the
    robot the daemon runs. Everything else the daemon reports (loop and bus figures, the Zenoh
    counters, the whole configuration summary) is in `raw`, as sent.
    """

    state: str
    reason: str | None
    position_m: Vec3 | None
    residual_m: float | None
    setpoint_m: Vec3 | None
    homed: bool
    home_source: str | None
    axes: tuple[AxisStatus, ...]
    path: PathQueue
    pretension: PretensionStatus
    robot_name: str | None
    node_ids: tuple[int, ...]
    max_speed_mps: float | None
    raw: Mapping[str, Any] = field(default_factory=lambda: _EMPTY, repr=False, compare=False)

    @classmethod
    def from_mapping(cls, st: Mapping[str, Any]) -> Status:
        """The status of a decoded `<prefix>/status` reply; never raises (an odd reply reads as
        state "UNKNOWN" with nothing known)."""
        pose = _section(st, "pose")
        cfg = _section(st, "config")
        reels = cfg.get("reels")
        node_ids = tuple(
            _int(r.get("node_id"), -1)
            for r in (reels if isinstance(reels, list) else [])
            if isinstance(r, Mapping)
        )
        axes = st.get("axes")
        position = vec3(pose.get("position_m"))
        return cls(
            state=_str(st.get("state")) or "UNKNOWN",
            reason=_str(st.get("reason")),
            position_m=position,
            residual_m=number(pose.get("residual_m")) if position is not None else None,
            setpoint_m=vec3(st.get("setpoint_m")),
            homed=st.get("homed") is True,
            home_source=_str(st.get("home_source")),
            axes=tuple(
                AxisStatus.from_mapping(a)
                for a in (axes if isinstance(axes, list) else [])
                if isinstance(a, Mapping)
            ),
            path=PathQueue.from_mapping(_section(st, "path")),
            pretension=PretensionStatus.from_mapping(_section(st, "pretension")),
            robot_name=_str(cfg.get("name")),
            node_ids=node_ids,
            max_speed_mps=number(_section(cfg, "limits").get("max_speed_mps")),
            raw=MappingProxyType(dict(st)),
        )


# --------------------------------------------------------------------------------------------
# Replies


@dataclass(frozen=True, slots=True)
class Reply:
    """A command's reply (`{"ok": true, ...}`): the state the robot is in now and what the
    verb reports. A move: `target_m`, `speed_mps` and `speed_limited_to_mps` (set when the speed
    asked for was above the robot's maximum); a path: `points` taken and the queue after it
    (`queue`); a home: `position_m`, `offsets_rev` by node, `saved` and `state_file`; a
    pre-tension: `tensions_n`; an `arm` of a robot that was armed already: `already_armed`.
    `raw` is the reply as sent."""

    verb: str
    state: str | None
    target_m: Vec3 | None = None
    speed_mps: float | None = None
    speed_limited_to_mps: float | None = None
    points: int | None = None
    queue: PathQueue | None = None
    position_m: Vec3 | None = None
    offsets_rev: Mapping[int, float] | None = None
    saved: bool = False
    state_file: str | None = None
    tensions_n: tuple[float | None, ...] | None = None
    already_armed: bool = False
    raw: Mapping[str, Any] = field(default_factory=lambda: _EMPTY, repr=False, compare=False)

    @classmethod
    def from_reply(cls, verb: str, reply: Any) -> Reply:
        """The reply of `verb` as decoded from the daemon (anything that is not an object
        reads as a bare "ok")."""
        r: Mapping[str, Any] = reply if isinstance(reply, Mapping) else _EMPTY
        queue = None
        if any(k in r for k in ("queued_points", "queued_s", "queue_full")):
            queue = PathQueue.from_mapping(r)
        return cls(
            verb=verb,
            state=_str(r.get("state")),
            target_m=vec3(r.get("target_m")),
            speed_mps=number(r.get("speed_mps")),
            speed_limited_to_mps=number(r.get("speed_limited_to_mps")),
            points=r.get("points") if isinstance(r.get("points"), int) else None,
            queue=queue,
            position_m=vec3(r.get("position_m")),
            offsets_rev=_offsets(r.get("offsets_rev")),
            saved=r.get("saved") is True,
            state_file=_str(r.get("state_file")),
            tensions_n=numbers(r.get("tensions_n")),
            already_armed=r.get("already_armed") is True,
            raw=MappingProxyType(dict(r)),
        )


def _offsets(value: Any) -> Mapping[int, float] | None:
    """A home reply's `offsets_rev` ({"node id": turns}) by node; None when there is none."""
    if not isinstance(value, Mapping):
        return None
    out: dict[int, float] = {}
    for k, v in value.items():
        turns = number(v)
        try:
            node = int(k)
        except (TypeError, ValueError):
            continue
        if turns is not None:
            out[node] = turns
    return MappingProxyType(out)


@dataclass(frozen=True, slots=True)
class PretensionResult:
    """How a pre-tension ended: `ok` (the reels came to rest and the robot was homed there),
    after how long, where it homed and the offsets, the measured tensions, whether the offsets
    are still being saved to the state file (`saving`); else `reason`."""

    ok: bool
    reason: str | None
    still_after_s: float | None
    position_m: Vec3 | None
    measured_tensions_n: tuple[float | None, ...] | None
    saving: bool = False
    raw: Mapping[str, Any] = field(default_factory=lambda: _EMPTY, repr=False, compare=False)

    @classmethod
    def from_mapping(cls, r: Mapping[str, Any]) -> PretensionResult:
        """The result in the status's `pretension.result`."""
        return cls(
            ok=r.get("ok") is True,
            reason=_str(r.get("reason")),
            still_after_s=number(r.get("still_after_s")),
            position_m=vec3(r.get("position_m")),
            measured_tensions_n=numbers(r.get("measured_tensions_n")),
            saving=r.get("saving") is True,
            raw=MappingProxyType(dict(r)),
        )


@dataclass(frozen=True, slots=True)
class DaemonInfo:
    """A live daemon: its key prefix, robot name, state and the endpoints it listens on (None
    where its status did not say, or it did not answer in time)."""

    prefix: str
    name: str | None = None
    state: str | None = None
    listen: tuple[str, ...] | None = None

    def as_dict(self) -> dict[str, Any]:
        """The daemon as a JSON-ready dict (`cablebot list --json`)."""
        return {
            "prefix": self.prefix,
            "name": self.name,
            "state": self.state,
            "listen": None if self.listen is None else list(self.listen),
        }


@dataclass(frozen=True, slots=True)
class Truth:
    """The simulator's ground truth (`<prefix>/sim/truth`, with the physical plant only): the
    plant's true effector position and cable tensions; never the controller's input."""

    position_m: Vec3 | None
    tensions_n: tuple[float | None, ...]
    received_s: float = field(default=0.0, compare=False)

    @classmethod
    def from_json(cls, data: bytes, received_s: float | None = None) -> Truth:
        """The truth of one sample. Raises ValueError when it is not a JSON object."""
        obj = decode_object(data)
        return cls(
            position_m=vec3(obj.get("position_m")),
            tensions_n=numbers(obj.get("tensions_n")) or (),
            received_s=time.monotonic() if received_s is None else received_s,
        )
