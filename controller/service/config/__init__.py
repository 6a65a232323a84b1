"""Robot configuration: one TOML file per robot -> validated, frozen `RobotConfig`.

One module per concern: `schema` (every key: type, default, description; the dataclasses),
`tables` (typed getters that collect every problem), `parse` (validation), `load` (`load_config`),
`interfaces` (`[bus]` and `[zenoh]`), `robot` (the built-in robot), `reference` (writes the
configuration reference, `docs/configuration.md`, from the schema).

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

from controller.service.config.interfaces import bus_option_names
from controller.service.config.load import load_config, robot_description, robot_digest
from controller.service.config.parse import (
    parse_config,
    tension_check,
    tension_problem,
)
from controller.service.config.robot import (
    PAPER_HEIGHT_M,
    PAPER_LENGTH_M,
    PAPER_WIDTH_M,
    default_config,
    paper_robot_data,
)
from controller.service.config.schema import (
    FLOAT32_RESOLUTION_LIMIT_M,
    REEL_KEYS,
    SECTIONS,
    SIM_PLANTS,
    STRETCH_TENSIONS,
    TORQUE_TELEMETRY,
    WATCHDOG_DEFAULT_PERIODS,
    WATCHDOG_MIN_PERIODS,
    BusConfig,
    ConfigError,
    DriveConfig,
    FaultConfig,
    GcodeConfig,
    HomingConfig,
    Key,
    LimitsConfig,
    LoopConfig,
    PayloadConfig,
    ReelConfig,
    RobotConfig,
    Ros2Config,
    Section,
    ShaperConfig,
    SimConfig,
    TensionLimits,
    Vec3,
    ZenohConfig,
)

__all__ = [
    "FLOAT32_RESOLUTION_LIMIT_M",
    "PAPER_HEIGHT_M",
    "PAPER_LENGTH_M",
    "PAPER_WIDTH_M",
    "REEL_KEYS",
    "SECTIONS",
    "SIM_PLANTS",
    "STRETCH_TENSIONS",
    "TORQUE_TELEMETRY",
    "WATCHDOG_DEFAULT_PERIODS",
    "WATCHDOG_MIN_PERIODS",
    "BusConfig",
    "ConfigError",
    "DriveConfig",
    "FaultConfig",
    "GcodeConfig",
    "HomingConfig",
    "Key",
    "LimitsConfig",
    "LoopConfig",
    "PayloadConfig",
    "ReelConfig",
    "RobotConfig",
    "Ros2Config",
    "Section",
    "ShaperConfig",
    "SimConfig",
    "TensionLimits",
    "Vec3",
    "ZenohConfig",
    "bus_option_names",
    "default_config",
    "load_config",
    "paper_robot_data",
    "parse_config",
    "robot_description",
    "robot_digest",
    "tension_check",
    "tension_problem",
]
