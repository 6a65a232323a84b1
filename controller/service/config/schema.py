"""The configuration schema: every key of a robot file, its type, default and description.

Each section's keys are the fields of its frozen dataclass (`LoopConfig` for `[loop]`, ...),
declared with `key(default, description)` so that the type, the default and the one-line
description of a key sit on one line of code: the parser accepts exactly these fields (and
falls back to these defaults), and `controller.service.config.reference` writes the
configuration reference from them. The unit of a key is part of its name (`_m`, `_mps`, `_s`,
...). Sections without a dataclass of their own (the top level, `[[reels]]`) list their keys as
`Key` rows here; the `[drive]` options are the drive families' own table
(`drivers.registry.Option`).

Adding a key: one field (or `Key` row) here with its default and description, and the line of
the parser (`controller.service.config.parse`) that reads and range-checks it; then `make docs`
writes the reference (a test fails until it is current). Adding a section: its dataclass here,
a `Section` row in `SECTIONS` (the top level then accepts the table), a field of `RobotConfig`
and the parser's function for it.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, TypeVar

from controller.core.kinematics import Geometry
from controller.core.motion import DEFAULT_JUNCTION_DEVIATION_M, DEFAULT_MAX_QUEUED_POINTS
from controller.core.motion.shaper import (
    DEFAULT_DAMPING_RATIO,
    DEFAULT_SHAPER_TYPE,
    MAX_DAMPING_RATIO,
    MAX_PASSES,
    SHAPER_TYPES,
)
from controller.core.pretension import PretensionSettings
from controller.core.reel import ReelModel
from drivers import registry

Vec3 = tuple[float, float, float]
_T = TypeVar("_T")

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
STRETCH_TENSIONS = ("planned", "measured")


# ------------------------------------------------------------------------------- the schema
@dataclass(frozen=True, slots=True)
class Key:
    """One configuration key as the reference documents it.

    `default` is the value when the key is absent (None: unset, nothing applies);
    `shown` replaces the default in the reference when it is not a plain value ("required",
    "`max_speed_mps`"); `unit` replaces the unit read from the key's name (e.g. "m [x,y,z]").
    """

    name: str
    description: str
    default: Any = None
    shown: str | None = None
    unit: str | None = None


_KEY = "cablebot.key"
"""The dataclass field metadata entry that holds a field's `Key`."""


def key(
    default: _T,
    description: str,
    *,
    shown: str | None = None,
    unit: str | None = None,
) -> _T:
    """A dataclass field with `default` that is also a documented configuration key.

    Raises nothing."""
    meta = {_KEY: Key("", description, default, shown, unit)}
    return field(default=default, metadata=meta)


def section_keys(cls: type) -> tuple[Key, ...]:
    """The documented keys of a section dataclass, in field order (each named).

    Raises TypeError if a field of `cls` was declared without `key()` (it would be accepted
    but undocumented)."""
    out = []
    for f in dataclasses.fields(cls):
        k = f.metadata.get(_KEY)
        if not isinstance(k, Key):
            raise TypeError(f"{cls.__name__}.{f.name} is not declared with key()")
        out.append(dataclasses.replace(k, name=f.name))
    return tuple(out)


def key_names(keys: Sequence[Key]) -> tuple[str, ...]:
    """The names of `keys`, in order. Raises nothing."""
    return tuple(k.name for k in keys)


def defaults(keys: Sequence[Key]) -> Mapping[str, Any]:
    """Each key's default by name. Raises nothing."""
    return MappingProxyType({k.name: k.default for k in keys})


TOP_KEYS_DOC = (
    Key(
        "name",
        "robot name (`[A-Za-z0-9][A-Za-z0-9_.-]*`), used in the Zenoh prefix and `{name}`",
        "default",
    ),
)
"""The keys of the top level besides the sections."""

REEL_KEYS = (
    Key(
        "node_id",
        "the drive's CAN node id, unique: ODrive 0..63, CiA 402 (CANopen) 1..127",
        shown="required",
    ),
    Key("anchor_m", "pulley exit point", shown="required", unit="m [x,y,z]"),
    Key(
        "metres_per_rev",
        "cable per drum turn; give exactly one of `metres_per_rev` and `drum_radius_m`",
        shown="one of the two required",
        unit="m/drum turn",
    ),
    Key("drum_radius_m", "drum radius (2πr of cable per drum turn)", shown="one of the two"),
    Key("gear_ratio", "gearbox", 1.0, unit="motor turns/drum turn"),
    Key("direction", "+1: positive motor turns pay cable out; −1: wind it in", 1),
    Key("mechanical_advantage", "pulley-block ratio", 1.0),
    Key(
        "spool_buildup_m_per_rev2",
        "spool build-up (Hangprinter-style: the effective radius grows as cable winds on); "
        "or give `cable_diameter_m` and `turns_per_layer` instead",
        0.0,
        unit="m/turn²",
    ),
    Key("cable_diameter_m", "cable diameter, for the spool build-up", 0.0),
    Key("turns_per_layer", "drum turns per layer of cable, for the spool build-up", 1.0),
    Key(
        "spool_buildup_factor_m",
        "the spool build-up as RepRapFirmware's Hangprinter gives it (M666 Q in metres, times "
        "M666 O for several lines on one spool): the spool radius² falls by this × the cable "
        "paid out from the spool; another way to give `spool_buildup_m_per_rev2` (2π² × this)",
        shown="– (no build-up)",
        unit="m²/m",
    ),
    Key(
        "reference_length_m",
        "cable length at which `metres_per_rev` holds (matters with build-up)",
        0.0,
    ),
    Key(
        "max_torque_nm",
        "the motor's torque limit; the reel then bounds the cable tension to "
        "`max_torque_nm × 2π / (dL/drev)` at the steepest end of the cable range "
        "(needs `[payload]`)",
    ),
    Key(
        "cable_ea_n",
        "the cable's axial stiffness EA: the kinematics account for its stretch under the "
        "planned tensions (`docs/cable-stretch.md`; needs `[payload]`); absent = rigid",
        shown="– (rigid)",
    ),
    Key(
        "cable_mass_kg_per_m",
        "the cable's mass per metre: the statics and kinematics account for its sag "
        "(elastic catenary, `docs/cable-sag.md`; needs `[payload]`); absent = massless",
        shown="– (massless)",
        unit="kg/m",
    ),
)
"""The keys of one `[[reels]]` table (a reel's model is `controller.core.reel.ReelModel`)."""


def table_key(description: str, *, shown: str = "`{}`") -> Any:
    """A dataclass field holding a sub-table (an empty read-only mapping by default) that is
    also a documented configuration key. Raises nothing."""
    meta = {_KEY: Key("", description, None, shown, "–")}
    return field(default_factory=lambda: MappingProxyType({}), metadata=meta)


def required_key(description: str) -> Any:
    """A dataclass field without a default that is also a documented, required
    configuration key. Raises nothing."""
    return field(metadata={_KEY: Key("", description, None, "required")})


# ------------------------------------------------------------------------------- errors
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


# ------------------------------------------------------------------------------- sections
@dataclass(frozen=True, slots=True)
class ReelConfig:
    """One reel: its drive's CAN node id, the anchor (pulley exit point) and the reel model.

    Its keys in a file are `REEL_KEYS`."""

    node_id: int
    anchor_m: Vec3
    reel: ReelModel
    max_torque_nm: float | None = None
    """The motor's torque limit (N m); with it the reel bounds the cable tension (see
    `TensionLimits`). None = no bound from this reel."""
    cable_ea_n: float | None = None
    """The cable's axial stiffness EA (N): the kinematics account for its stretch under the
    planned tensions (`controller.core.stretch`; needs `[payload]`). None = rigid."""
    cable_mass_kg_per_m: float | None = None
    """The cable's mass per metre (kg/m): the statics and kinematics account for its sag
    (`controller.core.sag`; needs `[payload]`). None = massless."""


@dataclass(frozen=True, slots=True)
class BusConfig:
    """The python-can bus: interface, channel, bitrate (None = leave as is), extra options."""

    interface: str = key(
        "virtual",
        "python-can interface (`socketcan`, `udp_multicast`, `virtual`, `pcan`, ...; checked "
        "against python-can's list)",
    )
    channel: str = key("cablebot", "interface channel (`can0`, multicast group, ...)")
    bitrate: int | None = key(
        None,
        "passed only to interfaces that set it themselves (not socketcan/virtual/udp_multicast)",
        unit="bit/s",
    )
    options: Mapping[str, Any] = table_key(
        "`[bus.options]`: further python-can keywords, passed through (e.g. `port = 43113`, "
        "`hop_limit = 0`); each must be a keyword of the interface's bus class or python-can's "
        "generic ones (bit timing, `fd`, `data_bitrate`, `can_filters`); not checked when the "
        "interface's vendor library is missing"
    )

    def as_mapping(self) -> dict[str, Any]:
        """The mapping `drivers.bus.open_bus` accepts (interface, channel, bitrate, options)."""
        out: dict[str, Any] = {"interface": self.interface, "channel": self.channel}
        if self.bitrate is not None:
            out["bitrate"] = self.bitrate
        out.update(self.options)
        return out


BUS_OPTION_KEYS_DOC = (
    Key(
        "options.hop_limit",
        "multicast TTL; 0 keeps frames on this host (see [udp_multicast stays on this "
        "host](#udp_multicast-stays-on-this-host))",
        shown="0 (udp_multicast)",
    ),
)
"""`[bus.options]` keys cablebot itself gives a meaning to (the others are python-can's)."""


@dataclass(frozen=True, slots=True)
class LoopConfig:
    """The control loop: rate, real-time scheduling, GC freeze, publish decimation, RTR polling."""

    rate_hz: float = key(500.0, "control loop rate, 1..2000")
    realtime: bool = key(True, "try SCHED_FIFO for the loop thread")
    gc_freeze: bool = key(True, "freeze the garbage collector after start-up")
    publish_every: int = key(1, "publish the pose every N ticks", unit="ticks")
    encoder_rtr: bool = key(
        False, "poll encoders with RTR frames instead of relying on broadcasts (ODrive only)"
    )
    rt_priority: int = key(50, "SCHED_FIFO priority of the loop thread when `realtime`, 1..99")
    auto_arm: bool | None = key(
        None,
        "arm at start-up; unset = only when the reels are simulated in-process (`sim.enabled`)",
    )
    torque_telemetry: str = key(
        "off",
        'measured cable tensions from the motors\' torques: "off", "cyclic" (the ODrives '
        'broadcast Get_Torques: set their `torques_msg_rate_ms`) or "rtr" (asked every '
        "`torque_rtr_period_s`); not with the kinematic simulator (in the daemon, or "
        "`cablebot sim` on a simulated bus)",
    )
    torque_rtr_period_s: float = key(
        0.01,
        'with `torque_telemetry = "rtr"`: how often every axis is asked for its torques '
        "(2 frames per axis each time: mind the bus load)",
    )
    stretch_tensions: str = key(
        "planned",
        'the tensions the cable stretch is computed with (reels with `cable_ea_n`): "planned" '
        '(statics at the pose) or "measured" (torque telemetry; needs it on)',
    )


_IN_A_FILE = "required"
"""How the reference shows a `[limits]` default that a file must give anyway."""


@dataclass(frozen=True, slots=True)
class LimitsConfig:
    """Workspace, cable and motion limits (checked on command arrival and every tick).

    In a file every key but `default_speed_mps`, `velocity_timeout_s`, the path keys
    (`junction_deviation_m`, `max_queued_points`) and the tension keys is
    required (a safe limit depends on the robot); the defaults here are stand-ins."""

    xy_margin_m: float = key(
        2.0,
        "keep this far inside the anchors' plan-view polygon (among the anchors: inside the "
        "anchors' hull, measured across the plan view at every height)",
        shown=_IN_A_FILE,
    )
    floor_z_m: float = key(
        0.0,
        "lowest allowed z; at or above the lowest anchor minus `top_margin_m` the effector "
        "works among the anchors (a Hangprinter: see [Hangprinters](hangprinter.md))",
        shown=_IN_A_FILE,
    )
    top_margin_m: float = key(
        1.0,
        "highest z = lowest anchor z minus this (among the anchors: highest anchor z minus this)",
        shown=_IN_A_FILE,
    )
    ceiling_z_m: float | None = key(None, "highest allowed z, when lower than the anchors allow")
    print_radius_m: float | None = key(
        None,
        "keep within this plan-view radius of the origin (RepRapFirmware's M669 P)",
    )
    min_cable_m: float = key(
        1.0, "shortest allowed cable (every cable, every tick)", shown=_IN_A_FILE
    )
    max_cable_m: float = key(
        100.0, "longest allowed cable (every cable, every tick)", shown=_IN_A_FILE
    )
    max_cable_speed_mps: float = key(3.0, "per-cable speed limit", shown=_IN_A_FILE)
    max_speed_mps: float = key(2.0, "effector speed limit for all motion", shown=_IN_A_FILE)
    max_accel_mps2: float = key(1.0, "effector acceleration limit for all motion", shown=_IN_A_FILE)
    default_speed_mps: float = key(
        1.0, "speed of a move/path that gives none", shown="`max_speed_mps`"
    )
    velocity_timeout_s: float = key(
        0.25,
        "dead-man of velocity input: no `<prefix>/velocity` sample for this long brakes to a hold",
    )
    junction_deviation_m: float = key(
        DEFAULT_JUNCTION_DEVIATION_M,
        "how far a path's rounded corner may pass from its point (Grbl's junction deviation: "
        "larger is a faster corner; see [motion](motion.md))",
    )
    max_queued_points: int = key(
        DEFAULT_MAX_QUEUED_POINTS,
        "most path points queued ahead of the effector (a path and its appends); an append "
        "beyond it is refused with the queue's depth (the client retries); 1000 (one path "
        "command) to 10000000",
    )
    min_tension_n: float | None = key(
        None,
        "least tension any cable may carry (taut)",
        shown="– (required with `[payload]`)",
    )
    max_tension_n: float | None = key(
        None,
        "most tension any cable may carry; the smaller of this and the reels' torque limits "
        "(`max_torque_nm`) wins",
        shown="– (required with `[payload]` unless every reel has `max_torque_nm`)",
    )
    tension_margin_n: float = key(
        0.0,
        "every tension of a command or set-point stays this far inside "
        "`min_tension_n..max_tension_n` (e.g. mass × max acceleration)",
    )


@dataclass(frozen=True, slots=True)
class PayloadConfig:
    """What the cables carry: the effector and its tool, as one point mass."""

    mass_kg: float = required_key(
        "effector + tool, a point mass; the power-up pose must hold it within the tension "
        "limits and margin (see [statics](statics-and-calibration.md#statics))"
    )


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

    stale_timeout_s: float = key(0.05, "fault if an encoder reading is older (≥ 2 loop periods)")
    heartbeat_timeout_s: float = key(
        0.5,
        "fault if a drive's heartbeat is older (≥ 2 `drive.heartbeat_period_s` for CiA 402)",
    )
    residual_max_m: float = key(
        0.02, "fault if the FPK residual (cable inconsistency) exceeds this"
    )
    tracking_max_m: float = key(
        0.25,
        "fault if measured pose and set-point differ by more (plus the set-point's speed times "
        "the age of the oldest encoder reading: the pose is where the effector was then)",
    )
    arm_timeout_s: float = key(2.0, "time allowed for every axis to reach closed loop")
    bus_error_timeout_s: float = key(
        0.05,
        "fault when bus errors (failed sends, CAN error frames) go on this long; 0 = at the first",
    )
    slack_tension_n: float | None = key(
        None,
        "fault `slack` when a measured tension stays below this for `slack_time_s` (needs "
        "torque telemetry, `[payload]`, and a value below `min_tension_n`); unset = no slack "
        "fault",
    )
    slack_time_s: float = key(
        0.1,
        "how long a measured tension may stay below `slack_tension_n` or above the tension "
        "maximum (`over_tension`) before the loop faults",
    )


@dataclass(frozen=True, slots=True)
class HomingConfig:
    """Pose at power-up (None = operator must `home`) and the offsets state file (None = none).

    `state_file` is stored expanded (``~`` and ``{name}`` replaced).
    """

    power_up_position_m: Vec3 | None = key(  # noqa: RUF009 (a tuple: immutable)
        None, "pose of the effector at power-up (unset: run `home`)", unit="m [x,y,z]"
    )
    state_file: str | None = key(
        None,
        "where offsets are saved atomically and reloaded; `~` and `{name}` expanded; unset = "
        "not saved. Offsets stay valid only while the ODrives keep power.",
        unit="path",
    )
    pretension_still_mps: float = key(
        0.001, "`cablebot home --pretension`: a cable slower than this counts as still"
    )
    pretension_settle_s: float = key(
        2.0,
        "every cable still this long: the home pose is declared; longer than half the "
        "effector's slowest swing (on long flat cables a vertical bounce barely changes their "
        "lengths, so a short window takes a turning point for stillness)",
    )
    pretension_timeout_s: float = key(
        30.0, "fault `pretension: not still after ...` if the reels are not still by then"
    )
    pretension_max_travel_m: float = key(
        0.5, "fault `pretension: cable N moved ...` when a cable's length changes by more"
    )
    pretension_speed_mps: float = key(
        0.05,
        "the drives' velocity limit in torque control, as cable speed (where the family can "
        "set it: ODrive with `[drive] velocity_limit_rps` and `current_limit_a`)",
    )

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

    prefix: str = key(
        "cablebot/default",
        "key-expression prefix of this robot (no wildcards)",
        shown="`cablebot/{name}`",
    )
    mode: str = key("peer", "`peer`, `client` or `router`")
    listen: tuple[str, ...] = key(
        ("tcp/127.0.0.1:7447",),
        "endpoints to listen on (`tcp/HOST:PORT`, port 0..65535, 0 = any free port)",
    )
    connect: tuple[str, ...] = key((), "endpoints to connect to (port 1..65535)")
    multicast_scouting: bool = key(False, "Zenoh multicast scouting")
    config_file: str | None = key(
        None,
        "Zenoh JSON5 configuration (TLS, access control); `~` expanded; must exist and load, "
        "with valid endpoints",
        unit="path",
    )


@dataclass(frozen=True, slots=True)
class SimConfig:
    """Simulated drives of the `[drive]` family (started in-process by the daemon when
    `enabled`, or by `cablebot sim`); the broadcast periods and the watchdog are ODrive's."""

    enabled: bool = key(
        False,
        "start simulated drives of the `[drive]` family in the daemon's process",
        shown="true on `virtual`, else false",
    )
    encoder_period_s: float = key(
        0.002, "simulated encoder broadcast period (ODrive; CiA 402 drives answer every SYNC)"
    )
    heartbeat_period_s: float = key(0.1, "simulated heartbeat period (ODrive)")
    max_velocity_rps: float = key(100.0, "simulated motor velocity limit")
    max_accel_rps2: float = key(400.0, "simulated motor acceleration limit")
    tick_s: float = key(0.001, "time step of the simulated axes' dynamics")
    watchdog_timeout_s: float = key(
        0.3,
        "simulated ODrive axis watchdog (axis.config.watchdog_timeout): IDLE with "
        "`WATCHDOG_TIMER_EXPIRED` after this long in closed loop without a command; 0 = off, "
        "else ≥ 3 loop periods",
        shown="0.3 (≥ 5 loop periods)",
    )
    plant: str = key(
        "kinematic",
        '"kinematic": the reels move, nothing hangs on them (exact, no parameters); '
        '"physical": one elastic-cable plant carries the payload and each axis reports its '
        "holding torque by Get_Torques (`controller.core.plant.ReelPlant`; ODrive drives only; "
        "needs `[payload]` and `homing.power_up_position_m`); `home --pretension` and torque "
        "telemetry need it, for drives simulated in the daemon or by `cablebot sim` on a "
        "virtual or udp_multicast bus",
    )
    cable_ea_n: float = key(1.0e6, "axial stiffness EA of every simulated cable (physical plant)")
    cable_mass_kg_per_m: float | None = key(
        None,
        "mass per metre of every simulated cable (physical plant: heavy cables hang in "
        "catenaries); absent = each reel's `cable_mass_kg_per_m` (massless without it)",
        shown="the reels'",
        unit="kg/m",
    )
    cable_damping_ratio: float = key(
        0.02,
        "damping ratio of the simulated ropes (physical plant): every mode their stretch "
        "stiffens rings down at it; real rope 0.005–0.05, 1 = critical (see "
        "[shaping](shaping.md#the-simulator))",
    )
    effector_damping_n_s_per_m: float | None = key(
        None,
        "drag on the simulated effector (physical plant); unset = a light drag of "
        "0.1 s⁻¹ × `[payload] mass_kg`",
        shown="0.1 × mass_kg",
    )
    torque_period_s: float = key(
        0.01,
        "Get_Torques broadcast period of each simulated axis (physical plant); 0 = by RTR only",
    )


def kinematic_sim(sim: SimConfig, bus_interface: str) -> bool:
    """True when the reels are cablebot's simulated drives with the kinematic plant, so nothing
    hangs on them (no load, no torque): the daemon runs them (`[sim] enabled`), or the bus is
    one only simulated drives speak (virtual, udp_multicast: `cablebot sim` runs them from the
    robot file's `[sim]`). The one rule for what needs a load (pre-tension, torque telemetry)."""
    from drivers.busload import SIMULATED_INTERFACES

    simulated = sim.enabled or bus_interface in SIMULATED_INTERFACES
    return simulated and sim.plant == "kinematic"


@dataclass(frozen=True, slots=True)
class DriveConfig:
    """The reels' drive family (a `drivers.registry` name) and its `[drive]` options: every
    option of the family that has a value (given, or its default)."""

    kind: str = key(
        registry.DEFAULT_KIND,
        '"odrive" (CANSimple) or "cia402" (CANopen servo drives, CSP)',
    )
    options: Mapping[str, Any] = table_key(
        "the family's options, the other keys of `[drive]` (`drivers.registry`)"
    )


@dataclass(frozen=True, slots=True)
class Ros2Config:
    """`[ros2]`: take part in a ROS 2 graph over the daemon's Zenoh session (rmw_zenoh)."""

    enabled: bool = key(
        False,
        "publish the pose, cables and state as ROS 2 topics and take goal poses and twists "
        "(`docs/ros2.md`)",
    )
    domain_id: int = key(0, "ROS 2 domain id, 0..232 (the first part of every key expression)")
    namespace: str = key(
        "/cablebot", "absolute ROS namespace of the node and its topics (`/` for none)"
    )
    node_name: str = key("cablebot", "ROS node name (letters, digits, `_`)")
    frame_id: str = key(
        "world", "the robot's world frame: stamped on published poses, required of goal poses"
    )


GCODE_UNITS = ("mm", "inch")
GCODE_DIALECTS = ("marlin", "reprapfirmware")


@dataclass(frozen=True, slots=True)
class GcodeConfig:
    """`[gcode]`: where G-code coordinates are in the robot frame, and how they read
    (`cablebot gcode`, `docs/gcode.md`)."""

    origin_m: Vec3 = key(  # noqa: RUF009 (a tuple: immutable)
        (0.0, 0.0, 0.0), "robot-frame point of G-code X0 Y0 Z0", unit="m [x,y,z]"
    )
    units: str = key("mm", "G-code length unit at the start of a job: `mm` or `inch`")
    home_m: Vec3 | None = key(  # noqa: RUF009 (a tuple: immutable)
        None, "where `G28` goes (unset: the G-code origin)", unit="m [x,y,z]"
    )
    arc_tolerance_m: float = key(
        0.0001, "largest distance of a `G2`/`G3` arc's chords from the arc, > 0"
    )
    rapid_speed_mps: float | None = key(
        None, "speed of a `G0` without F (unset: `limits.max_speed_mps`)", shown="`max_speed_mps`"
    )
    dialect: str = key(
        "marlin", "`marlin` or `reprapfirmware`: the unit of `M203` (mm/s or mm/min)"
    )


@dataclass(frozen=True, slots=True)
class ShaperConfig:
    """`[shaper]`: input shaping of every set-point against the effector's modes
    (`controller.core.motion.shaper`, [shaping](shaping.md))."""

    type: str = key(
        DEFAULT_SHAPER_TYPE,
        f"`{'`, `'.join(SHAPER_TYPES)}`: the impulse train of each mode (`off`: no shaping)",
        shown=f"`{DEFAULT_SHAPER_TYPE}` where the modes are known, else `off`",
    )
    damping_ratio: float = key(
        DEFAULT_DAMPING_RATIO,
        f"the modes' damping ratio the trains are designed for, 0..{MAX_DAMPING_RATIO:g} "
        "(`cablebot resonance` measures it)",
    )
    frequency_hz: float | None = key(
        None,
        "shape one mode of this frequency everywhere; unset = the model's three modes at the "
        "set-point (needs every reel's `cable_ea_n` and `[payload]`), following the pose",
        shown="– (the model's)",
    )
    frequency_scale: float = key(
        1.0,
        "the model's frequencies are multiplied by this measured correction (`cablebot "
        "resonance` prints it), 0.2..5",
    )
    passes: int = key(
        1,
        f"each mode's train applied this many times in a row, 1..{MAX_PASSES}: 2 for a robot "
        "whose model may be well off (a cable EA not measured), for twice the delay",
    )

    @property
    def enabled(self) -> bool:
        """True unless the type is "off"."""
        return self.type != "off"


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
    ros2: Ros2Config = field(default_factory=lambda: Ros2Config())
    gcode: GcodeConfig = field(default_factory=lambda: GcodeConfig())
    shaper: ShaperConfig = field(default_factory=lambda: ShaperConfig(type="off"))
    text: str = field(default="", compare=False, repr=False)
    """The robot file's TOML text as loaded (for a robot built from a mapping, its TOML text):
    what the daemon serves as its robot description on `<prefix>/robot`."""

    @property
    def node_ids(self) -> tuple[int, ...]:
        """Node ids in reel (= cable) order."""
        return tuple(r.node_id for r in self.reels)

    @property
    def anchors_m(self) -> tuple[Vec3, ...]:
        """Anchors in reel (= cable) order."""
        return tuple(r.anchor_m for r in self.reels)

    @property
    def kinematic_sim(self) -> bool:
        """True when the reels are the kinematic simulator's: nothing hangs on them
        (`kinematic_sim`)."""
        return kinematic_sim(self.sim, self.bus.interface)

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
                    "cable_ea_n": r.cable_ea_n,
                    "cable_mass_kg_per_m": r.cable_mass_kg_per_m,
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
            "shaper": _fields(self.shaper),
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


@dataclass(frozen=True, slots=True)
class Section:
    """One table of a robot file: its name ("" for the top level), what the reference says of
    it as a whole, and its keys."""

    name: str
    note: str
    keys: tuple[Key, ...]


SECTIONS = (
    Section("", "", TOP_KEYS_DOC),
    Section("bus", "", section_keys(BusConfig) + BUS_OPTION_KEYS_DOC),
    Section("loop", "", section_keys(LoopConfig)),
    Section(
        "limits",
        "required; all keys but `default_speed_mps`, `velocity_timeout_s`, `junction_deviation_m`, "
        "`max_queued_points` and the tension keys",
        section_keys(LimitsConfig),
    ),
    Section(
        "payload", "optional: without it no statics, geometry only", section_keys(PayloadConfig)
    ),
    Section("faults", "", section_keys(FaultConfig)),
    Section("homing", "", section_keys(HomingConfig)),
    Section("zenoh", "", section_keys(ZenohConfig)),
    Section(
        "drive",
        "the reels' drive family and its options (`drivers.registry`)",
        tuple(k for k in section_keys(DriveConfig) if k.name != "options"),
    ),
    Section("sim", "", section_keys(SimConfig)),
    Section("ros2", "optional: the robot as a ROS 2 node over Zenoh", section_keys(Ros2Config)),
    Section("gcode", "optional: G-code jobs (`cablebot gcode`)", section_keys(GcodeConfig)),
    Section(
        "shaper",
        "optional: input shaping against the effector's modes ([shaping](shaping.md))",
        section_keys(ShaperConfig),
    ),
    Section("reels", "≥ 3, in cable order: the first is cable 1", REEL_KEYS),
)
"""Every table of a robot file, in the order the reference shows them; the `[drive]` family
options are `drivers.registry.FAMILIES`' own."""

TOP_KEYS = (*key_names(TOP_KEYS_DOC), *(s.name for s in SECTIONS if s.name))
"""The keys of the top level of a file (`name` and the sections)."""
