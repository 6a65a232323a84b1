"""Robot configuration: one TOML file per robot -> validated, frozen `RobotConfig`.

`load_config(path)` reads and validates a file (`None` = the built-in default robot),
`parse_config(mapping, source)` validates an already-parsed mapping, `default_config()` is the
paper's 80.9 m x 50 m x 7.62 m robot on four simulated reels on a python-can `virtual` bus.

Validation rules (every mistake is reported, all of them at once: one `ConfigError` whose
message has one line per problem naming the file and the key path, e.g.
``config/desk.toml: reels[2].metres_per_rev: must be > 0, got -0.1``; checks that combine
values run only when those values are valid themselves):

* the file must be UTF-8 TOML;
* unknown keys are errors (with a "did you mean" hint), so typos never silently pass;
* units are part of the key names (`_m`, `_mps`, `_mps2`, `_s`, `_hz`, `_rps`, `_rev`); a value
  written with a unit ("2 m/s") or of the wrong type is an error naming the unit expected;
* numbers are finite, within ±1e9 and range-checked, node ids are unique and in the drive
  family's range (ODrive 0..63, CiA 402 1..127), at least three reels;
* `[drive] kind` names a drive family of `drivers.registry` ("odrive" by default, "cia402"),
  and the other `[drive]` keys are that family's options, checked from the registry's table
  (type, default, range; a file must exist) and by the family's own checks (a CiA 402 EDS must
  load and hold the objects used, the loop period must be an exact CiA 402 interpolation
  period); cross-checks: `faults.heartbeat_timeout_s` is at least two drive heartbeat periods,
  `loop.encoder_rtr` only with ODrive drives, and with `counts_per_rev` every reel's cable
  range fits the drives' 32-bit position;
* `bus.interface` is a python-can interface name and every `[bus.options]` key is a keyword
  the interface's python-can bus class takes (`bus_option_names`; `hop_limit` for
  udp_multicast); Zenoh endpoints are `proto/host:port` with a valid port, and a Zenoh
  `config_file` must load (with valid endpoints);
* the anchors must make a usable `Geometry` (coincident or collinear anchors -> error naming
  the anchors);
* cross-checks: the shrunk workspace is not empty, floor below the top limit, min < max cable,
  default speed <= max speed, fault timeouts longer than two loop periods (and than the
  simulator's encoder period), every reel can pay out `max_cable_m` and keeps better than
  0.1 mm resolution over the cable range in float32 motor turns (the ODrive CANSimple
  position type), and the power-up position (if any) is inside the limits;
* statics: with `[payload] mass_kg`, `limits.min_tension_n` is required and so is
  `limits.max_tension_n` unless every reel gives `max_torque_nm` (the smaller maximum wins:
  `TensionLimits`); the range must stay open inside `tension_margin_n`, and the payload must
  be holdable at the power-up position with every tension at least the margin inside the
  range. Without `[payload]` no tension key may be set (it would do nothing).

Keys and helpers with defaults, so a file that omits them still loads:
`LoopConfig.rt_priority` (int, 50), `LoopConfig.auto_arm` (bool | None; None = arm at start
only with `sim.enabled`), `SimConfig.tick_s` (0.001 s), `SimConfig.watchdog_timeout_s` (0.3 s,
the simulated drives' axis watchdog; unset in a file: 0.3 s or 5 loop periods if longer),
`BusConfig.as_mapping()` (for `drivers.bus.open_bus`), `RobotConfig.node_ids` /
`RobotConfig.anchors_m` properties, `bus_option_names(interface)`.
`HomingConfig.state_file` is stored already expanded (``~`` and ``{name}`` replaced).
In a file, `[limits]` is required with every key but `default_speed_mps` and
`velocity_timeout_s` (a safe limit depends on the robot); all other sections are optional with
the defaults of the dataclasses.
`sim.enabled` defaults to true on the `virtual` bus (nothing else could answer there).
"""

from __future__ import annotations

import difflib
import functools
import json
import math
import os
import re
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, overload

from controller.core.kinematics import Geometry, KinematicsError, SingularGeometryError
from controller.core.pretension import PretensionSettings
from controller.core.reel import ReelModel, spool_buildup
from controller.core.statics import TensionCheck
from controller.core.workspace import Workspace, WorkspaceError
from drivers import busload, registry

Vec3 = tuple[float, float, float]

FLOAT32_RESOLUTION_LIMIT_M = 1e-4
"""Worst allowed cable-length step of one float32 ULP of motor turns over the cable range."""
_MAX_ABS = 1e9
"""Largest magnitude any number in a configuration may have (keeps every check finite)."""
WATCHDOG_MIN_PERIODS = 3.0
"""A simulated drive watchdog must allow at least this many loop periods between commands."""
WATCHDOG_DEFAULT_PERIODS = 5.0
"""Without `sim.watchdog_timeout_s`, the watchdog allows at least this many loop periods."""

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,62}$")
_PREFIX_RE = re.compile(r"^[A-Za-z0-9_.-]+(/[A-Za-z0-9_.-]+)*$")
_ZENOH_MODES = ("peer", "client", "router")
SIM_PLANTS = ("kinematic", "physical")
TORQUE_TELEMETRY = ("off", "cyclic", "rtr")


class ConfigError(ValueError):
    """An invalid configuration; the message names the file (or source) and the key path.

    `errors` holds every problem found (just this one for a single problem), and the message
    has one line per problem, ``<source>: <key>: <problem>``; `key` and `problem` are those of
    the first.
    """

    def __init__(
        self, source: str, key: str, problem: str, *, errors: Sequence[ConfigError] = ()
    ) -> None:
        self.source = source
        self.key = key
        self.problem = problem
        self.errors: tuple[ConfigError, ...] = tuple(errors) if errors else (self,)
        if errors:
            super().__init__("\n".join(_error_line(e) for e in self.errors))
        else:
            super().__init__(_error_line(self))

    @classmethod
    def collected(cls, source: str, errors: Sequence[ConfigError]) -> ConfigError:
        """One error for `errors` (the error itself when there is only one)."""
        if len(errors) == 1:
            return errors[0]
        first = errors[0]
        return cls(source, first.key, first.problem, errors=errors)


def _error_line(e: ConfigError) -> str:
    return f"{e.source}: {e.key}: {e.problem}" if e.key else f"{e.source}: {e.problem}"


# ------------------------------------------------------------------------------- dataclasses
@dataclass(frozen=True, slots=True)
class ReelConfig:
    """One reel: its drive's CAN node id, the anchor (pulley exit point) and the reel model."""

    node_id: int
    anchor_m: Vec3
    reel: ReelModel
    max_torque_nm: float | None = None
    """The motor's torque limit (N m); with it the reel bounds the cable tension (see
    `TensionLimits`). None = no bound from this reel."""


@dataclass(frozen=True, slots=True)
class BusConfig:
    """The python-can bus: interface, channel, bitrate (None = leave as is), extra options."""

    interface: str = "virtual"
    channel: str = "cablebot"
    bitrate: int | None = None
    options: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))

    def as_mapping(self) -> dict[str, Any]:
        """The mapping `drivers.bus.open_bus` accepts (interface, channel, bitrate, options)."""
        out: dict[str, Any] = {"interface": self.interface, "channel": self.channel}
        if self.bitrate is not None:
            out["bitrate"] = self.bitrate
        out.update(self.options)
        return out


@dataclass(frozen=True, slots=True)
class LoopConfig:
    """The control loop: rate, real-time scheduling, GC freeze, publish decimation, RTR polling."""

    rate_hz: float = 500.0
    realtime: bool = True
    gc_freeze: bool = True
    publish_every: int = 1
    encoder_rtr: bool = False
    rt_priority: int = 50
    """SCHED_FIFO priority of the loop thread when `realtime` (1..99)."""
    auto_arm: bool | None = None
    """Arm at start-up; None = only when the reels are simulated in-process (`sim.enabled`)."""
    torque_telemetry: str = "off"
    """How the loop learns each motor's torque (measured cable tensions): "off", "cyclic" (the
    drives broadcast Get_Torques) or "rtr" (asked every `torque_rtr_period_s`)."""
    torque_rtr_period_s: float = 0.01
    """With `torque_telemetry = "rtr"`: how often every axis is asked for its torques."""


@dataclass(frozen=True, slots=True)
class LimitsConfig:
    """Workspace, cable and motion limits (checked on command arrival and every tick)."""

    xy_margin_m: float = 2.0
    floor_z_m: float = 0.0
    top_margin_m: float = 1.0
    min_cable_m: float = 1.0
    max_cable_m: float = 100.0
    max_cable_speed_mps: float = 3.0
    max_speed_mps: float = 2.0
    max_accel_mps2: float = 1.0
    default_speed_mps: float = 1.0
    velocity_timeout_s: float = 0.25
    """Dead-man of velocity input: no `<prefix>/velocity` sample for this long brakes to a hold."""
    min_tension_n: float | None = None
    """Least tension a cable may carry (N); required with `[payload]`."""
    max_tension_n: float | None = None
    """Most tension a cable may carry (N); the reels' `max_torque_nm` may lower it."""
    tension_margin_n: float = 0.0
    """Every tension of a command or set-point must stay this far inside the limits (N)."""


@dataclass(frozen=True, slots=True)
class PayloadConfig:
    """What the cables carry: the effector and its tool, as one point mass."""

    mass_kg: float


@dataclass(frozen=True, slots=True)
class TensionLimits:
    """The cable tension range statics checks against, and where its maximum comes from.

    `max_n` is the smaller of `limits.max_tension_n` and the least tension any reel's
    `max_torque_nm` holds over the cable range (`ReelModel.max_tension_n`); `max_source` names
    the key that won. A command's tensions must lie in [min_n + margin_n, max_n - margin_n].
    """

    min_n: float
    max_n: float
    margin_n: float
    max_source: str


@dataclass(frozen=True, slots=True)
class FaultConfig:
    """Fault thresholds: stale encoders/heartbeats, FPK residual, tracking error, arming time."""

    stale_timeout_s: float = 0.05
    heartbeat_timeout_s: float = 0.5
    residual_max_m: float = 0.02
    tracking_max_m: float = 0.25
    arm_timeout_s: float = 2.0
    bus_error_timeout_s: float = 0.05
    slack_tension_n: float | None = None
    """Fault when a measured cable tension stays below this for `slack_time_s` (needs torque
    telemetry and `[payload]`); None = no slack fault."""
    slack_time_s: float = 0.1
    """How long a measured tension may stay below `slack_tension_n` or above the tension
    maximum before the loop faults."""


@dataclass(frozen=True, slots=True)
class HomingConfig:
    """Pose at power-up (None = operator must `home`) and the offsets state file (None = none).

    `state_file` is stored expanded (``~`` and ``{name}`` replaced).
    """

    power_up_position_m: Vec3 | None = None
    state_file: str | None = None
    pretension_still_mps: float = 0.001
    """Pre-tension (`cablebot home --pretension`): a cable slower than this (m/s) is still."""
    pretension_settle_s: float = 2.0
    """Every cable still for this long: the home pose is declared (longer than half the
    effector's slowest swing)."""
    pretension_timeout_s: float = 30.0
    """The pre-tension faults if the reels are not still by then."""
    pretension_max_travel_m: float = 0.5
    """The pre-tension faults if a cable's length changes by more than this."""
    pretension_speed_mps: float = 0.05
    """The drives' velocity limit in torque control, as cable speed (where the family can set
    it: ODrive with `[drive] velocity_limit_rps` and `current_limit_a`)."""

    @property
    def pretension(self) -> PretensionSettings:
        """The `pretension_*` keys as `controller.core.pretension.PretensionSettings`."""
        return PretensionSettings(
            still_mps=self.pretension_still_mps,
            settle_s=self.pretension_settle_s,
            timeout_s=self.pretension_timeout_s,
            max_travel_m=self.pretension_max_travel_m,
            speed_mps=self.pretension_speed_mps,
        )


@dataclass(frozen=True, slots=True)
class ZenohConfig:
    """Zenoh session settings and the key-expression prefix of this robot."""

    prefix: str = "cablebot/default"
    mode: str = "peer"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    config_file: str | None = None


@dataclass(frozen=True, slots=True)
class SimConfig:
    """Simulated drives of the `[drive]` family (started in-process by the daemon when
    `enabled`, or by `cablebot sim`); the broadcast periods and the watchdog are ODrive's."""

    enabled: bool = False
    encoder_period_s: float = 0.002
    heartbeat_period_s: float = 0.1
    max_velocity_rps: float = 100.0
    max_accel_rps2: float = 400.0
    tick_s: float = 0.001
    """Time step of the simulated axes' dynamics."""
    watchdog_timeout_s: float = 0.3
    """Simulated ODrive axis watchdog (axis.config.watchdog_timeout): an axis in closed loop
    that receives no command for this long disarms to IDLE with WATCHDOG_TIMER_EXPIRED;
    0 = off."""
    plant: str = "kinematic"
    """"kinematic": the reels move, nothing hangs on them (exact, no parameters); "physical":
    one elastic-cable plant carries the payload and the axes report the torque their cables
    need (`controller.core.plant.ReelPlant`; needs `[payload]` and a power-up pose)."""
    cable_ea_n: float = 1.0e6
    """Axial stiffness EA (N) of every simulated cable (physical plant)."""
    torque_period_s: float = 0.01
    """Period of each simulated axis's Get_Torques broadcast (physical plant); 0 = RTR only."""


@dataclass(frozen=True, slots=True)
class DriveConfig:
    """The reels' drive family (a `drivers.registry` name) and its `[drive]` options: every
    option of the family that has a value (given, or its default)."""

    kind: str = registry.DEFAULT_KIND
    options: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))


@dataclass(frozen=True, slots=True)
class RobotConfig:
    """A validated robot configuration (build it with `load_config` / `parse_config`)."""

    name: str
    reels: tuple[ReelConfig, ...]
    geometry: Geometry = field(compare=False)
    bus: BusConfig
    loop: LoopConfig
    limits: LimitsConfig
    faults: FaultConfig
    homing: HomingConfig
    zenoh: ZenohConfig
    sim: SimConfig
    source: str
    payload: PayloadConfig | None = None
    """None: no `[payload]`, so no statics (geometry only)."""
    tension: TensionLimits | None = None
    """Set exactly when `payload` is."""
    drive: DriveConfig = field(default_factory=DriveConfig)

    @property
    def node_ids(self) -> tuple[int, ...]:
        """Node ids in reel (= cable) order."""
        return tuple(r.node_id for r in self.reels)

    @property
    def anchors_m(self) -> tuple[Vec3, ...]:
        """Anchors in reel (= cable) order."""
        return tuple(r.anchor_m for r in self.reels)

    def summary(self) -> dict[str, Any]:
        """A JSON-able description of the whole configuration (for the status queryable)."""
        reels = []
        for r in self.reels:
            m = r.reel
            reels.append(
                {
                    "node_id": r.node_id,
                    "anchor_m": list(r.anchor_m),
                    "metres_per_rev": m.metres_per_rev,
                    "gear_ratio": m.gear_ratio,
                    "direction": m.direction,
                    "mechanical_advantage": m.mechanical_advantage,
                    "spool_buildup_m_per_rev2": m.spool_buildup_m_per_rev2,
                    "reference_length_m": m.reference_length_m,
                    "max_torque_nm": r.max_torque_nm,
                }
            )
        return {
            "name": self.name,
            "source": self.source,
            "reels": reels,
            "bus": {
                "interface": self.bus.interface,
                "channel": self.bus.channel,
                "bitrate": self.bus.bitrate,
                "options": {k: _jsonable(v) for k, v in self.bus.options.items()},
            },
            "loop": _fields(self.loop),
            "limits": _fields(self.limits),
            "faults": _fields(self.faults),
            "homing": {
                "power_up_position_m": (
                    None
                    if self.homing.power_up_position_m is None
                    else list(self.homing.power_up_position_m)
                ),
                "state_file": self.homing.state_file,
                **{
                    k: getattr(self.homing, k)
                    for k in HomingConfig.__dataclass_fields__
                    if k.startswith("pretension_")
                },
            },
            "zenoh": {
                "prefix": self.zenoh.prefix,
                "mode": self.zenoh.mode,
                "listen": list(self.zenoh.listen),
                "connect": list(self.zenoh.connect),
                "multicast_scouting": self.zenoh.multicast_scouting,
                "config_file": self.zenoh.config_file,
            },
            "sim": _fields(self.sim),
            "payload": None if self.payload is None else _fields(self.payload),
            "tension": None if self.tension is None else _fields(self.tension),
            "drive": {
                "kind": self.drive.kind,
                "options": {k: _jsonable(v) for k, v in self.drive.options.items()},
            },
        }


def _fields(obj: Any) -> dict[str, Any]:
    return {name: getattr(obj, name) for name in obj.__dataclass_fields__}


def _jsonable(v: Any) -> Any:
    if isinstance(v, bool | int | str) or v is None:
        return v
    if isinstance(v, float):
        return v if math.isfinite(v) else str(v)
    if isinstance(v, list | tuple):
        return [_jsonable(x) for x in v]
    if isinstance(v, Mapping):
        return {str(k): _jsonable(x) for k, x in v.items()}
    return str(v)


# ------------------------------------------------------------------------------- validation
_UNIT_WORDS = {
    "_kg": "kilograms",
    "_nm": "newton-metres",
    "_n": "newtons",
    "_per_rev": "units per motor turn",
    "_per_rps": "units per motor turn per second",
    "_mps2": "metres per second squared",
    "_rps2": "motor turns per second squared",
    "_m_per_rev2": "metres per turn per turn",
    "_mps": "metres per second",
    "_rps": "motor turns per second",
    "_hz": "hertz",
    "_rev": "motor turns",
    "_m": "metres",
    "_s": "seconds",
}


def _unit_of(key: str) -> str | None:
    for suffix, words in _UNIT_WORDS.items():
        if key.endswith(suffix):
            return words
    return None


class _Errors:
    """Every problem found in one configuration, in the order found."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.items: list[ConfigError] = []

    def add(self, key: str, problem: str) -> None:
        self.items.append(ConfigError(self.source, key, problem))

    def mark(self) -> int:
        return len(self.items)

    def clean_since(self, mark: int) -> bool:
        """True if no problem was found since `mark()` returned `mark`."""
        return len(self.items) == mark

    def check(self, key: str, fn: Callable[[], None]) -> None:
        """Run a cross-check that raises ConfigError; record its problems and go on. A value
        that makes the arithmetic fail is reported against `key` too."""
        try:
            fn()
        except ConfigError as exc:
            self.items.extend(exc.errors)
        except (ArithmeticError, ValueError) as exc:
            self.add(key, f"values out of range for the checks ({type(exc).__name__}: {exc})")

    def raise_if_any(self) -> None:
        """Raise one ConfigError listing every problem found (nothing if none)."""
        if self.items:
            raise ConfigError.collected(self.source, self.items)


class _Table:
    """One TOML table being validated: typed getters that record which keys were used.

    A getter that finds a problem records it in `errs` and returns a stand-in (the default, or
    NaN / None), so that validation goes on and every problem is reported at once; checks that
    combine values run only when their inputs were clean.
    """

    def __init__(self, data: Any, path: str, errs: _Errors) -> None:
        self.path = path
        self.errs = errs
        self.source = errs.source
        self.used: set[str] = set()
        if isinstance(data, Mapping):
            self.data: Mapping[str, Any] = data
        else:
            errs.add(path, f"must be a table, got {_tname(data)}")
            self.data = {}

    def key(self, name: str) -> str:
        return f"{self.path}.{name}" if self.path else name

    def error(self, name: str, problem: str) -> ConfigError:
        return ConfigError(self.source, self.key(name), problem)

    def fail(self, name: str, problem: str) -> None:
        """Record a problem with key `name` of this table."""
        self.errs.add(self.key(name), problem)

    def fail_here(self, problem: str) -> None:
        """Record a problem with this table as a whole."""
        self.errs.add(self.path, problem)

    def has(self, name: str) -> bool:
        return name in self.data

    def raw(self, name: str) -> Any:
        self.used.add(name)
        return self.data[name]

    def number(
        self,
        name: str,
        default: float | None = None,
        *,
        gt: float | None = None,
        ge: float | None = None,
        le: float | None = None,
        required: bool = False,
    ) -> float:
        fallback = math.nan if default is None else default
        if name not in self.data:
            if required or default is None:
                self.fail(name, "missing (required)")
            return fallback
        v = self.raw(name)
        if isinstance(v, bool) or not isinstance(v, int | float):
            unit = _unit_of(name)
            hint = f" in {unit} (the unit is in the key name)" if unit else ""
            self.fail(name, f"must be a number{hint}, got {v!r}")
            return fallback
        try:
            f = float(v)
        except OverflowError:  # an integer beyond float range
            f = math.inf
        problem = None
        if not math.isfinite(f):
            problem = f"must be finite, got {v!r}"
        elif abs(f) > _MAX_ABS:
            problem = f"must be within ±{_MAX_ABS:g}, got {v!r}"
        elif gt is not None and not f > gt:
            problem = f"must be > {gt:g}, got {v!r}"
        elif ge is not None and not f >= ge:
            problem = f"must be >= {ge:g}, got {v!r}"
        elif le is not None and not f <= le:
            problem = f"must be <= {le:g}, got {v!r}"
        if problem is not None:
            self.fail(name, problem)
            return fallback
        return f

    @overload
    def integer(
        self, name: str, default: int, *, ge: int | None = None, le: int | None = None
    ) -> int: ...

    @overload
    def integer(
        self, name: str, default: None = None, *, ge: int | None = None, le: int | None = None
    ) -> int | None: ...

    def integer(
        self, name: str, default: int | None = None, *, ge: int | None = None, le: int | None = None
    ) -> int | None:
        """The integer at `name`; None (after recording the problem) if it is missing without
        a default or invalid and there is no default."""
        if name not in self.data:
            if default is None:
                self.fail(name, "missing (required)")
            return default
        v = self.raw(name)
        problem = None
        if isinstance(v, bool) or not isinstance(v, int):
            problem = f"must be an integer, got {v!r}"
        elif ge is not None and v < ge:
            problem = f"must be >= {ge}, got {v}"
        elif le is not None and v > le:
            problem = f"must be <= {le}, got {v}"
        if problem is not None:
            self.fail(name, problem)
            return default
        return int(v)

    def boolean(self, name: str, default: bool) -> bool:
        if name not in self.data:
            return default
        v = self.raw(name)
        if not isinstance(v, bool):
            self.fail(name, f"must be true or false, got {v!r}")
            return default
        return v

    def string(self, name: str, default: str | None) -> str | None:
        if name not in self.data:
            return default
        v = self.raw(name)
        if not isinstance(v, str) or not v:
            self.fail(name, f"must be a non-empty string, got {v!r}")
            return default
        return v

    def strings(self, name: str, default: tuple[str, ...]) -> tuple[str, ...]:
        if name not in self.data:
            return default
        v = self.raw(name)
        if not isinstance(v, list) or not all(isinstance(s, str) and s for s in v):
            self.fail(name, f"must be a list of non-empty strings, got {v!r}")
            return default
        return tuple(v)

    def vec3(self, name: str, *, required: bool = True) -> Vec3 | None:
        """[x, y, z] in metres at `name`; None if absent (recorded when `required`) or bad."""
        if name not in self.data:
            if required:
                self.fail(name, "missing (required)")
            return None
        v = self.raw(name)
        if (
            not isinstance(v, list)
            or len(v) != 3
            or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
        ):
            self.fail(name, f"must be [x, y, z] in metres (3 numbers), got {v!r}")
            return None
        try:
            x, y, z = (float(c) for c in v)
        except OverflowError:
            x = y = z = math.inf
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            self.fail(name, f"must be finite, got {v!r}")
            return None
        if max(abs(x), abs(y), abs(z)) > _MAX_ABS:
            self.fail(name, f"coordinates must be within ±{_MAX_ABS:g} m, got {v!r}")
            return None
        return (x, y, z)

    def sub(self, name: str) -> _Table:
        if name not in self.data:
            return _Table({}, self.key(name), self.errs)
        return _Table(self.raw(name), self.key(name), self.errs)

    def finish(self, allowed: tuple[str, ...]) -> None:
        """Record every key not in `allowed` (unknown key, with a did-you-mean hint)."""
        known = set(allowed)
        for k in self.data:
            if k not in known:
                self.fail(k, _unknown(k, known))


def _unknown(key: str, known: set[str]) -> str:
    close = difflib.get_close_matches(key, sorted(known), n=1, cutoff=0.6)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    if not close:
        stem = key.rsplit("_", 1)[0]
        same_stem = sorted(k for k in known if k.rsplit("_", 1)[0] == stem)
        if same_stem:
            hint = f"; units are part of key names: did you mean {same_stem[0]!r}?"
    return f"unknown key{hint}"


def _tname(v: Any) -> str:
    return type(v).__name__


_REEL_KEYS = (
    "node_id",
    "anchor_m",
    "metres_per_rev",
    "drum_radius_m",
    "gear_ratio",
    "direction",
    "mechanical_advantage",
    "spool_buildup_m_per_rev2",
    "cable_diameter_m",
    "turns_per_layer",
    "reference_length_m",
    "max_torque_nm",
)


def _parse_reel(t: _Table, family: registry.Family | None) -> ReelConfig | None:
    """One [[reels]] table; None (problems recorded) if it is not usable. `family`: the drive
    family whose node id range applies (None: the family is unknown, any 0..127)."""
    mark = t.errs.mark()
    t.finish(_REEL_KEYS)
    lo, hi = (0, 127) if family is None else (family.node_id_min, family.node_id_max)
    node_id = t.integer("node_id", ge=lo, le=hi)
    anchor = t.vec3("anchor_m")
    has_mpr, has_radius = t.has("metres_per_rev"), t.has("drum_radius_m")
    mpr = math.nan
    if has_mpr == has_radius:
        t.fail_here("give exactly one of metres_per_rev and drum_radius_m")
    elif has_mpr:
        mpr = t.number("metres_per_rev", gt=0.0)
    else:
        mpr = 2.0 * math.pi * t.number("drum_radius_m", gt=0.0)
    gear = t.number("gear_ratio", 1.0, gt=0.0)
    direction = t.integer("direction", 1)
    if direction not in (1, -1):
        t.fail("direction", f"must be 1 or -1, got {direction}")
    ma = t.number("mechanical_advantage", 1.0, gt=0.0)
    buildup = 0.0
    if t.has("spool_buildup_m_per_rev2") and (
        t.has("cable_diameter_m") or t.has("turns_per_layer")
    ):
        t.fail_here(
            "give either spool_buildup_m_per_rev2 or cable_diameter_m/turns_per_layer, not both"
        )
    elif t.has("cable_diameter_m") or t.has("turns_per_layer"):
        d = t.number("cable_diameter_m", 0.0, ge=0.0)
        tpl = t.number("turns_per_layer", 1.0, gt=0.0)
        buildup = spool_buildup(d, tpl)
    else:
        buildup = t.number("spool_buildup_m_per_rev2", 0.0, ge=0.0)
    ref = t.number("reference_length_m", 0.0, ge=0.0)
    max_torque = t.number("max_torque_nm", gt=0.0) if t.has("max_torque_nm") else None
    if not t.errs.clean_since(mark) or node_id is None or anchor is None:
        return None
    try:
        model = ReelModel(
            metres_per_rev=mpr,
            gear_ratio=gear,
            direction=direction,
            mechanical_advantage=ma,
            spool_buildup_m_per_rev2=buildup,
            reference_length_m=ref,
        )
    except (ValueError, ArithmeticError) as exc:
        t.fail_here(f"unusable reel model: {exc}")
        return None
    return ReelConfig(node_id=node_id, anchor_m=anchor, reel=model, max_torque_nm=max_torque)


def _check_reel_range(rc: ReelConfig, i: int, lim: LimitsConfig, source: str) -> None:
    """Reel must reach [min_cable, max_cable] and keep float32 resolution over the range."""
    key = f"reels[{i}]"
    m = rc.reel
    try:
        lo = m.position_rev(lim.min_cable_m)
        hi = m.position_rev(lim.max_cable_m)
        for p in (lo, hi):
            if not math.isfinite(p) or m.length_rate_mps(p, 1.0) * m.direction <= 0.0:
                raise ValueError("metres per turn fall to zero within the cable range")
    except ValueError as exc:
        raise ConfigError(
            source,
            key,
            f"cannot cover limits.min_cable_m..max_cable_m "
            f"({lim.min_cable_m:g}..{lim.max_cable_m:g} m): {exc}",
        ) from exc
    # Relative encoders start near 0 at power-up, so motor positions span at most the turns
    # between the shortest and the longest cable (either side of 0).
    span_rev = abs(hi - lo)
    if span_rev > 0.0:
        ulp_rev = 2.0 ** (math.floor(math.log2(span_rev)) - 23)
        metres_per_motor_rev = abs(lim.max_cable_m - lim.min_cable_m) / span_rev
        res_m = ulp_rev * metres_per_motor_rev
        if res_m > FLOAT32_RESOLUTION_LIMIT_M:
            raise ConfigError(
                source,
                key,
                f"float32 motor turns resolve only {res_m * 1e3:.3g} mm of cable over "
                f"{span_rev:.6g} turns (limit {FLOAT32_RESOLUTION_LIMIT_M * 1e3:g} mm): "
                "use fewer metres per motor turn or a shorter cable range",
            )


_TOP_KEYS = (
    "name",
    "reels",
    "bus",
    "loop",
    "limits",
    "faults",
    "homing",
    "zenoh",
    "sim",
    "payload",
    "drive",
)
_BUS_KEYS = ("interface", "channel", "bitrate", "options")


def _parse_loop(lt: _Table) -> LoopConfig:
    """The `[loop]` table (problems are recorded in the table's error list)."""
    lt.finish(tuple(LoopConfig.__dataclass_fields__))
    d_loop = LoopConfig()
    loop = LoopConfig(
        rate_hz=lt.number("rate_hz", d_loop.rate_hz, ge=1.0, le=2000.0),
        realtime=lt.boolean("realtime", d_loop.realtime),
        gc_freeze=lt.boolean("gc_freeze", d_loop.gc_freeze),
        publish_every=lt.integer("publish_every", d_loop.publish_every, ge=1, le=100_000),
        encoder_rtr=lt.boolean("encoder_rtr", d_loop.encoder_rtr),
        rt_priority=lt.integer("rt_priority", d_loop.rt_priority, ge=1, le=99),
        auto_arm=lt.boolean("auto_arm", False) if lt.has("auto_arm") else None,
        torque_telemetry=lt.string("torque_telemetry", d_loop.torque_telemetry) or "off",
        torque_rtr_period_s=lt.number(
            "torque_rtr_period_s", d_loop.torque_rtr_period_s, gt=0.0, le=10.0
        ),
    )
    if loop.torque_telemetry not in TORQUE_TELEMETRY:
        lt.fail(
            "torque_telemetry",
            f"must be one of {', '.join(TORQUE_TELEMETRY)}, got {loop.torque_telemetry!r}",
        )
    return loop


def _parse_sim(st: _Table, interface: str, loop: LoopConfig) -> SimConfig:
    """The `[sim]` table; its defaults depend on the bus interface and the loop rate."""
    st.finish(tuple(SimConfig.__dataclass_fields__))
    d_sim = SimConfig()
    period_s = 1.0 / loop.rate_hz
    sim = SimConfig(
        enabled=st.boolean("enabled", interface == "virtual"),
        encoder_period_s=st.number("encoder_period_s", d_sim.encoder_period_s, gt=0.0, le=1.0),
        heartbeat_period_s=st.number(
            "heartbeat_period_s", d_sim.heartbeat_period_s, gt=0.0, le=10.0
        ),
        max_velocity_rps=st.number("max_velocity_rps", d_sim.max_velocity_rps, gt=0.0),
        max_accel_rps2=st.number("max_accel_rps2", d_sim.max_accel_rps2, gt=0.0),
        tick_s=st.number("tick_s", d_sim.tick_s, gt=0.0, le=0.1),
        watchdog_timeout_s=st.number(
            "watchdog_timeout_s",
            max(d_sim.watchdog_timeout_s, WATCHDOG_DEFAULT_PERIODS * period_s),
            ge=0.0,
            le=10.0,
        ),
        plant=st.string("plant", d_sim.plant) or d_sim.plant,
        cable_ea_n=st.number("cable_ea_n", d_sim.cable_ea_n, gt=0.0),
        torque_period_s=st.number("torque_period_s", d_sim.torque_period_s, ge=0.0, le=10.0),
    )
    if sim.plant not in SIM_PLANTS:
        st.fail("plant", f"must be one of {', '.join(SIM_PLANTS)}, got {sim.plant!r}")
    wd = sim.watchdog_timeout_s
    if 0.0 < wd < WATCHDOG_MIN_PERIODS * period_s:
        st.fail(
            "watchdog_timeout_s",
            f"{wd:g} s is shorter than {WATCHDOG_MIN_PERIODS:g} loop periods "
            f"({WATCHDOG_MIN_PERIODS * period_s:g} s at {loop.rate_hz:g} Hz); 0 turns it off",
        )
    return sim


def _parse_faults(ft: _Table, loop: LoopConfig, sim: SimConfig) -> FaultConfig:
    """The `[faults]` table, checked against the loop rate and the simulated drives."""
    period_s = 1.0 / loop.rate_hz
    ft.finish(tuple(FaultConfig.__dataclass_fields__))
    d_f = FaultConfig()
    faults = FaultConfig(
        stale_timeout_s=ft.number("stale_timeout_s", d_f.stale_timeout_s, gt=0.0, le=10.0),
        heartbeat_timeout_s=ft.number(
            "heartbeat_timeout_s", d_f.heartbeat_timeout_s, gt=0.0, le=60.0
        ),
        residual_max_m=ft.number("residual_max_m", d_f.residual_max_m, gt=0.0),
        tracking_max_m=ft.number("tracking_max_m", d_f.tracking_max_m, gt=0.0),
        arm_timeout_s=ft.number("arm_timeout_s", d_f.arm_timeout_s, gt=0.0, le=60.0),
        bus_error_timeout_s=ft.number(
            "bus_error_timeout_s", d_f.bus_error_timeout_s, ge=0.0, le=10.0
        ),
        slack_tension_n=(
            ft.number("slack_tension_n", ge=0.0) if ft.has("slack_tension_n") else None
        ),
        slack_time_s=ft.number("slack_time_s", d_f.slack_time_s, ge=0.0, le=10.0),
    )
    if faults.stale_timeout_s < 2.0 * period_s:
        ft.fail(
            "stale_timeout_s",
            f"{faults.stale_timeout_s:g} s is shorter than two loop periods "
            f"({2.0 * period_s:g} s at {loop.rate_hz:g} Hz)",
        )
    if sim.enabled and faults.stale_timeout_s < 2.0 * sim.encoder_period_s:
        ft.fail(
            "stale_timeout_s",
            f"{faults.stale_timeout_s:g} s is shorter than two simulated encoder periods "
            f"(sim.encoder_period_s = {sim.encoder_period_s:g} s)",
        )
    if sim.enabled and faults.heartbeat_timeout_s < 2.0 * sim.heartbeat_period_s:
        ft.fail(
            "heartbeat_timeout_s",
            f"{faults.heartbeat_timeout_s:g} s is shorter than two simulated heartbeat periods "
            f"(sim.heartbeat_period_s = {sim.heartbeat_period_s:g} s)",
        )
    return faults


def parse_config(data: Mapping[str, Any], source: str) -> RobotConfig:
    """Validate an already-parsed TOML mapping and return the `RobotConfig`.

    `source` names the origin (file path) in error messages. Raises one ConfigError listing
    every problem found (each naming the key path): unknown keys, wrong types or units,
    out-of-range values, duplicate node ids, unusable anchor geometry, an unknown bus interface
    or interface option, a bad Zenoh endpoint or file, failed cross-checks.
    """
    errs = _Errors(source)
    if not isinstance(data, Mapping):
        raise ConfigError(source, "", f"must be a table, got {_tname(data)}")
    top = _Table(data, "", errs)
    top.finish(_TOP_KEYS)
    name = top.string("name", "default") or "default"
    if not _NAME_RE.match(name):
        top.fail("name", f"must match {_NAME_RE.pattern} (used in paths and keys), got {name!r}")
        name = "default"

    mark = errs.mark()
    drive, family = _parse_drive(top)
    drive_ok = errs.clean_since(mark)
    reels = _parse_reels(top, data, errs, family)
    geometry: Geometry | None = None
    if reels is not None:
        try:
            geometry = Geometry([r.anchor_m for r in reels])
        except SingularGeometryError as exc:
            errs.add("reels[*].anchor_m", f"singular anchors: {exc} (anchors numbered from 1)")
        except (KinematicsError, ArithmeticError, ValueError) as exc:
            errs.add("reels[*].anchor_m", str(exc))

    bus = _parse_bus(top)

    lt = top.sub("loop")
    loop = _parse_loop(lt)

    # ---- limits: no defaults in a file (a safe limit depends on the robot)
    mark = errs.mark()
    if top.has("limits"):
        limits = _parse_limits(top.sub("limits"))
    else:
        errs.add("limits", "missing (every robot needs its own [limits])")
        limits = LimitsConfig()  # a stand-in: the configuration is refused
    limits_ok = errs.clean_since(mark)
    if limits_ok and geometry is not None and reels is not None:
        g = geometry
        errs.check("limits", lambda: _check_limits(limits, g, source))
        for i, r in enumerate(reels):
            errs.check(f"reels[{i}]", functools.partial(_check_reel_range, r, i, limits, source))
    limits_ok = limits_ok and errs.clean_since(mark)

    st = top.sub("sim")
    sim = _parse_sim(st, bus.interface, loop)
    ft = top.sub("faults")
    faults = _parse_faults(ft, loop, sim)

    # ---- homing
    ht = top.sub("homing")
    ht.finish(tuple(HomingConfig.__dataclass_fields__))
    pup = ht.vec3("power_up_position_m", required=False)
    state_file = ht.string("state_file", None)
    if pup is not None and limits_ok and geometry is not None:
        p, g = pup, geometry
        errs.check(
            "homing.power_up_position_m",
            lambda: _raise_point_problem(ht, "power_up_position_m", p, limits, g),
        )
    if state_file is not None:
        try:
            state_file = os.path.expanduser(state_file.format(name=name))
        except (KeyError, IndexError, ValueError):
            ht.fail("state_file", f"only {{name}} may be substituted, got {state_file!r}")
    d_h = HomingConfig()
    pt = {
        key: ht.number(key, getattr(d_h, key), gt=0.0, le=le)
        for key, le in (
            ("pretension_still_mps", 1.0),
            ("pretension_settle_s", 60.0),
            ("pretension_timeout_s", 3600.0),
            ("pretension_max_travel_m", 1000.0),
            ("pretension_speed_mps", 10.0),
        )
    }
    homing = HomingConfig(pup, state_file, **pt)

    zenoh = _parse_zenoh(top, name)

    if family is not None:
        limits_used = limits if limits_ok else None
        _check_drive(top, drive, family, drive_ok, loop, faults, limits_used, reels)
        if drive_ok and reels:  # the bus must carry the tick's frames (drivers.busload)
            refusal = busload.for_config(drive, len(reels), loop, bus).refusal()
            if refusal is not None:
                errs.add("loop.rate_hz", refusal)
    payload, tension = _parse_statics(top, errs, limits, limits_ok, reels, geometry, pup)
    if loop.torque_telemetry != "off" and sim.enabled and sim.plant == "kinematic":
        lt.fail(
            "torque_telemetry",
            f'"{loop.torque_telemetry}" with the kinematic simulator (sim.enabled): it carries '
            'no load and reports no torque; use sim.plant = "physical"',
        )
    if faults.slack_tension_n is not None:
        if loop.torque_telemetry == "off":
            ft.fail("slack_tension_n", 'needs measured tensions: loop.torque_telemetry is "off"')
        if not top.has("payload"):
            ft.fail("slack_tension_n", "needs [payload] mass_kg (tension limits need a load)")
        elif tension is not None and not faults.slack_tension_n < tension.min_n:
            ft.fail(
                "slack_tension_n",
                f"{faults.slack_tension_n:g} N must be below limits.min_tension_n "
                f"({tension.min_n:g} N): every holding pose would be slack",
            )
    if sim.plant == "physical":
        if drive.kind != "odrive":
            st.fail(
                "plant",
                f'"physical" needs simulated ODrives (they report torques); drive.kind is '
                f"{drive.kind!r}",
            )
        if payload is None and not top.has("payload"):
            st.fail("plant", '"physical" needs [payload] mass_kg (what the cables carry)')
        if pup is None and not ht.has("power_up_position_m"):
            st.fail(
                "plant",
                '"physical" needs homing.power_up_position_m (where the simulated effector starts)',
            )

    errs.raise_if_any()
    assert reels is not None and geometry is not None  # no problems: both were built
    return RobotConfig(
        name=name,
        reels=reels,
        geometry=geometry,
        bus=bus,
        loop=loop,
        limits=limits,
        faults=faults,
        homing=homing,
        zenoh=zenoh,
        sim=sim,
        source=source,
        drive=drive,
        payload=payload,
        tension=tension,
    )


def _parse_limits(mt: _Table) -> LimitsConfig:
    mt.finish(tuple(LimitsConfig.__dataclass_fields__))
    max_speed = mt.number("max_speed_mps", required=True, gt=0.0)
    return LimitsConfig(
        xy_margin_m=mt.number("xy_margin_m", required=True, ge=0.0),
        floor_z_m=mt.number("floor_z_m", required=True),
        top_margin_m=mt.number("top_margin_m", required=True, ge=0.0),
        min_cable_m=mt.number("min_cable_m", required=True, gt=0.0),
        max_cable_m=mt.number("max_cable_m", required=True, gt=0.0),
        max_cable_speed_mps=mt.number("max_cable_speed_mps", required=True, gt=0.0),
        max_speed_mps=max_speed,
        max_accel_mps2=mt.number("max_accel_mps2", required=True, gt=0.0),
        default_speed_mps=mt.number("default_speed_mps", max_speed, gt=0.0),
        velocity_timeout_s=mt.number("velocity_timeout_s", 0.25, gt=0.0),
        min_tension_n=mt.number("min_tension_n", ge=0.0) if mt.has("min_tension_n") else None,
        max_tension_n=mt.number("max_tension_n", gt=0.0) if mt.has("max_tension_n") else None,
        tension_margin_n=mt.number("tension_margin_n", 0.0, ge=0.0),
    )


_TENSION_KEYS = ("min_tension_n", "max_tension_n", "tension_margin_n")


def _parse_statics(
    top: _Table,
    errs: _Errors,
    limits: LimitsConfig,
    limits_ok: bool,
    reels: tuple[ReelConfig, ...] | None,
    geometry: Geometry | None,
    power_up_m: Vec3 | None,
) -> tuple[PayloadConfig | None, TensionLimits | None]:
    """`[payload]` and the tension limits; (None, None) without `[payload]` (then no tension key
    may be set: it would do nothing). Cross-checks, when their inputs are clean: a usable
    tension range and a tension-feasible power-up pose."""
    if not top.has("payload"):
        lim_raw = top.raw("limits") if top.has("limits") else {}
        for k in _TENSION_KEYS:
            if isinstance(lim_raw, Mapping) and k in lim_raw:
                errs.add(f"limits.{k}", "needs [payload] mass_kg (tension limits need a load)")
        for i, r in enumerate(reels or ()):
            if r.max_torque_nm is not None:
                errs.add(
                    f"reels[{i}].max_torque_nm",
                    "needs [payload] mass_kg (tension limits need a load)",
                )
        return None, None
    pt = top.sub("payload")
    pt.finish(tuple(PayloadConfig.__dataclass_fields__))
    mark = errs.mark()
    mass = pt.number("mass_kg", required=True, gt=0.0)
    if limits_ok and limits.min_tension_n is None:
        errs.add("limits.min_tension_n", "missing (required with [payload])")
    if not (errs.clean_since(mark) and limits_ok and reels is not None and geometry is not None):
        return None, None
    payload = PayloadConfig(mass_kg=mass)
    max_n, max_source = math.inf, ""
    if limits.max_tension_n is not None:
        max_n, max_source = limits.max_tension_n, "limits.max_tension_n"
    for i, r in enumerate(reels):
        if r.max_torque_nm is None:
            continue
        try:
            t = r.reel.max_tension_n(r.max_torque_nm, limits.min_cable_m, limits.max_cable_m)
        except ValueError as exc:  # already reported by the reel range check
            errs.add(f"reels[{i}].max_torque_nm", f"no tension bound: {exc}")
            return None, None
        if t < max_n:
            max_n, max_source = t, f"reels[{i}].max_torque_nm"
    if not math.isfinite(max_n):
        errs.add(
            "limits.max_tension_n",
            "missing (required with [payload] unless every reel has max_torque_nm)",
        )
        return None, None
    if any(r.max_torque_nm is None for r in reels) and limits.max_tension_n is None:
        missing = ", ".join(f"reels[{i}]" for i, r in enumerate(reels) if r.max_torque_nm is None)
        errs.add(
            "limits.max_tension_n",
            f"missing (required with [payload] unless every reel has max_torque_nm; "
            f"{missing} has none)",
        )
        return None, None
    lo = limits.min_tension_n
    assert lo is not None
    margin = limits.tension_margin_n
    if not lo + margin < max_n - margin:
        errs.add(
            "limits.min_tension_n",
            f"{lo:g} N + tension_margin_n ({margin:g} N) leaves no tension range below the "
            f"maximum {max_n:.4g} N (from {max_source}) minus the margin",
        )
        return None, None
    tension = TensionLimits(min_n=lo, max_n=max_n, margin_n=margin, max_source=max_source)
    if power_up_m is not None:
        problem = tension_problem(geometry, payload, tension, power_up_m)
        if problem is not None:
            errs.add("homing.power_up_position_m", problem)
    return payload, tension


def tension_check(
    payload: PayloadConfig, tension: TensionLimits, geometry: Geometry
) -> TensionCheck:
    """The `controller.core.statics.TensionCheck` of this payload and these limits.

    Raises StaticsInputError only for values validation refuses."""
    return TensionCheck(
        geometry.anchors_m,
        payload.mass_kg,
        tension.min_n,
        tension.max_n,
        tension.margin_n,
        tension.max_source,
    )


def tension_problem(
    geometry: Geometry, payload: PayloadConfig, tension: TensionLimits, point_m: Vec3
) -> str | None:
    """Why the cables cannot hold `payload` at `point_m` within the tension limits and their
    margin, or None when they can. Raises nothing."""
    return tension_check(payload, tension, geometry).check(point_m)


def _parse_reels(
    top: _Table, data: Mapping[str, Any], errs: _Errors, family: registry.Family | None
) -> tuple[ReelConfig, ...] | None:
    """The [[reels]] array; None (problems recorded) unless every reel is usable."""
    if "reels" not in data:
        errs.add("reels", "missing (need at least 3 [[reels]] tables)")
        return None
    reels_raw = top.raw("reels")
    if not isinstance(reels_raw, list):
        errs.add("reels", f"must be an array of tables ([[reels]]), got {_tname(reels_raw)}")
        return None
    if len(reels_raw) < 3:
        errs.add("reels", f"need at least 3 reels, got {len(reels_raw)}")
    parsed = [_parse_reel(_Table(r, f"reels[{i}]", errs), family) for i, r in enumerate(reels_raw)]
    seen: dict[int, int] = {}
    for i, r in enumerate(parsed):
        if r is None:
            continue
        if r.node_id in seen:
            errs.add(
                f"reels[{i}].node_id",
                f"duplicate node id {r.node_id} (also reels[{seen[r.node_id]}])",
            )
        else:
            seen[r.node_id] = i
    good = [r for r in parsed if r is not None]
    if len(good) != len(parsed) or len(good) < 3 or len(seen) != len(good):
        return None
    return tuple(good)


def _parse_drive(top: _Table) -> tuple[DriveConfig, registry.Family | None]:
    """The [drive] table: the family named by `kind` and its options from the registry's
    table; the family is None (problem recorded) when `kind` names none."""
    t = top.sub("drive")
    kind = t.string("kind", registry.DEFAULT_KIND) or registry.DEFAULT_KIND
    family = registry.FAMILIES.get(kind)
    if family is None:
        t.fail("kind", registry.unknown_family_problem(kind))
        return DriveConfig(kind), None
    known = {"kind", *(o.name for o in family.options)}
    for k in t.data:
        if k in known:
            continue
        owners = sorted(
            f.name for f in registry.FAMILIES.values() if k in {o.name for o in f.options}
        )
        problem = _unknown(k, known)
        if owners:
            problem += f" ({k} is an option of [drive] kind = {owners[0]!r}, not {kind!r})"
        t.fail(k, problem)
    options: dict[str, Any] = {}
    for o in family.options:
        if not t.has(o.name) and not o.required and o.default is None:
            continue  # no value: the driver's own default applies
        if o.kind == "number":
            default = None if o.default is None else float(o.default)
            value: Any = t.number(o.name, default, gt=o.gt, ge=o.ge, le=o.le, required=o.required)
        elif o.kind == "bool":
            value = t.boolean(o.name, bool(o.default))
        else:
            text = t.string(o.name, None if o.default is None else str(o.default))
            if text is None:
                continue
            value = os.path.expanduser(text)
            if not Path(value).is_file():
                t.fail(o.name, f"no such file: {value}")
        options[o.name] = value
    return DriveConfig(kind, MappingProxyType(options)), family


def _check_drive(
    top: _Table,
    drive: DriveConfig,
    family: registry.Family,
    drive_ok: bool,
    loop: LoopConfig,
    faults: FaultConfig,
    limits: LimitsConfig | None,
    reels: Sequence[ReelConfig] | None,
) -> None:
    """Cross-checks of the drive family with the loop, faults and reels (see the module
    docstring); run only on values that are valid themselves (`drive_ok`: the [drive] table
    was)."""
    errs = top.errs
    opts = drive.options
    if loop.encoder_rtr and family.name != "odrive":
        errs.add(
            "loop.encoder_rtr",
            f"applies to ODrive drives only ([drive] kind = {family.name!r} drives send their "
            "positions every cycle)",
        )
    hb = opts.get("heartbeat_period_s")
    if drive_ok and isinstance(hb, float) and faults.heartbeat_timeout_s < 2.0 * hb:
        errs.add(
            "faults.heartbeat_timeout_s",
            f"{faults.heartbeat_timeout_s:g} s is shorter than two drive heartbeat periods "
            f"(drive.heartbeat_period_s = {hb:g} s)",
        )
    cpr = opts.get("counts_per_rev")
    if drive_ok and isinstance(cpr, float) and limits is not None and reels:
        for i, r in enumerate(reels):
            try:
                span_rev = abs(
                    r.reel.position_rev(limits.max_cable_m)
                    - r.reel.position_rev(limits.min_cable_m)
                )
            except (ValueError, ArithmeticError):
                continue  # reported by the reel range check
            if span_rev * cpr > 2**31 - 1:
                errs.add(
                    f"reels[{i}]",
                    f"{span_rev:.6g} motor turns over limits.min_cable_m..max_cable_m are "
                    f"{span_rev * cpr:.4g} position counts at drive.counts_per_rev = {cpr:g}: "
                    "beyond the drives' 32-bit position",
                )
    if drive_ok:
        for key, problem in family.check_options(opts, 1.0 / loop.rate_hz):
            errs.add(key, problem)


def _parse_bus(top: _Table) -> BusConfig:
    b = top.sub("bus")
    b.finish(_BUS_KEYS)
    interface = b.string("interface", "virtual") or "virtual"
    problem = _interface_problem(interface)
    if problem is not None:
        b.fail("interface", problem)
    channel_raw = b.raw("channel") if b.has("channel") else "cablebot"
    if isinstance(channel_raw, bool) or not isinstance(channel_raw, str | int) or channel_raw == "":
        b.fail("channel", f"must be a non-empty string or an integer, got {channel_raw!r}")
        channel_raw = "cablebot"
    bitrate: int | None = None
    if b.has("bitrate"):
        bitrate = b.integer("bitrate", ge=10_000, le=8_000_000)
    options: dict[str, Any] = {}
    if b.has("options"):
        opts = b.raw("options")
        if not isinstance(opts, Mapping):
            b.fail("options", f"must be a table, got {_tname(opts)}")
        else:
            options = dict(opts)
    for reserved in ("interface", "channel", "bitrate"):
        if reserved in options:
            b.fail(f"options.{reserved}", f"set it as bus.{reserved}, not in options")
            del options[reserved]
    if options and problem is None:
        allowed = bus_option_names(interface)
        if allowed is not None:
            for k in options:
                if k not in allowed:
                    b.fail(
                        f"options.{k}",
                        _unknown(k, set(allowed)).replace(
                            "unknown key", f"not an option of the {interface} interface"
                        )
                        + f" (it takes: {', '.join(sorted(allowed))})",
                    )
    return BusConfig(interface, str(channel_raw), bitrate, MappingProxyType(options))


def _interface_problem(interface: str) -> str | None:
    """Why `interface` is not a python-can interface name, or None if it is one."""
    import can

    valid = sorted(can.interfaces.VALID_INTERFACES)
    if interface in valid:
        return None
    close = difflib.get_close_matches(interface, valid, n=1, cutoff=0.6)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return f"unknown python-can interface {interface!r}{hint} (known: {', '.join(valid)})"


_GENERIC_BUS_OPTIONS = frozenset(
    {"timing", "fd", "data_bitrate", "state", "receive_own_messages", "can_filters"}
)
"""Keywords python-can's `can.Bus` understands for any interface (besides bit-timing fields)."""


def bus_option_names(interface: str) -> frozenset[str] | None:
    """The keyword options python-can's bus class for `interface` names in its constructor
    (plus python-can's generic ones: bit timing, fd, data_bitrate, state, can_filters), and
    `hop_limit` for udp_multicast. None if the interface's module cannot be imported here (a
    vendor library missing): its options cannot be checked. Raises nothing."""
    import importlib
    import inspect

    import can
    import can.typechecking

    entry = can.interfaces.BACKENDS.get(interface)
    if entry is None:
        return None
    module_name, class_name = entry
    try:
        cls = getattr(importlib.import_module(module_name), class_name)
        params = list(inspect.signature(cls.__init__).parameters.values())
        params += list(inspect.signature(can.BusABC.__init__).parameters.values())
    except Exception:  # a missing vendor library, an odd plugin: cannot tell
        return None
    named = {p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
    named.discard("self")
    named.discard("channel")
    named |= _GENERIC_BUS_OPTIONS
    named |= set(can.typechecking.BitTimingDict.__annotations__)
    named |= set(can.typechecking.BitTimingFdDict.__annotations__)
    if interface == "udp_multicast":
        named.add("hop_limit")
    return frozenset(named)


_PORT_PROTOCOLS = frozenset({"tcp", "udp", "tls", "quic", "ws"})


def _endpoint_problem(ep: str, *, listen: bool) -> str | None:
    """Why Zenoh endpoint `ep` is malformed (protocol/address; for tcp, udp, tls, quic and ws
    host:port with a port in 1..65535, or 0 = any free port for a listen endpoint)."""
    proto, sep, rest = ep.partition("/")
    if not sep or not proto or not rest:
        return f"endpoint {ep!r} must look like 'tcp/HOST:PORT'"
    if proto not in _PORT_PROTOCOLS:
        return None  # unixsock-stream/PATH, serial/..., vsock/...: Zenoh checks these
    address = rest.split("?", 1)[0].split("#", 1)[0]
    host, colon, port_text = address.rpartition(":")
    if not colon or not host:
        return f"endpoint {ep!r} must look like '{proto}/HOST:PORT'"
    lowest = 0 if listen else 1
    if not port_text.isdigit() or not lowest <= int(port_text) <= 65535:
        return f"endpoint {ep!r}: port must be {lowest}..65535, got {port_text!r}"
    return None


def _parse_zenoh(top: _Table, name: str) -> ZenohConfig:
    zt = top.sub("zenoh")
    zt.finish(tuple(ZenohConfig.__dataclass_fields__))
    prefix = zt.string("prefix", f"cablebot/{name}") or f"cablebot/{name}"
    if not _PREFIX_RE.match(prefix):
        zt.fail(
            "prefix",
            f"must be a plain key expression like 'cablebot/desk' (no wildcards), got {prefix!r}",
        )
    mode = zt.string("mode", "peer") or "peer"
    if mode not in _ZENOH_MODES:
        zt.fail("mode", f"must be one of {', '.join(_ZENOH_MODES)}, got {mode!r}")
    listen = zt.strings("listen", ("tcp/127.0.0.1:7447",))
    connect = zt.strings("connect", ())
    for k, eps in (("listen", listen), ("connect", connect)):
        for ep in eps:
            problem = _endpoint_problem(ep, listen=k == "listen")
            if problem is not None:
                zt.fail(k, problem)
    scouting = zt.boolean("multicast_scouting", False)
    zcfg = zt.string("config_file", None)
    if zcfg is not None:
        zcfg = os.path.expanduser(zcfg)
        if not Path(zcfg).is_file():
            zt.fail("config_file", f"no such file: {zcfg}")
        else:
            problem = _zenoh_file_problem(zcfg)
            if problem is not None:
                zt.fail("config_file", problem)
    return ZenohConfig(prefix, mode, listen, connect, scouting, zcfg)


def _zenoh_file_problem(path: str) -> str | None:
    """Why Zenoh cannot use the JSON5 configuration at `path` (unloadable, or a malformed
    listen/connect endpoint that it sets), or None if it can."""
    try:
        import zenoh
    except ImportError:  # pragma: no cover - zenoh is a dependency
        return None
    try:
        conf = zenoh.Config.from_file(path)
        defaults = zenoh.Config()
        problems = []
        for key in ("listen/endpoints", "connect/endpoints"):
            text = conf.get_json(key)
            if text == defaults.get_json(key):
                continue
            value = json.loads(text)
            groups = value.values() if isinstance(value, dict) else [value]
            for eps in groups:
                for ep in eps if isinstance(eps, list) else [eps]:
                    problem = _endpoint_problem(str(ep), listen=key.startswith("listen"))
                    if problem is not None:
                        problems.append(f"{key.split('/')[0]}: {problem}")
    except Exception as exc:  # zenoh.ZError, OSError, UnicodeDecodeError...
        return f"not a valid Zenoh configuration: {type(exc).__name__}: {exc}"
    return "; ".join(problems) if problems else None


def _check_limits(lim: LimitsConfig, geometry: Geometry, source: str) -> None:
    """Raise ConfigError (naming the `limits.` keys) if the limits leave no workspace or no
    cable range (`Workspace` decides), or the default speed exceeds the maximum."""
    problems: list[ConfigError] = []
    try:
        Workspace.from_limits(lim, geometry)
    except WorkspaceError as exc:
        problems.append(ConfigError(source, f"limits.{exc.limit}", exc.detail))
    if lim.default_speed_mps > lim.max_speed_mps:
        problems.append(
            ConfigError(
                source,
                "limits.default_speed_mps",
                f"{lim.default_speed_mps:g} m/s exceeds max_speed_mps ({lim.max_speed_mps:g} m/s)",
            )
        )
    if problems:
        raise ConfigError.collected(source, problems)


def _raise_point_problem(
    t: _Table, name: str, p: Vec3, lim: LimitsConfig, geometry: Geometry
) -> None:
    problem = _point_problem(p, Workspace.from_limits(lim, geometry))
    if problem is not None:
        raise t.error(name, problem)


def _point_problem(p: Vec3, workspace: Workspace) -> str | None:
    """Why `p` is not an allowed pose (the workspace decides), in the words of the
    configuration keys, or None."""
    v = workspace.target_violation(p)
    if v is None:
        return None
    x, y, z = p
    if v.limit == "xy_margin_m":
        return (
            f"({x:g}, {y:g}) m is outside the anchors' plan-view polygon shrunk by "
            f"limits.xy_margin_m ({v.bound:g} m)"
        )
    if v.limit == "floor_z_m":
        return f"z={z:g} m is below limits.floor_z_m ({v.bound:g} m)"
    if v.limit == "top_margin_m":
        return (
            f"z={z:g} m is above the anchor plane minus margin ({v.bound:g} m), "
            "the lowest anchor minus limits.top_margin_m"
        )
    if v.limit in ("min_cable_m", "max_cable_m"):
        return (
            f"cable {v.cable} would be {v.value:.4g} m, outside limits.min_cable_m..max_cable_m "
            f"({workspace.min_cable_m:g}..{workspace.max_cable_m:g} m)"
        )
    return v.reason


def load_config(path: str | os.PathLike[str] | None) -> RobotConfig:
    """Read and validate the TOML file at `path`; `None` returns `default_config()`.

    Raises ConfigError (naming the file) if the file cannot be read, is not valid TOML, or
    fails validation.
    """
    if path is None:
        return default_config()
    source = os.fspath(path)
    try:
        with open(source, "rb") as fh:
            raw = fh.read()
    except OSError as exc:
        raise ConfigError(source, "", f"cannot read: {exc.strerror or exc}") from exc
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        column = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        raise ConfigError(
            source,
            "",
            f"not UTF-8 text: byte 0x{raw[exc.start]:02x} at line {line}, column {column} "
            "(TOML files must be UTF-8)",
        ) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(source, "", f"not valid TOML: {exc}") from exc
    return parse_config(data, source)


PAPER_LENGTH_M = 80.9
PAPER_WIDTH_M = 50.0
PAPER_HEIGHT_M = 7.62


def paper_robot_data(name: str = "default") -> dict[str, Any]:
    """The paper robot as a TOML-shaped mapping (reels B1..B4, node ids 0..3, simulated).

    Reels: 0.5 m of cable per drum turn (80 mm drum radius) behind a 10:1 gearbox, i.e.
    0.05 m per motor turn; the 99 m cable range (1..100 m) is 1980 motor turns, where one
    float32 ULP is 2^-13 turn = 6.1 micrometres of cable (limit 0.1 mm). The gearing cancels
    out: the worst resolution is about range * 2^-23 (12 um for 99 m), so only cable ranges
    beyond ~800 m fail the check. Raises nothing.
    """
    hl, hw, h = PAPER_LENGTH_M / 2.0, PAPER_WIDTH_M / 2.0, PAPER_HEIGHT_M
    anchors = [(-hl, -hw, h), (-hl, hw, h), (hl, hw, h), (hl, -hw, h)]
    return {
        "name": name,
        "bus": {"interface": "virtual", "channel": f"cablebot-{name}"},
        "loop": {"rate_hz": 500.0},
        "limits": {
            "xy_margin_m": 2.0,
            "floor_z_m": 0.0,
            "top_margin_m": 1.0,
            "min_cable_m": 1.0,
            "max_cable_m": 100.0,
            "max_cable_speed_mps": 3.0,
            "max_speed_mps": 2.0,
            "max_accel_mps2": 1.0,
            "default_speed_mps": 1.0,
            "min_tension_n": 5.0,
            "max_tension_n": 500.0,
            "tension_margin_n": 5.0,
        },
        "payload": {"mass_kg": 5.0},
        # Its simulated drives share the CPU with everything else on the machine (a desktop, a
        # laptop running a build): a reading may wait a few hundred ms for a busy scheduler, and
        # a starved simulated reel lags its set-point. A real rig keeps the 50 ms / 0.5 s
        # defaults and a tracking limit near 0.25 m; the simulated robot must not fault on load.
        "faults": {
            "stale_timeout_s": 0.5,
            "heartbeat_timeout_s": 1.0,
            "residual_max_m": 0.02,
            "tracking_max_m": 1.0,
            "arm_timeout_s": 2.0,
            "bus_error_timeout_s": 0.05,
        },
        "homing": {"power_up_position_m": [0.0, 0.0, 2.0]},
        # The simulated drives' axis watchdog (idle when no command came for this long) gets the
        # same allowance for a busy machine as the staleness windows above.
        "sim": {"enabled": True, "watchdog_timeout_s": 1.0},
        "reels": [
            {
                "node_id": i,
                "anchor_m": list(a),
                "metres_per_rev": 0.5,
                "gear_ratio": 10.0,
            }
            for i, a in enumerate(anchors)
        ],
    }


def default_config() -> RobotConfig:
    """The built-in robot: the paper's acre robot on 4 simulated reels on a `virtual` bus.

    Name "default" (Zenoh prefix cablebot/default), power-up pose (0, 0, 2) m, no state file.
    Raises nothing (the data is valid by construction; a test checks it).
    """
    return parse_config(paper_robot_data("default"), "<built-in default>")
