"""Drive families by name: which driver and which simulated nodes a `[drive] kind` stands for.

Modelled on python-can's interface table: a small table of names, each pointing at
"module:callable" strings that are imported only when the family is used, so naming a family
costs nothing and a family whose library is missing fails only when it is chosen.

    fam = family("cia402")                     # UnknownFamilyError with a did-you-mean hint
    driver = fam.open_driver(bus, (1, 2, 3, 4), options, LoopSettings(period_s=0.002,
                                                                      stale_timeout_s=0.05))
    bank = fam.sim_bank(sim_bus, (1, 2, 3, 4), options, SimSettings((0.0,) * 4)).start()

Each `Family` declares:

* `node_id_min` / `node_id_max`: the node ids its bus addressing allows (ODrive CANSimple
  0..63, CANopen 1..127);
* `options`: the `[drive]` keys it takes besides `kind`, with type, default and range; the
  configuration (`controller.service.config`) validates them from this table alone, and
  passes the driver and simulator factories a mapping holding every option with a value;
* `driver`: ``(bus, node_ids, options, loop: LoopSettings) -> ReelDriver``;
* `sim`: ``(bus, node_ids, options, sim: SimSettings) -> SimBank`` (not started);
* `check` (optional): ``(options, period_s) -> [(key, problem), ...]``, checks that need the
  family's library (an EDS that must load, a loop period the drives must represent);
* `startup_note` (optional): ``(reading, armed) -> (logging level, message) | None``, what the
  daemon says about a drive's first heartbeat.

A driver that also has a `configure()` method (`drivers.base.ConfigurableDriver`, e.g. CiA 402:
SDO set-up of every drive) is configured by the daemon before its loop runs.
Only the standard library and `drivers.base` are imported here.
"""

from __future__ import annotations

import difflib
import importlib
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Literal, Protocol

from drivers.base import AxisReading, ReelDriver

if TYPE_CHECKING:
    import can

DEFAULT_KIND = "odrive"


class UnknownFamilyError(ValueError):
    """A drive family name that is not in the table; the message names the known ones."""


@dataclass(frozen=True, slots=True)
class Option:
    """One `[drive]` key of a family: its type, default and allowed range."""

    name: str
    kind: Literal["number", "bool", "path"]
    default: float | bool | str | None = None
    """The value when the key is absent; None = no value (the driver's own default applies)."""
    required: bool = False
    gt: float | None = None
    ge: float | None = None
    le: float | None = None
    doc: str = ""


@dataclass(frozen=True, slots=True)
class LoopSettings:
    """What the daemon tells any driver it opens about the loop that will drive it."""

    period_s: float
    """The control loop's period."""
    stale_timeout_s: float
    """`faults.stale_timeout_s`: readings older than this fault the loop."""
    encoder_rtr: bool = False
    """`loop.encoder_rtr`: ask for encoder readings instead of waiting for broadcasts (ODrive)."""
    torque_rtr: bool = False
    """`loop.torque_telemetry = "rtr"`: ask for the motors' torques (ODrive Get_Torques)."""
    torque_rtr_period_s: float = 0.01
    """`loop.torque_rtr_period_s`: how often (with `torque_rtr`)."""


@dataclass(frozen=True, slots=True)
class SimSettings:
    """The `[sim]` settings of simulated nodes; each family uses those that apply to it."""

    initial_positions_rev: tuple[float, ...]
    """Motor turns at power-up, one per node (node order)."""
    max_velocity_rps: float = 20.0
    max_accel_rps2: float = 200.0
    tick_s: float = 0.001
    encoder_period_s: float = 0.01
    """Encoder broadcast period (ODrive; CiA 402 drives answer every SYNC instead)."""
    heartbeat_period_s: float = 0.1
    """Heartbeat period (ODrive; a CiA 402 drive's is set by the driver at start-up)."""
    watchdog_timeout_s: float = 0.0
    """Axis watchdog (ODrive): idle after this long in closed loop without a command; 0 = off."""


class SimBank(Protocol):
    """Simulated nodes served on a bus by a background thread."""

    def start(self) -> Any:
        """Start serving (once); returns the bank."""
        ...

    def stop(self, timeout_s: float = 2.0) -> bool:
        """Stop serving; True if the thread has ended within `timeout_s`."""
        ...

    @property
    def thread(self) -> threading.Thread | None:
        """The serving thread once started (for its scheduling), else None."""
        ...

    def axis(self, node_id: int) -> Any:
        """The simulated node with this id (fault injection in tests). Raises KeyError."""
        ...


DriverFactory = Callable[["can.BusABC", Sequence[int], Mapping[str, Any], LoopSettings], ReelDriver]
SimFactory = Callable[["can.BusABC", Sequence[int], Mapping[str, Any], SimSettings], SimBank]
CheckFunction = Callable[[Mapping[str, Any], float], list[tuple[str, str]]]
NoteFunction = Callable[[AxisReading, bool], tuple[int, str] | None]


def _load(target: str) -> Any:
    module, _, attr = target.partition(":")
    return getattr(importlib.import_module(module), attr)


@dataclass(frozen=True, slots=True)
class Family:
    """One drive family (see the module docstring)."""

    name: str
    title: str
    """How people call its drives in messages, e.g. "ODrive" in "ODrive node 3"."""
    node_id_min: int
    node_id_max: int
    options: tuple[Option, ...]
    driver: str
    sim: str
    check: str | None = None
    startup_note: str | None = None

    def option(self, name: str) -> Option:
        """The option called `name`. Raises KeyError if the family has none."""
        for o in self.options:
            if o.name == name:
                return o
        raise KeyError(name)

    def open_driver(
        self,
        bus: can.BusABC,
        node_ids: Sequence[int],
        options: Mapping[str, Any],
        loop: LoopSettings,
    ) -> ReelDriver:
        """Create the family's driver on `bus` (nothing is sent yet). Raises ImportError if
        the family's library is missing, ValueError on bad node ids or options."""
        factory: DriverFactory = _load(self.driver)
        return factory(bus, node_ids, options, loop)

    def sim_bank(
        self,
        bus: can.BusABC,
        node_ids: Sequence[int],
        options: Mapping[str, Any],
        sim: SimSettings,
    ) -> SimBank:
        """Create (not start) simulated drives of this family for `node_ids` on `bus`. Raises
        ImportError if the family's library is missing, ValueError on bad ids or settings."""
        factory: SimFactory = _load(self.sim)
        return factory(bus, node_ids, options, sim)

    def check_options(self, options: Mapping[str, Any], period_s: float) -> list[tuple[str, str]]:
        """Problems (key path, what) the family's own checks find in valid-looking options at
        a loop period of `period_s`; empty if none (or the family has no such checks)."""
        if self.check is None:
            return []
        fn: CheckFunction = _load(self.check)
        return fn(options, period_s)

    def note_first_heartbeat(self, reading: AxisReading, armed: bool) -> tuple[int, str] | None:
        """What the daemon logs about a drive's first heartbeat ((level, message) or None);
        `armed`: cablebot has asked the drives to arm already."""
        if self.startup_note is None:
            return None
        fn: NoteFunction = _load(self.startup_note)
        return fn(reading, armed)


_ODRIVE_OPTIONS = (
    Option(
        "velocity_limit_rps",
        "number",
        gt=0.0,
        doc="the drives' configured vel_limit (rev/s): with both this and current_limit_a, "
        "cablebot lowers vel_limit during the pre-tension (Set_Limits sets both at once) and "
        "restores these after",
    ),
    Option(
        "current_limit_a",
        "number",
        gt=0.0,
        doc="the drives' configured current limit (A): with both this and velocity_limit_rps, "
        "cablebot lowers vel_limit during the pre-tension (Set_Limits sets both at once) and "
        "restores these after",
    ),
)

_CIA402_OPTIONS = (
    Option(
        "counts_per_rev",
        "number",
        required=True,
        gt=0.0,
        doc="position units (0x6064/0x607A) per motor turn: the encoder's increments per turn "
        "unless the drive scales them; every reel's cable range must fit the drives' 32-bit "
        "position",
    ),
    Option(
        "velocity_units_per_rps",
        "number",
        gt=0.0,
        doc="velocity offset (0x60B1) units per motor turn per second (default: counts_per_rev)",
    ),
    Option(
        "eds",
        "path",
        doc="the drives' EDS file (default: the one shipped with cablebot); it must load and "
        "hold every object the driver uses",
    ),
    Option(
        "velocity_offset",
        "bool",
        True,
        doc="send the velocity feed-forward as velocity offset (RPDO2)",
    ),
    Option("torque", "bool", True, doc="read torque actual (0x6077) in TPDO1"),
    Option(
        "heartbeat_period_s",
        "number",
        0.1,
        ge=0.001,
        le=65.535,
        doc="each drive's heartbeat producer time (0x1017)",
    ),
    Option(
        "sdo_timeout_s",
        "number",
        0.3,
        gt=0.0,
        le=10.0,
        doc="how long start-up waits for each SDO answer",
    ),
)

FAMILIES: Mapping[str, Family] = MappingProxyType(
    {
        "odrive": Family(
            name="odrive",
            title="ODrive",
            node_id_min=0,
            node_id_max=63,
            options=_ODRIVE_OPTIONS,
            driver="drivers.odrive.driver:open_driver",
            sim="drivers.odrive.sim:open_sim_bank",
            startup_note="drivers.odrive.driver:startup_note",
        ),
        "cia402": Family(
            name="cia402",
            title="CiA 402 drive",
            node_id_min=1,
            node_id_max=127,
            options=_CIA402_OPTIONS,
            driver="drivers.cia402.driver:open_driver",
            sim="drivers.cia402.sim:open_sim_bank",
            check="drivers.cia402.driver:check_options",
        ),
    }
)
"""Every drive family by its `[drive] kind` name."""


def unknown_family_problem(kind: str) -> str:
    """Why `kind` is not a drive family, with a did-you-mean hint and the known names."""
    known = sorted(FAMILIES)
    close = difflib.get_close_matches(kind, known, n=1, cutoff=0.6)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return f"unknown drive family {kind!r}{hint} (known: {', '.join(known)})"


def family(kind: str) -> Family:
    """The family called `kind`. Raises UnknownFamilyError naming the known ones."""
    fam = FAMILIES.get(kind)
    if fam is None:
        raise UnknownFamilyError(unknown_family_problem(kind))
    return fam
