"""A RepRapFirmware Hangprinter configuration (`config.g`) read into what it says about the robot.

Pure: text in, a `HangprinterConfig` out, no I/O. The lines are read with the G-code line
parser (`controller.core.gcode`) and applied in order, as RepRapFirmware runs them at start-up:

* `M669 K6` makes the machine a Hangprinter; `N` the number of anchors (3 to 8); the anchors
  `A B C D I J L O` (RepRapFirmware 3.7's letters; 3.6 holds five, A B C D I), each
  `X:Y:Z` in millimetres, the last one on top; `P` the print radius.
* `M666` the spools and lines, one value per anchor where RepRapFirmware takes one: `Q` the
  build-up factor, `R` the spool radii at the origin, `U` the mechanical advantages, `O` the
  lines per spool, `L`/`H` the motor and spool gear teeth, `J` full steps per motor turn; the
  flex parameters `W` mover mass, `S` spring constant per unit length, `I`/`X` least and most
  planned force, `Y` guy wire lengths, `A` anchor mode, `F` flex algorithm (3.7).
* `M208` the Z limits; `M584` the drivers of the anchors' motors (axes X Y Z U V W A B in
  anchor order); `M569` their directions; `M201`/`M203` the X, Y, Z accelerations and speeds;
  `M550` the machine's name.

Numbers are read as RepRapFirmware reads them: the float parameters of these commands may
carry an exponent (`M666 S2e4` is 20000, `written_out`), which G-code jobs never do.

Everything else is kept as `Unmapped` with the reason. A value the configuration does not set
is RepRapFirmware's default (`RRF_DEFAULTS`) and says so (`Where.default`).

Problems that make the configuration unusable (a line that cannot be read, a kinematics other
than K6, an anchor or array count RepRapFirmware would refuse, a value out of range, a missing
anchor) are all collected and raised together as one `RrfError`, each naming its line.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from decimal import Decimal
from typing import Final, Generic, TypeVar

from controller.core.gcode import ChecksumError, Command, GcodeError, ParamValue, parse_line

T = TypeVar("T")
Vec3 = tuple[float, float, float]
DriverId = tuple[int, int]
"""A RepRapFirmware driver: (CAN board address, driver on it); board 0 is the main board."""

ANCHOR_LETTERS: Final = "ABCDIJLO"
"""The M669 letters of anchors 1..8 (RepRapFirmware 3.7; 3.6 holds five: A B C D I)."""
MOTOR_AXES: Final = "XYZUVWAB"
"""The axis letters of the anchors' motors in M584, in anchor order."""
MIN_ANCHORS: Final = 3
MAX_ANCHORS: Final = 8
DEFAULT_ANCHORS: Final = 4

_MAX_ANCHOR_MM: Final = 1e6
_MAX_RADIUS_MM: Final = 1e4
_MAX_WHOLE: Final = 100_000
_MAX_FORCE_N: Final = 1e9


@dataclass(frozen=True, slots=True)
class RrfDefaults:
    """RepRapFirmware's Hangprinter defaults (`HangprinterKinematics::Init`, 3.6), used where a
    configuration leaves a value unset."""

    print_radius_mm: float = 1500.0
    anchor_mode: int = 1
    buildup_factor_mm: float = 0.007
    spool_radius_mm: float = 75.0
    mechanical_advantage: tuple[int, ...] = (2, 2, 2, 2, 4, 2, 2, 2)
    lines_per_spool: int = 1
    motor_gear_teeth: int = 20
    spool_gear_teeth: int = 255
    full_steps_per_rev: int = 25
    mover_mass_kg: float = 0.0
    spring_k_per_unit_length_n: float = 20000.0
    min_force_n: float = 0.0
    max_force_n: float = 70.0
    guy_wire_mm: float = -1.0
    """Negative: derived from the anchors in the last-on-top mode (`HangprinterConfig`)."""


RRF_DEFAULTS: Final = RrfDefaults()


@dataclass(frozen=True, slots=True)
class Where:
    """Where a value came from: line `line_no` of input `source`, or RepRapFirmware's default
    (`source` empty)."""

    source: str = ""
    line_no: int = 0

    @property
    def default(self) -> bool:
        """True when the value is RepRapFirmware's default (no line set it)."""
        return not self.source

    def __str__(self) -> str:
        if not self.source:
            return "RepRapFirmware's default"
        return f"{self.source}:{self.line_no}" if self.line_no else self.source


DEFAULT: Final = Where()


@dataclass(frozen=True, slots=True)
class Value(Generic[T]):
    """A value and where it came from; `text` is how the line wrote it (e.g. ``Q0.128``)."""

    value: T
    where: Where = DEFAULT
    text: str = ""


@dataclass(frozen=True, slots=True)
class Unmapped:
    """A command or parameter of the configuration that says nothing cablebot uses."""

    where: Where
    what: str
    reason: str

    def __str__(self) -> str:
        return f"{self.where} {self.what}: {self.reason}"


@dataclass(frozen=True, slots=True)
class RrfProblem:
    """Why a line makes the configuration unusable; `text` is the line as written."""

    where: Where
    reason: str
    text: str = ""

    def __str__(self) -> str:
        text = _clip(self.text)
        shown = f" ({text!r})" if text and text not in self.reason else ""
        return f"{self.where}: {self.reason}{shown}"


class RrfError(ValueError):
    """A configuration that cannot be imported; `problems` names every line at fault, one per
    line of the message."""

    def __init__(self, problems: Sequence[RrfProblem]) -> None:
        self.problems = tuple(problems)
        super().__init__("\n".join(str(p) for p in self.problems))


@dataclass(frozen=True, slots=True)
class HangprinterConfig:
    """What a Hangprinter configuration says about the robot, per anchor in anchor order.

    Lengths in millimetres and forces in newtons, as RepRapFirmware has them; `directions`
    +1 (forwards, M569 S1, the default) or -1 (backwards, S0)."""

    anchors_mm: tuple[Value[Vec3], ...]
    print_radius_mm: Value[float]
    anchor_mode: Value[int]
    buildup_factor_mm: Value[float]
    spool_radius_mm: tuple[Value[float], ...]
    mechanical_advantage: tuple[Value[int], ...]
    lines_per_spool: tuple[Value[int], ...]
    motor_gear_teeth: tuple[Value[int], ...]
    spool_gear_teeth: tuple[Value[int], ...]
    full_steps_per_rev: tuple[Value[int], ...]
    mover_mass_kg: Value[float]
    spring_k_per_unit_length_n: Value[float]
    min_force_n: tuple[Value[float], ...]
    max_force_n: tuple[Value[float], ...]
    guy_wire_mm: tuple[Value[float], ...]
    flex_algorithm: Value[int | None]
    z_min_mm: Value[float | None]
    z_max_mm: Value[float | None]
    max_feedrate_mm_per_min: Value[float | None]
    """The least of M203's X, Y and Z (None: not set)."""
    max_accel_mm_per_s2: Value[float | None]
    """The least of M201's X, Y and Z (None: not set)."""
    drivers: tuple[Value[DriverId | None], ...]
    """The M584 driver of each anchor's motor (``40.0``: CAN board 40, driver 0); None: not set."""
    directions: tuple[Value[int], ...]
    machine_name: Value[str | None]
    unmapped: tuple[Unmapped, ...] = field(default=())

    @property
    def n(self) -> int:
        """The number of anchors."""
        return len(self.anchors_mm)

    @property
    def letters(self) -> str:
        """The anchors' M669 letters, in order."""
        return ANCHOR_LETTERS[: self.n]

    @property
    def flex_on(self) -> bool:
        """Whether RepRapFirmware compensates line flex: a mover mass above 0.1 g (3.6), unless
        M666 F0 turns it off (3.7 also needs F1 or F2; a configuration for 3.7 sets F)."""
        if self.flex_algorithm.value == 0:
            return False
        return self.mover_mass_kg.value > 0.0001


def _clip(text: str, n: int = 60) -> str:
    text = "".join(c if c.isprintable() else " " for c in text).strip()
    return text if len(text) <= n else text[: n - 3] + "..."


def format_param(letter: str, value: ParamValue) -> str:
    """A parameter word as a line would write it (``A0:-1610.98:-131.53``, ``P"name"``).
    Raises nothing."""
    if value is None:
        return letter
    if isinstance(value, str):
        return f'{letter}"{_clip(value, 40)}"'
    if isinstance(value, tuple):
        return letter + ":".join(f"{v:g}" for v in value)
    return f"{letter}{value:g}"


def format_command(cmd: Command, letters: Sequence[str] | None = None) -> str:
    """`cmd` written back (its code and the parameters `letters`, all when None)."""
    keys = list(cmd.params) if letters is None else [k for k in letters if k in cmd.params]
    return " ".join([cmd.code or "(axis words)"] + [format_param(k, cmd.params[k]) for k in keys])


_DRIVER_RE: Final = re.compile(r"([A-Za-z])[ \t]*(\d+(?:\.\d+)?(?::\d+(?:\.\d+)?)*)")


def driver_words(text: str) -> dict[str, tuple[DriverId, ...]]:
    """The driver ids of each parameter of an M584 or M569 line, as written: ``40.0`` is CAN
    board 40's driver 0, ``1`` the main board's driver 1 (as numbers ``1`` and ``1.0`` are
    the same, so they are read from the text). Raises nothing."""
    out: dict[str, tuple[DriverId, ...]] = {}
    for letter, value in _DRIVER_RE.findall(text.split(";", 1)[0]):
        ids: list[DriverId] = []
        for part in value.split(":"):
            board, dot, driver = part.partition(".")
            ids.append((int(board), int(driver)) if dot else (0, int(board)))
        out.setdefault(letter.upper(), tuple(ids))
    return out


def format_driver(d: DriverId) -> str:
    """A driver id as RepRapFirmware writes it (``40.0``, or ``1`` on the main board)."""
    return f"{d[0]}.{d[1]}" if d[0] else f"{d[1]}"


# ------------------------------------------------------------------------------ the reasons
_NOT_MOTION = "not a motion setting (cablebot moves the effector only: no heaters, tools, fans)"
_REASONS: Final[dict[str, str]] = {
    "G4": "a pause: nothing to configure",
    "G10": _NOT_MOTION,
    "G20": "G-code units: a job sets its own ([gcode] units, mm by default)",
    "G21": "G-code units: a job sets its own ([gcode] units, mm by default)",
    "G28": "homing moves: cablebot homes by declaring the pose (`cablebot home`)",
    "G29": "bed compensation: cablebot has none",
    "G31": "probe offsets: cablebot has no probe",
    "G90": "G-code modes: each job sets its own",
    "G91": "G-code modes: each job sets its own",
    "G92": "set position: cablebot homes by declaring the pose (`cablebot home`)",
    "M82": "extruder mode: cablebot has no extruder",
    "M83": "extruder mode: cablebot has no extruder",
    "M84": "motors off: the daemon's disarm does that",
    "M92": "steps per mm: RepRapFirmware derives the anchors' from M666; the drives report turns",
    "M98": "runs another file: give that file to import-rrf too, after this one",
    "M106": _NOT_MOTION,
    "M107": _NOT_MOTION,
    "M140": _NOT_MOTION,
    "M141": _NOT_MOTION,
    "M143": _NOT_MOTION,
    "M150": _NOT_MOTION,
    "M204": "print and travel accelerations: cablebot plans every move at limits.max_accel_mps2",
    "M207": _NOT_MOTION,
    "M221": _NOT_MOTION,
    "M280": _NOT_MOTION,
    "M307": _NOT_MOTION,
    "M308": _NOT_MOTION,
    "M350": "microstepping: the drives report motor turns, not steps",
    "M376": "bed compensation: cablebot has none",
    "M404": _NOT_MOTION,
    "M500": "stores the settings: give config-override.g to import-rrf too, after this file",
    "M501": "loads config-override.g: give it to import-rrf too, after this file",
    "M540": "network settings: not the robot's",
    "M551": "network settings: not the robot's",
    "M552": "network settings: not the robot's",
    "M553": "network settings: not the robot's",
    "M554": "network settings: not the robot's",
    "M555": "firmware compatibility: cablebot reads RepRapFirmware G-code by [gcode] dialect",
    "M557": "bed compensation: cablebot has none",
    "M558": "probe: cablebot has none",
    "M563": _NOT_MOTION,
    "M564": "axis limits off/on: cablebot always refuses a move outside its limits",
    "M566": "instantaneous speed changes: cablebot rounds corners by limits.junction_deviation_m",
    "M570": _NOT_MOTION,
    "M574": "endstops: a Hangprinter has none; cablebot homes by declaring the pose",
    "M575": "serial ports: `cablebot gcode --serial` serves a printer host",
    "M586": "network settings: not the robot's",
    "M587": "network settings: not the robot's",
    "M589": "network settings: not the robot's",
    "M591": _NOT_MOTION,
    "M593": "input shaping: not part of the imported robot file",
    "M671": "bed levelling: cablebot has none",
    "M900": _NOT_MOTION,
    "M906": "motor currents: the drives' own settings",
    "M911": "power failure handling: the drives' and the daemon's own",
    "M912": _NOT_MOTION,
    "M913": "motor currents: the drives' own settings",
    "M915": "stall detection: the drives' own settings",
    "M917": "motor currents: the drives' own settings",
    "M950": _NOT_MOTION,
    "M955": "accelerometer: `cablebot` measures resonance its own way",
}
_OTHER_REASON = "not a setting of the robot file"
_T_REASON = _NOT_MOTION


def _reason(cmd: Command) -> str:
    if cmd.letter == "T":
        return _T_REASON
    return _REASONS.get(cmd.code, _OTHER_REASON)


_FLOAT_LINE_RE: Final = re.compile(r"\s*(?:[Nn]-?\d+\s*)?[Mm]0*(?:666|669|208|201|203)(?![\d.])")
"""A line of a command whose numbers RepRapFirmware reads as floats, exponents included."""
_EXPONENT_RE: Final = re.compile(r"(?<=[A-Za-z:])([+-]?(?:\d+\.?\d*|\.\d+))[eE]([+-]?\d+)")
_MAX_EXPONENT: Final = 30
_CHECKSUM_RE: Final = re.compile(r"\*\s*\d+\s*$")


def written_out(text: str) -> str:
    """`text` with every number that has an exponent (``S2e4``) written out in full
    (``S20000``), as RepRapFirmware reads the float parameters of M666, M669, M208, M201 and
    M203 (`_FLOAT_LINE_RE`); the G-code
    line parser reads no exponents and would take ``S2e4`` for ``S2`` and ``E4``. Quoted
    strings and comments are left alone, and so is an exponent beyond ±30 (no length or
    force of a robot: the parser's own reading of it is then refused by range). A line's
    checksum, checked on the line as written, is dropped from a line written out. Raises
    nothing."""
    code, sep, comment = text.partition(";")
    parts = code.split('"')

    def full(m: re.Match[str]) -> str:
        exponent = int(m.group(2))
        if abs(exponent) > _MAX_EXPONENT:
            return m.group(0)
        return format(Decimal(m.group(1)) * Decimal(10) ** exponent, "f")

    parts[::2] = [_EXPONENT_RE.sub(full, p) for p in parts[::2]]  # outside quotes
    new = '"'.join(parts)
    if new == code:
        return text
    # A checksum was checked on the line as written; the written-out line has none.
    return _CHECKSUM_RE.sub("", new) + sep + comment


def _check_checksum(text: str, line_no: int) -> None:
    """Raise ChecksumError when the line as written has a checksum that does not match it
    (whatever else it holds that the G-code parser cannot read)."""
    try:
        parse_line(text, line_no)
    except ChecksumError:
        raise
    except GcodeError:
        pass


# ------------------------------------------------------------------------------ the reader
class _Reader:
    """Applies lines in order; collects problems and unmapped items."""

    def __init__(self) -> None:
        d = RRF_DEFAULTS
        self.sources: list[str] = []
        self.problems: list[RrfProblem] = []
        self.unmapped: list[Unmapped] = []
        self.kinematics: Value[int] | None = None
        self.n: Value[int] = Value(DEFAULT_ANCHORS)
        self.anchors: list[Value[Vec3] | None] = [None] * MAX_ANCHORS
        self.print_radius: Value[float] = Value(d.print_radius_mm)
        self.anchor_mode: Value[int] = Value(d.anchor_mode)
        self.q: Value[float] = Value(d.buildup_factor_mm)
        self.arrays: dict[str, list[Value[float]]] = {
            "R": [Value(d.spool_radius_mm)] * MAX_ANCHORS,
            "U": [Value(float(u)) for u in d.mechanical_advantage],
            "O": [Value(float(d.lines_per_spool))] * MAX_ANCHORS,
            "L": [Value(float(d.motor_gear_teeth))] * MAX_ANCHORS,
            "H": [Value(float(d.spool_gear_teeth))] * MAX_ANCHORS,
            "J": [Value(float(d.full_steps_per_rev))] * MAX_ANCHORS,
            "I": [Value(d.min_force_n)] * MAX_ANCHORS,
            "X": [Value(d.max_force_n)] * MAX_ANCHORS,
            "Y": [Value(d.guy_wire_mm)] * MAX_ANCHORS,
        }
        self.w: Value[float] = Value(d.mover_mass_kg)
        self.s: Value[float] = Value(d.spring_k_per_unit_length_n)
        self.flex: Value[int | None] = Value(None)
        self.z_min: Value[float | None] = Value(None)
        self.z_max: Value[float | None] = Value(None)
        self.feedrate: dict[str, Value[float]] = {}
        self.accel: dict[str, Value[float]] = {}
        self.axis_drivers: dict[str, Value[DriverId]] = {}
        self.driver_dirs: dict[DriverId, Value[int]] = {}
        self.name: Value[str | None] = Value(None)
        self._where = DEFAULT
        self._text = ""

    # -- recording
    def problem(self, reason: str) -> None:
        self.problems.append(RrfProblem(self._where, reason, self._text))

    def skip(self, what: str, reason: str) -> None:
        self.unmapped.append(Unmapped(self._where, what, reason))

    def skip_params(self, cmd: Command, letters: Sequence[str], reason: str) -> None:
        if letters:
            self.skip(format_command(cmd, letters), reason)

    # -- values
    def number(
        self, cmd: Command, k: str, lo: float, hi: float, *, lo_open: bool = False
    ) -> float | None:
        v = cmd.params[k]
        if not isinstance(v, float):
            got = "no value" if v is None else f"got {format_param(k, v)}"
            self.problem(f"{cmd.code} {k}: needs one number, {got}")
            return None
        if not (v > lo if lo_open else v >= lo) or v > hi:
            low = f"> {lo:g}" if lo_open else f">= {lo:g}"
            self.problem(f"{cmd.code} {k}{v:g}: must be {low} and <= {hi:g}")
            return None
        return v

    def whole(self, cmd: Command, k: str, lo: int, hi: int) -> int | None:
        v = self.number(cmd, k, lo, hi)
        if v is None:
            return None
        if v != int(v):
            self.problem(f"{cmd.code} {k}{v:g}: must be a whole number")
            return None
        return int(v)

    def array(
        self, cmd: Command, k: str, lo: float, hi: float, *, whole: bool, lo_open: bool = False
    ) -> tuple[float, ...] | None:
        """One value per anchor, as RepRapFirmware requires (exactly N of them)."""
        v = cmd.params[k]
        n = self.n.value
        values = (v,) if isinstance(v, float) else v
        if not isinstance(values, tuple):
            got = "no value" if v is None else f"got {format_param(k, v)}"
            self.problem(f"{cmd.code} {k}: needs {n} numbers (one per anchor), {got}")
            return None
        if len(values) != n:
            self.problem(
                f"{cmd.code} {k}: {len(values)} value{'s' * (len(values) != 1)}, "
                f"RepRapFirmware expects {n} (one per anchor, N{n})"
            )
            return None
        for x in values:
            bad = not (x > lo if lo_open else x >= lo) or x > hi or (whole and x != int(x))
            if bad:
                low = f"> {lo:g}" if lo_open else f">= {lo:g}"
                kind = "whole numbers " if whole else ""
                self.problem(
                    f"{cmd.code} {format_param(k, v)}: every value must be {kind}{low} "
                    f"and <= {hi:g}"
                )
                return None
        return values

    # -- lines
    def line(self, source: str, line_no: int, text: str) -> None:
        self._where = Where(source, line_no)
        self._text = text
        try:
            read = written_out(text) if _FLOAT_LINE_RE.match(text) else text
            if read != text:
                _check_checksum(text, line_no)  # of the line as written
            parsed = parse_line(read, line_no)
        except GcodeError as exc:
            self.problem(f"cannot read the line: {exc.reason}")
            return
        for cmd in parsed.commands:
            handler = _HANDLERS.get(cmd.code)
            if handler is not None:
                handler(self, cmd)
            else:
                self.skip(format_command(cmd), _reason(cmd))

    def hangprinter(self, cmd: Command) -> bool:
        """Whether M669 K6 is in force; names the problem when it is not."""
        if self.kinematics is not None and self.kinematics.value == 6:
            return True
        self.problem(
            f"{cmd.code} before M669 K6: RepRapFirmware applies it to the kinematics then in "
            "force, and M669 K6 starts from its defaults: put it after M669 K6"
        )
        return False

    def m669(self, cmd: Command) -> None:
        if cmd.has("K"):
            k = self.whole(cmd, "K", 0, 1000)
            if k is None:
                return
            if k != 6:
                self.problem(
                    f"M669 K{k}: not a Hangprinter (K6): import-rrf reads Hangprinter "
                    "configurations only"
                )
                return
            self.kinematics = Value(6, self._where, "K6")
        geometry = [k for k in cmd.params if k in ANCHOR_LETTERS or k in "NP"]
        if geometry and not self.hangprinter(cmd):
            return
        if cmd.has("N"):
            n = self.whole(cmd, "N", MIN_ANCHORS, MAX_ANCHORS)
            if n is not None:
                self.n = Value(n, self._where, f"N{n}")
        for i, letter in enumerate(ANCHOR_LETTERS):
            if not cmd.has(letter):
                continue
            v = cmd.params[letter]
            n = self.n.value
            if i >= n:
                self.problem(
                    f"M669 {letter}: anchor {i + 1}, but N is {n} (RepRapFirmware reads "
                    f"{' '.join(ANCHOR_LETTERS[:n])} only): add N{i + 1}"
                )
            elif not (isinstance(v, tuple) and len(v) == 3):
                self.problem(
                    f"M669 {letter}: an anchor is X:Y:Z in mm, got {format_param(letter, v)}"
                )
            elif any(abs(x) > _MAX_ANCHOR_MM for x in v):
                self.problem(f"M669 {format_param(letter, v)}: beyond {_MAX_ANCHOR_MM:g} mm")
            else:
                xyz = (v[0] + 0.0, v[1] + 0.0, v[2] + 0.0)
                self.anchors[i] = Value(xyz, self._where, format_param(letter, v))
        if cmd.has("P"):
            p = self.number(cmd, "P", 0.0, _MAX_ANCHOR_MM, lo_open=True)
            if p is not None:
                self.print_radius = Value(p, self._where, f"P{p:g}")
        self.skip_params(
            cmd,
            [k for k in cmd.params if k in "ST"],
            "segmentation: cablebot computes the cables every tick, no segments",
        )
        self.skip_params(
            cmd,
            [k for k in cmd.params if k not in ANCHOR_LETTERS + "KNPST"],
            "not a Hangprinter parameter",
        )

    def m666(self, cmd: Command) -> None:
        if not self.hangprinter(cmd):
            return
        if cmd.has("A"):
            a = self.whole(cmd, "A", 0, 2)
            if a is not None:
                self.anchor_mode = Value(a, self._where, f"A{a}")
        if cmd.has("Q"):
            q = self.number(cmd, "Q", 0.0, 1000.0)
            if q is not None:
                self.q = Value(q, self._where, f"Q{q:g}")
        limits: dict[str, tuple[float, float, bool, bool]] = {
            # letter: (low, high, whole numbers, low bound open)
            "R": (0.0, _MAX_RADIUS_MM, False, True),
            "U": (1.0, 1000.0, True, False),
            "O": (1.0, 1000.0, True, False),
            "L": (1.0, _MAX_WHOLE, True, False),
            "H": (1.0, _MAX_WHOLE, True, False),
            "J": (1.0, _MAX_WHOLE, True, False),
            "I": (0.0, _MAX_FORCE_N, False, False),
            "X": (0.0, _MAX_FORCE_N, False, True),
            "Y": (-_MAX_ANCHOR_MM, _MAX_ANCHOR_MM, False, False),
        }
        for k, (lo, hi, whole, lo_open) in limits.items():
            if not cmd.has(k):
                continue
            values = self.array(cmd, k, lo, hi, whole=whole, lo_open=lo_open)
            if values is not None:
                text = format_param(k, cmd.params[k])
                for i, x in enumerate(values):
                    self.arrays[k][i] = Value(x, self._where, text)
        if cmd.has("W"):
            w = self.number(cmd, "W", 0.0, 1e4)
            if w is not None:
                self.w = Value(w, self._where, f"W{w:g}")
        if cmd.has("S"):
            s = self.number(cmd, "S", 0.0, 1e12, lo_open=True)
            if s is not None:
                self.s = Value(s, self._where, f"S{s:g}")
        if cmd.has("F"):
            f = self.whole(cmd, "F", 0, 2)
            if f is not None:
                self.flex = Value(f, self._where, f"F{f}")
        self.skip_params(
            cmd,
            [k for k in cmd.params if k == "T"],
            "target force: cablebot plans the tensions farthest from limits.min_tension_n and "
            "max_tension_n (raise min_tension_n to keep the lines tighter)",
        )
        self.skip_params(
            cmd,
            [k for k in cmd.params if k == "C"],
            "torque constants: the ODrives report torque in N m themselves",
        )
        self.skip_params(
            cmd,
            [k for k in cmd.params if k in "BP"],
            "flex planning options of RepRapFirmware 3.7: cablebot's statics has its own rule",
        )
        self.skip_params(
            cmd,
            [k for k in cmd.params if k not in "AQRUOLHJIXYWSFTCBP"],
            "not a Hangprinter parameter",
        )

    def m208(self, cmd: Command) -> None:
        s = 0
        if cmd.has("S"):
            sv = self.whole(cmd, "S", 0, 1)
            if sv is None:
                return
            s = sv
        if cmd.has("Z"):
            v = cmd.params["Z"]
            if isinstance(v, tuple) and len(v) == 2:
                if not v[0] < v[1]:
                    self.problem(
                        f"M208 {format_param('Z', v)}: the minimum is not below the maximum"
                    )
                else:
                    text = format_param("Z", v)
                    self.z_min = Value(v[0], self._where, text)
                    self.z_max = Value(v[1], self._where, text)
            elif isinstance(v, float):
                text = f"S{s} Z{v:g}" if cmd.has("S") else f"Z{v:g}"
                if s == 1:
                    self.z_min = Value(v, self._where, text)
                else:
                    self.z_max = Value(v, self._where, text)
            else:
                self.problem(f"M208 Z: needs a number or min:max in mm, got {format_param('Z', v)}")
        self.skip_params(
            cmd,
            [k for k in cmd.params if k not in "SZ"],
            "RepRapFirmware limits a Hangprinter's X and Y by the print radius (M669 P) only",
        )

    def m584(self, cmd: Command) -> None:
        written = driver_words(self._text)
        for k in cmd.params:
            if k not in MOTOR_AXES:
                continue
            v = cmd.params[k]
            ids = written.get(k)
            if not isinstance(v, float | tuple) or not ids:
                self.problem(f"M584 {format_param(k, v)}: not a driver number")
                continue
            text = f"{k}{':'.join(format_driver(d) for d in ids)}"
            self.axis_drivers[k] = Value(ids[0], self._where, text)
            if len(ids) > 1:
                self.skip(
                    f"M584 {text}",
                    "several drivers on one axis: a reel has one drive (the first is used)",
                )
        self.skip_params(
            cmd,
            [k for k in cmd.params if k not in MOTOR_AXES],
            "not an anchor's motor (axes X Y Z U V W A B drive the anchors, in order)",
        )

    def m569(self, cmd: Command) -> None:
        if not (cmd.has("P") and cmd.has("S")):
            self.skip(format_command(cmd), "no direction (P and S) to map")
            return
        ids = driver_words(self._text).get("P")
        if not isinstance(cmd.params["P"], float) or not ids:
            self.problem(f"M569 {format_param('P', cmd.params['P'])}: not a driver number")
            return
        s = self.whole(cmd, "S", 0, 1)
        if s is None:
            return
        text = f"P{format_driver(ids[0])} S{s}"
        self.driver_dirs[ids[0]] = Value(1 if s == 1 else -1, self._where, text)
        self.skip_params(
            cmd,
            [k for k in cmd.params if k not in "PS"],
            "driver settings: the drives' own",
        )

    def speeds(self, cmd: Command, into: dict[str, Value[float]]) -> None:
        for k in "XYZ":
            if cmd.has(k):
                v = self.number(cmd, k, 0.0, 1e9, lo_open=True)
                if v is not None:
                    into[k] = Value(v, self._where, f"{k}{v:g}")
        self.skip_params(
            cmd,
            [k for k in cmd.params if k not in "XYZ"],
            "not the effector's X, Y or Z",
        )

    def m201(self, cmd: Command) -> None:
        self.speeds(cmd, self.accel)

    def m203(self, cmd: Command) -> None:
        self.speeds(cmd, self.feedrate)

    def m550(self, cmd: Command) -> None:
        v = cmd.params.get("P")
        if isinstance(v, str) and v.strip():
            self.name = Value(v.strip(), self._where, format_param("P", v))
        else:
            self.skip(format_command(cmd), 'no machine name (P"name") to map')

    # -- the end
    def _order(self, u: Unmapped) -> tuple[int, int]:
        source = u.where.source
        return (self.sources.index(source) if source in self.sources else -1, u.where.line_no)

    def finish(self) -> HangprinterConfig:
        """The configuration read; raises RrfError with every problem found. Problems of the
        whole input (no K6, a missing anchor) are named only when no line had one: those
        usually follow from it."""
        whole = Where(", ".join(self.sources) or "(no input)")
        late: list[RrfProblem] = []
        if self.kinematics is None:
            late.append(
                RrfProblem(whole, "no M669 K6: not a RepRapFirmware Hangprinter configuration")
            )
        n = self.n.value
        anchors: list[Value[Vec3]] = []
        for i in range(n):
            a = self.anchors[i]
            if a is None:
                if self.kinematics is not None:
                    late.append(
                        RrfProblem(
                            whole,
                            f"M669 gives no anchor {ANCHOR_LETTERS[i]} (anchor {i + 1} of N{n}): "
                            "RepRapFirmware's placeholder anchors are not a machine",
                        )
                    )
                continue
            if math.hypot(*a.value) == 0.0:
                self.problems.append(
                    RrfProblem(
                        a.where,
                        f"M669 {a.text}: an anchor at the origin, where the effector starts",
                    )
                )
            anchors.append(a)
        if self.problems or late:
            raise RrfError(self.problems or late)
        return self._config(tuple(anchors))

    def _config(self, anchors: tuple[Value[Vec3], ...]) -> HangprinterConfig:
        n = len(anchors)

        def whole(k: str) -> tuple[Value[int], ...]:
            return tuple(Value(int(v.value), v.where, v.text) for v in self.arrays[k][:n])

        drivers: list[Value[DriverId | None]] = []
        directions: list[Value[int]] = []
        for axis in MOTOR_AXES[:n]:
            d = self.axis_drivers.get(axis)
            if d is None:
                drivers.append(Value(None))
                directions.append(Value(1))
                continue
            drivers.append(Value(d.value, d.where, d.text))
            directions.append(self.driver_dirs.get(d.value, Value(1)))
        for axis, d in self.axis_drivers.items():
            if MOTOR_AXES.index(axis) >= n:
                self.unmapped.append(
                    Unmapped(d.where, f"M584 {d.text}", f"not an anchor's motor (N{n})")
                )
        used = {d.value for d in drivers}
        for driver, direction in self.driver_dirs.items():
            if driver not in used:
                self.unmapped.append(
                    Unmapped(
                        direction.where,
                        f"M569 {direction.text}",
                        "this driver moves no anchor (M584)",
                    )
                )

        def least(d: dict[str, Value[float]], code: str) -> Value[float | None]:
            if not d:
                return Value(None)
            k = min(d, key=lambda a: d[a].value)
            text = f"{code} " + " ".join(f"{a}{d[a].value:g}" for a in sorted(d))
            return Value(d[k].value, d[k].where, text)

        return HangprinterConfig(
            anchors_mm=anchors,
            print_radius_mm=self.print_radius,
            anchor_mode=self.anchor_mode,
            buildup_factor_mm=self.q,
            spool_radius_mm=tuple(self.arrays["R"][:n]),
            mechanical_advantage=whole("U"),
            lines_per_spool=whole("O"),
            motor_gear_teeth=whole("L"),
            spool_gear_teeth=whole("H"),
            full_steps_per_rev=whole("J"),
            mover_mass_kg=self.w,
            spring_k_per_unit_length_n=self.s,
            min_force_n=tuple(self.arrays["I"][:n]),
            max_force_n=tuple(self.arrays["X"][:n]),
            guy_wire_mm=tuple(self.arrays["Y"][:n]),
            flex_algorithm=self.flex,
            z_min_mm=self.z_min,
            z_max_mm=self.z_max,
            max_feedrate_mm_per_min=least(self.feedrate, "M203"),
            max_accel_mm_per_s2=least(self.accel, "M201"),
            drivers=tuple(drivers),
            directions=tuple(directions),
            machine_name=self.name,
            unmapped=tuple(sorted(self.unmapped, key=self._order)),
        )


_HANDLERS: Final[dict[str, Callable[[_Reader, Command], None]]] = {
    "M669": _Reader.m669,
    "M666": _Reader.m666,
    "M208": _Reader.m208,
    "M584": _Reader.m584,
    "M569": _Reader.m569,
    "M201": _Reader.m201,
    "M203": _Reader.m203,
    "M550": _Reader.m550,
}


def read_rrf(files: Sequence[tuple[str, str]]) -> HangprinterConfig:
    """Read RepRapFirmware configuration files, given as (name, text) pairs, in order (e.g.
    config.g, then config-override.g), into a `HangprinterConfig`.

    Raises RrfError naming every line that cannot be read or makes the configuration unusable
    (see the module docstring); nothing is returned then.
    """
    reader = _Reader()
    for name, text in files:
        reader.sources.append(name)
        for line_no, line in enumerate(text.splitlines(), start=1):
            reader.line(name, line_no, line)
    return reader.finish()
