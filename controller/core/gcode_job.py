"""G-code jobs: the modal state of a G-code program turned into moves in the robot frame. Pure:
parsed lines (`controller.core.gcode`) in, actions out; no I/O, no clock.

The frame (`GcodeFrame`): G-code X0 Y0 Z0 is the robot-frame point `origin_m`, with the axes
of the robot frame; lengths are millimetres at the start of a job (`unit_m`; `G20`/`G21` switch
to inches and back) and feeds are length units per minute.

Supported, each as RepRapFirmware and Marlin document it (Klipper's where they differ):

* `G0`/`G1` X Y Z F: a straight move. F is modal (shared by G0 to G3) and scaled by `M220`.
  A `G0` without an F word runs at `rapid_speed_mps` (CAM tools' rapids); with one it runs at
  that feed (Marlin, Klipper). Axis words without a command repeat the last G0 to G3.
* `G2`/`G3` X Y (Z) I J or R, in the XY plane (`G17`; `G18`/`G19` are refused): clockwise and
  counter-clockwise arcs seen from +Z, the centre at the start plus (I, J) or from the radius R
  (negative R: the arc over 180 degrees), start = end with I J is a full circle, a Z word
  makes a helix. Linearised into chords that stay within `arc_tolerance_m` of the arc. An arc
  whose end is not on its circle (by more than `ARC_RADIUS_TOLERANCE`) is refused.
* `G4` P (ms) or S (s): dwell; `G20`/`G21`; `G90`/`G91` (X Y Z, and E unless `M82`/`M83` chose);
  `G92`: the current point is given these G-code coordinates (no words: all zero), no motion.
* `G28`: a move at the rapid speed to the home pose `home_m` (default: the G-code origin), in
  a straight line, of the named axes only if any are named. cablebot does not re-home its
  encoders here: homing is the operator's `cablebot home` before the job. RepRapFirmware's
  Hangprinter kinematics likewise has no endstops to home to; its home is a pose.
* `M400`: wait until every move has been flown; `M114`: report the position (in G-code units);
  `M18`/`M84`: disarm once the moves are flown (`M84 E...` only concerns extruders: not driven;
  `M84 S` alone sets Marlin's idle time-out: unsupported); `M112`: emergency stop at once.
* Limits: `M203` (maximum feed rate: mm/s in Marlin's dialect, mm/min in RepRapFirmware's),
  `M201` (maximum acceleration), `M204` (P/S printing and T travel acceleration: the lowest
  named is taken), `M220` S (feed percentage). The robot's speed and acceleration are the
  smallest of the configuration and the X and Y values given (Z and E values are not the
  robot's: a printer's slow Z screw says nothing of its cables). They can lower the limits,
  never raise them past the configuration. `M205` (jerk) is accepted: the planner's corner
  rule is junction deviation, not jerk.
* `M593` (input shaping, RepRapFirmware's syntax): come to rest, then shape every move after it
  with P"type" (RepRapFirmware's `none`, `zvd`, `mzv`, `ei2`, `ei3`, or cablebot's `off`, `zv`,
  `ei`, `2hump_ei`, `3hump_ei`; not case sensitive; `zvdd`, `zvddd` and `custom` are refused),
  at F Hz (absent: the model's modes at the set-point, as `[shaper]` without `frequency_hz`)
  for modes of damping ratio S (absent: the robot's). Without P the default type. A type, a
  frequency or a damping ratio the shaper refuses stops the job at its line before any move.
* Extrusion (E words), tools (T), temperatures, fans, flow, firmware retraction and
  linear advance are accepted and counted as not driven by cablebot (`Job.not_driven`);
  host messages and reports (`M73`, `M105`, `M110`, `M115`, `M117`, `M118`, ...) are accepted
  with nothing to do; every other code is counted once per code (`Job.unsupported`) and not
  run.

A job is checked whole before its first move (`check_job`): every point and leg against the
workspace, and with a payload the tension rule, naming the first G-code line that breaks one.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Final

from controller.core.gcode import Command, GcodeError, Line
from controller.core.motion import MotionPlanner, QueueError, check_speed, dedupe_path
from controller.core.motion.shaper import DEFAULT_SHAPER_TYPE, SHAPER_TYPES, check_shaper
from controller.core.statics import TensionCheck
from controller.core.suggest import closest
from controller.core.workspace import Workspace, points_array

Vec3 = tuple[float, float, float]

MM_M = 0.001
INCH_M = 0.0254
ARC_RADIUS_TOLERANCE = 0.002
"""An arc's end may be off its circle by this fraction of the radius (plus 10 um)."""
MAX_ARC_CHORDS = 100_000
"""An arc is linearised into at most this many chords (a coarser one is refused)."""

NOT_DRIVEN: frozenset[str] = frozenset(
    {
        "M104", "M109", "M140", "M190", "M141", "M191",  # temperatures
        "M106", "M107",  # fans
        "M221", "M900", "M207", "M208.1", "G10", "G11",  # flow, advance, firmware retraction
        "M82", "M83",  # extruder modes (tracked for M114)
        "M163", "M164", "M302", "M572",
    }
)  # fmt: skip
"""Codes about extruders, tools, heaters and fans: accepted and counted, nothing moves."""

NOTHING_TO_DO: frozenset[str] = frozenset(
    {"M73", "M105", "M110", "M111", "M115", "M117", "M118", "M486", "G17", "M205", "M107.1"}
)
"""Host messages, progress, reports and settings with no effect on the robot's motion."""


class JobError(GcodeError):
    """A G-code job that cannot be run as written (an unsupported plane, a bad arc, a feed
    the robot refuses, a point out of the workspace), naming its line."""


@dataclass(frozen=True, slots=True)
class GcodeFrame:
    """Where G-code coordinates are and how fast the robot may fly them.

    `origin_m`: the robot-frame point of G-code X0 Y0 Z0; `unit_m`: metres per G-code length
    unit at the start (0.001: mm); `home_m`: the `G28` pose (None: the origin);
    `arc_tolerance_m`: the largest distance of a chord from its arc; `max_speed_mps` and
    `max_accel_mps2`: the robot's limits (G-code may lower them); `rapid_speed_mps`: a `G0`
    without F (None: `max_speed_mps`); `m203_per_minute`: `M203` in units/min
    (RepRapFirmware) rather than units/s (Marlin)."""

    origin_m: Vec3 = (0.0, 0.0, 0.0)
    unit_m: float = MM_M
    home_m: Vec3 | None = None
    arc_tolerance_m: float = 1e-4
    max_speed_mps: float = 1.0
    max_accel_mps2: float = 1.0
    rapid_speed_mps: float | None = None
    m203_per_minute: bool = False

    def __post_init__(self) -> None:
        for name in ("unit_m", "arc_tolerance_m", "max_speed_mps", "max_accel_mps2"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {v!r}")
        if self.rapid_speed_mps is not None and not (
            math.isfinite(self.rapid_speed_mps) and self.rapid_speed_mps > 0.0
        ):
            raise ValueError(
                f"rapid_speed_mps must be finite and > 0, got {self.rapid_speed_mps!r}"
            )
        for name in ("origin_m", "home_m"):
            p = getattr(self, name)
            if p is not None and (len(p) != 3 or not all(math.isfinite(c) for c in p)):
                raise ValueError(f"{name} must be 3 finite numbers, got {p!r}")


# ------------------------------------------------------------------------------ the actions
@dataclass(frozen=True, slots=True)
class Motion:
    """Fly through `points_m` (robot frame) at `speed_mps`: one straight G0/G1 line or a
    G28 (one point), or the chords of an arc. `move` is True for a G0 to G3 line with an
    X, Y or Z word."""

    line_no: int
    points_m: tuple[Vec3, ...]
    speed_mps: float
    move: bool = True


@dataclass(frozen=True, slots=True)
class Dwell:
    """Come to rest, then wait `duration_s` (G4)."""

    line_no: int
    duration_s: float


@dataclass(frozen=True, slots=True)
class Sync:
    """Come to rest (M400; M114 with its `report`, the position in G-code units as Marlin
    words it)."""

    line_no: int
    report: str | None = None


@dataclass(frozen=True, slots=True)
class Disarm:
    """Come to rest, then disarm (M18/M84)."""

    line_no: int


@dataclass(frozen=True, slots=True)
class Estop:
    """Emergency stop at once (M112)."""

    line_no: int


@dataclass(frozen=True, slots=True)
class Limits:
    """From here on the robot flies at most `max_speed_mps` and `max_accel_mps2`."""

    line_no: int
    max_speed_mps: float
    max_accel_mps2: float


@dataclass(frozen=True, slots=True)
class Shaping:
    """Come to rest, then shape every move after this one with the train `type` ("off" for
    none), at `frequency_hz` (None: the model's modes at the set-point) for modes of
    `damping_ratio` (None: keep the robot's) (M593)."""

    line_no: int
    type: str
    frequency_hz: float | None
    damping_ratio: float | None


Action = Motion | Dwell | Sync | Disarm | Estop | Limits | Shaping


@dataclass(slots=True)
class Job:
    """A G-code program interpreted: its actions in order and what it holds.

    `lines`: lines read; `moves`: G0 to G3 lines with an X, Y or Z word; `start_m`: the
    robot-frame start point; `path_m`: the length of every motion; `bbox_m`: ((min x, y, z),
    (max x, y, z)) of every motion's points, where the job goes (the start, where the robot
    happens to be, only for a job without motion); `not_driven` and `unsupported`: code ->
    number of lines (extrusion words count under "E")."""

    start_m: Vec3
    actions: list[Action] = field(default_factory=list)
    lines: int = 0
    moves: int = 0
    path_m: float = 0.0
    bbox_m: tuple[Vec3, Vec3] = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    not_driven: dict[str, int] = field(default_factory=dict)
    unsupported: dict[str, int] = field(default_factory=dict)
    accel_mps2: float = math.inf
    """The lowest acceleration limit in effect at any point of the job (the frame's, or lower
    by `M201`/`M204`)."""
    speed_limit: tuple[int, float] | None = None
    """(line, m/s) of the `M203` that lowered the speed limit the most, if one did."""
    fastest_feed_mps: float = 0.0
    """The fastest feed the job's F words ask for (with `M220`), before any limit."""


# -------------------------------------------------------------------------- the interpreter
class Interpreter:
    """The modal state of a G-code program. `feed(line)` returns the actions of one parsed
    line (and updates `job`'s counts); `interpret` runs a whole program.

    Starts at the robot-frame point `start_m` (whose G-code coordinates follow from the
    frame), absolute, millimetres, the feed None (a G1 before any F is refused), 100 %
    feed."""

    def __init__(self, frame: GcodeFrame, start_m: Sequence[float]) -> None:
        start = (float(start_m[0]), float(start_m[1]), float(start_m[2]))
        if not all(math.isfinite(c) for c in start):
            raise ValueError(f"start_m must be finite, got {start_m!r}")
        self.frame = frame
        self.job = Job(start, bbox_m=(start, start), accel_mps2=frame.max_accel_mps2)
        self.pos_m: Vec3 = start
        self._shift_m: list[float] = list(frame.origin_m)  # robot point of G-code 0 (G92)
        self.unit_m = frame.unit_m
        self.absolute = True
        self.e_absolute: bool | None = None  # None: follows G90/G91
        self.e: float = 0.0
        self.feed_per_min: float | None = None
        self.feed_factor = 1.0
        self.motion_code = ""
        self.max_speed_mps = frame.max_speed_mps
        self.max_accel_mps2 = frame.max_accel_mps2
        self._lo: list[float] = []
        self._hi: list[float] = []
        """The box of the motions so far (empty before the first)."""

    # ---------------------------------------------------------------- coordinates
    def gcode_position(self) -> Vec3:
        """The current point in G-code coordinates (current units, after G92)."""
        u = self.unit_m
        p, s = self.pos_m, self._shift_m
        return ((p[0] - s[0]) / u, (p[1] - s[1]) / u, (p[2] - s[2]) / u)

    def _target(self, cmd: Command, line_no: int) -> Vec3 | None:
        """The robot-frame end of a move's X Y Z words (None when it has none)."""
        words = [cmd.number_param(a, line_no) for a in "XYZ"]
        if words == [None, None, None]:
            return None
        u, p, s = self.unit_m, self.pos_m, self._shift_m
        out = [0.0, 0.0, 0.0]
        for i, w in enumerate(words):
            if w is None:
                out[i] = p[i]
            elif self.absolute:
                out[i] = s[i] + w * u
            else:
                out[i] = p[i] + w * u
        return (out[0], out[1], out[2])

    def _speed(self, cmd: Command, line_no: int, rapid: bool) -> float:
        f = cmd.number_param("F", line_no)
        if f is not None:
            if not f > 0.0:
                raise JobError(line_no, f"feed F{f:g} must be > 0")
            self.feed_per_min = f
        elif rapid:
            r = self.frame.rapid_speed_mps
            return min(self.max_speed_mps, self.frame.max_speed_mps if r is None else r)
        if self.feed_per_min is None:
            raise JobError(line_no, f"{cmd.code or 'motion'} before any feed rate (F)")
        v = self.feed_per_min * self.unit_m / 60.0 * self.feed_factor
        why = check_speed(v)
        if why is not None:
            raise JobError(line_no, f"feed F{self.feed_per_min:g} ({v:.4g} m/s): {why}")
        if v > self.job.fastest_feed_mps:
            self.job.fastest_feed_mps = v
        return min(v, self.max_speed_mps)

    def _note(self, table: dict[str, int], code: str) -> None:
        table[code] = table.get(code, 0) + 1

    def _extrusion(self, cmd: Command, line_no: int) -> None:
        e = cmd.number_param("E", line_no)
        if e is None:
            return
        self._note(self.job.not_driven, "E")
        absolute = self.absolute if self.e_absolute is None else self.e_absolute
        self.e = e if absolute else self.e + e

    def _fly(self, line_no: int, points: tuple[Vec3, ...], speed: float, move: bool) -> Motion:
        job = self.job
        prev = self.pos_m
        lo, hi = self._lo, self._hi
        if not lo:
            lo.extend(points[0])
            hi.extend(points[0])
        total = 0.0
        for q in points:
            total += math.dist(prev, q)
            prev = q
            for i in range(3):
                if q[i] < lo[i]:
                    lo[i] = q[i]
                elif q[i] > hi[i]:
                    hi[i] = q[i]
        job.path_m += total
        job.bbox_m = ((lo[0], lo[1], lo[2]), (hi[0], hi[1], hi[2]))
        if move:
            job.moves += 1
        self.pos_m = points[-1]
        return Motion(line_no, points, speed, move)

    # ---------------------------------------------------------------- lines
    def feed(self, line: Line) -> list[Action]:
        """The actions of one parsed line, in order. Raises JobError (naming the line) for a
        command that cannot run as written; the state is then unspecified (stop the job)."""
        self.job.lines += 1
        out: list[Action] = []
        for cmd in line.commands:
            act = self._command(cmd, line.line_no)
            if act is not None:
                out.append(act)
        return out

    def _command(self, cmd: Command, n: int) -> Action | None:
        letter, code = cmd.letter, cmd.code
        if letter == "":
            if not (cmd.has("X") or cmd.has("Y") or cmd.has("Z")) or not self.motion_code:
                if cmd.params.keys() <= {"F"} and cmd.has("F"):
                    self.feed_per_min = cmd.number_param("F", n)
                    return None
                self._note(self.job.unsupported, "(words without a command)")
                return None
            return self._motion(self.motion_code, cmd, n)
        if letter == "T":
            self._note(self.job.not_driven, "T")
            return None
        if code in ("G0", "G1", "G2", "G3"):
            self.motion_code = code
            return self._motion(code, cmd, n)
        if code == "G4":
            p, s = cmd.number_param("P", n), cmd.number_param("S", n)
            d = (p / 1000.0 if p is not None else 0.0) + (s if s is not None else 0.0)
            if not d >= 0.0:
                raise JobError(n, f"G4: negative dwell {d:g} s")
            return Dwell(n, d)
        if code == "G20":
            self.unit_m = INCH_M
        elif code == "G21":
            self.unit_m = MM_M
        elif code == "G90":
            self.absolute = True
        elif code == "G91":
            self.absolute = False
        elif code == "M82":
            self.e_absolute = True
            self._note(self.job.not_driven, code)
        elif code == "M83":
            self.e_absolute = False
            self._note(self.job.not_driven, code)
        elif code in ("G18", "G19"):
            raise JobError(n, f"{code}: arcs only in the XY plane (G17)")
        elif code == "G92":
            self._set_position(cmd, n)
        elif code == "G28":
            return self._home(cmd, n)
        elif code == "M400":
            return Sync(n)
        elif code == "M114":
            x, y, z = self.gcode_position()
            return Sync(n, f"X:{x:.3f} Y:{y:.3f} Z:{z:.3f} E:{self.e:.3f}")
        elif code in ("M18", "M84"):
            axes = [a for a in cmd.params if a in "XYZ"]
            if cmd.params and not axes:
                self._note(self.job.not_driven if cmd.has("E") else self.job.unsupported, code)
                return None
            return Disarm(n)
        elif code == "M112":
            return Estop(n)
        elif code in ("M201", "M203", "M204", "M220"):
            return self._limits(cmd, n)
        elif code == "M593":
            return _shaping(cmd, n)
        elif code in NOT_DRIVEN:
            self._note(self.job.not_driven, code)
        elif code in NOTHING_TO_DO:
            pass
        else:
            self._note(self.job.unsupported, code)
        return None

    def _motion(self, code: str, cmd: Command, n: int) -> Action | None:
        self._extrusion(cmd, n)
        if code in ("G0", "G1"):
            target = self._target(cmd, n)
            speed = self._speed(cmd, n, rapid=code == "G0" and not cmd.has("F"))
            if target is None:
                return None
            return self._fly(n, (target,), speed, True)
        return self._arc(code == "G2", cmd, n)

    def _arc(self, clockwise: bool, cmd: Command, n: int) -> Action | None:
        speed = self._speed(cmd, n, rapid=False)
        end = self._target(cmd, n) or self.pos_m
        start = self.pos_m
        u = self.unit_m
        i, j, r = (cmd.number_param(a, n) for a in "IJR")
        sx, sy = start[0], start[1]
        ex, ey = end[0], end[1]
        if r is not None:
            if i is not None or j is not None:
                raise JobError(n, f"{cmd.code}: give I J or R, not both")
            radius = abs(r) * u
            dx, dy = ex - sx, ey - sy
            chord = math.hypot(dx, dy)
            if chord == 0.0:
                raise JobError(n, f"{cmd.code}: an R arc needs an end point other than its start")
            if chord > 2.0 * radius * (1.0 + ARC_RADIUS_TOLERANCE) + 1e-5:
                raise JobError(n, f"{cmd.code}: R{r:g} is shorter than half the chord")
            h = math.sqrt(max(0.0, radius * radius - chord * chord / 4.0))
            # centre to the right of start->end for a clockwise arc under 180 degrees
            side = -1.0 if clockwise else 1.0
            if r < 0.0:
                side = -side
            cx = sx + dx / 2.0 - side * h * dy / chord
            cy = sy + dy / 2.0 + side * h * dx / chord
        else:
            if i is None and j is None:
                raise JobError(n, f"{cmd.code}: an arc needs I J or R")
            cx = sx + (i or 0.0) * u
            cy = sy + (j or 0.0) * u
            radius = math.hypot(sx - cx, sy - cy)
            r_end = math.hypot(ex - cx, ey - cy)
            if abs(r_end - radius) > ARC_RADIUS_TOLERANCE * radius + 1e-5:
                raise JobError(
                    n,
                    f"{cmd.code}: the end is {r_end * 1e3:.3f} mm from the centre, the start "
                    f"{radius * 1e3:.3f} mm",
                )
        if radius <= 0.0:
            raise JobError(n, f"{cmd.code}: zero radius")
        a0 = math.atan2(sy - cy, sx - cx)
        a1 = math.atan2(ey - cy, ex - cx)
        sweep = a1 - a0
        if clockwise:
            if sweep >= -1e-12:
                sweep -= 2.0 * math.pi
        elif sweep <= 1e-12:
            sweep += 2.0 * math.pi
        if (sx, sy) != (ex, ey) and abs(abs(sweep) - 2.0 * math.pi) < 1e-12:
            sweep = 0.0
        tol = min(self.frame.arc_tolerance_m, radius)
        step = 2.0 * math.acos(1.0 - tol / radius)
        chords = max(1, math.ceil(abs(sweep) / step))
        if chords > MAX_ARC_CHORDS:
            raise JobError(n, f"{cmd.code}: {chords} chords (more than {MAX_ARC_CHORDS})")
        z0, dz = start[2], end[2] - start[2]
        pts: list[Vec3] = []
        for k in range(1, chords):
            f = k / chords
            a = a0 + sweep * f
            pts.append((cx + radius * math.cos(a), cy + radius * math.sin(a), z0 + dz * f))
        pts.append(end)
        return self._fly(n, tuple(pts), speed, True)

    def _set_position(self, cmd: Command, n: int) -> None:
        words = {a: cmd.number_param(a, n) for a in "XYZE" if cmd.has(a)}
        if not words:
            words = {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
        for k, a in enumerate("XYZ"):
            w = words.get(a)
            if w is not None:
                self._shift_m[k] = self.pos_m[k] - w * self.unit_m
        e = words.get("E")
        if e is not None:
            self.e = e

    def _home(self, cmd: Command, n: int) -> Action | None:
        home = self.frame.home_m or self.frame.origin_m
        named = [k for k, a in enumerate("XYZ") if cmd.has(a)]
        if not named:
            named = [0, 1, 2]
        p = list(self.pos_m)
        for k in named:
            p[k] = home[k]
        target = (p[0], p[1], p[2])
        r = self.frame.rapid_speed_mps
        speed = min(self.max_speed_mps, self.frame.max_speed_mps if r is None else r)
        if target == self.pos_m:
            return None
        return self._fly(n, (target,), speed, False)

    def _limits(self, cmd: Command, n: int) -> Action | None:
        code = cmd.code
        if code == "M220":
            s = cmd.number_param("S", n)
            if s is None:
                return None
            if not s > 0.0:
                raise JobError(n, f"M220 S{s:g}: the feed percentage must be > 0")
            self.feed_factor = s / 100.0
            return None
        per = 60.0 if code == "M203" and self.frame.m203_per_minute else 1.0
        letters = "XY" if code in ("M201", "M203") else "PST"
        vals: list[float] = []
        for a in letters:
            if not cmd.has(a):
                continue
            v = cmd.params[a]
            items = v if isinstance(v, tuple) else (cmd.number_param(a, n),)
            for x in items:
                if x is None or not x > 0.0:
                    raise JobError(n, f"{code} {a}: must be > 0")
                vals.append(x * self.unit_m / per)
        if not vals:
            return None
        if code == "M203":
            self.max_speed_mps = min(self.frame.max_speed_mps, min(vals))
            low = self.job.speed_limit
            if min(vals) < self.frame.max_speed_mps and (low is None or min(vals) < low[1]):
                self.job.speed_limit = (n, min(vals))
        else:
            self.max_accel_mps2 = min(self.frame.max_accel_mps2, min(vals))
            self.job.accel_mps2 = min(self.job.accel_mps2, self.max_accel_mps2)
        return Limits(n, self.max_speed_mps, self.max_accel_mps2)


M593_TYPES: Final = MappingProxyType(
    {
        "none": "off",
        "zvd": "zvd",
        "mzv": "mzv",
        "ei2": "2hump_ei",
        "ei3": "3hump_ei",
        **{kind: kind for kind in SHAPER_TYPES},
    }
)
"""M593's P types (RepRapFirmware's names, not case sensitive, and cablebot's own) and the
shaper each means."""


def _shaping(cmd: Command, n: int) -> Shaping | None:
    """M593 (RepRapFirmware's syntax): P"type", F (Hz; absent: the model's modes), S (damping
    ratio; absent: keep). No word at all reports in RepRapFirmware: nothing to do here. Raises
    JobError for an unknown or unsupported type and a frequency or damping ratio out of
    range, naming the line."""
    if not cmd.params:
        return None
    if "H" in cmd.params or "T" in cmd.params:
        raise JobError(n, 'M593 H/T (P"custom" impulses): not supported; name a type')
    raw = cmd.params.get("P")
    if raw is None and cmd.has("P"):
        raise JobError(n, 'M593 P: give a type, e.g. P"ei2"')
    if raw is not None and not isinstance(raw, str):
        raise JobError(n, f'M593 P: a quoted type, e.g. P"ei2", got {raw!r}')
    freq = cmd.number_param("F", n)
    damping = cmd.number_param("S", n)
    if raw is None:
        if freq is None and damping is None:
            return None
        kind = DEFAULT_SHAPER_TYPE
    else:
        kind_name = raw.strip().lower()
        found = M593_TYPES.get(kind_name)
        if found is None:
            near = closest(kind_name, M593_TYPES)
            hint = f" (did you mean {near!r}?)" if near else ""
            raise JobError(
                n,
                f'M593 P"{raw}": unknown or unsupported shaper type{hint}; one of '
                + ", ".join(sorted(M593_TYPES)),
            )
        kind = found
    reason = check_shaper(kind, freq, 0.0 if damping is None else damping)
    if reason is not None:
        raise JobError(n, f"M593: {reason}")
    return Shaping(n, kind, freq, damping)


def interpret(lines: Iterable[Line], frame: GcodeFrame, start_m: Sequence[float]) -> Job:
    """Interpret a whole program from `start_m` (robot frame). Raises JobError naming the
    first line that cannot run (and what `Interpreter.feed` raises)."""
    it = Interpreter(frame, start_m)
    actions = it.job.actions
    for line in lines:
        actions.extend(it.feed(line))
    return it.job


# ------------------------------------------------------------------------------ the check
def motion_failure(
    points: Sequence[Vec3],
    start_m: Sequence[float] | None,
    workspace: Workspace,
    tension: TensionCheck | None = None,
    tension_step_m: float = 0.05,
) -> tuple[int, str] | None:
    """The first of `points` (flown in order from `start_m`; None: the leg to the first point
    is not checked) that leaves the workspace (a point or a straight leg) or, with `tension`,
    the tension rule (legs sampled every `tension_step_m`), as (0-based index, reason); None
    when the whole motion is allowed: the check of a whole job or path file before anything is
    sent. Raises nothing."""
    failure = workspace.path_failure(points, start_m, array=points_array(points))
    if failure is None and tension is not None:
        failure = tension.path_failure(points, start_m, tension_step_m)
    return failure


def check_job(
    job: Job,
    workspace: Workspace,
    tension: TensionCheck | None = None,
    tension_step_m: float = 0.05,
) -> tuple[int, str] | None:
    """The first G-code line whose motion leaves the workspace (a point or a straight leg,
    from the job's start) or, with `tension`, the tension rule (legs sampled every
    `tension_step_m`), as (line number, reason); None when the whole job is allowed.
    Raises nothing for a job `interpret` built."""
    points: list[Vec3] = []
    owners: list[int] = []
    for act in job.actions:
        if isinstance(act, Motion):
            points.extend(act.points_m)
            owners.extend([act.line_no] * len(act.points_m))
    if not points:
        return None
    failure = motion_failure(points, job.start_m, workspace, tension, tension_step_m)
    if failure is None:
        return None
    k, why = failure
    p = points[k]
    return owners[k], f"point [{p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}]: {why}"


# ------------------------------------------------------------------------- chunks and timing
DRY_RUN_DT_S = 0.02
"""The longest time step at which `plan_job` advances the planner (`dry_run_step_s`)."""
PIECES_PER_STEP = 4
"""`dry_run_step_s` keeps the points crossed in one step of all but the job's shortest 1 %
segments under this (each point is a line and a corner arc: 8 pieces, half of
`motion.MAX_LEGS_PER_ADVANCE`, beyond which a step drops time)."""


def dry_run_step_s(job: Job, loop_period_s: float) -> float:
    """The time step for `plan_job`: as long as `DRY_RUN_DT_S` (fewer steps, a faster dry
    run) but short enough that a step crosses at most `PIECES_PER_STEP` points of the job's
    segments at their speeds (but its shortest 1 %), and never shorter than the loop's period:
    where the planner would drop time in a long step, the loop does not. Raises nothing."""
    times: list[float] = []
    prev = job.start_m
    for act in job.actions:
        if isinstance(act, Motion):
            for q in act.points_m:
                d = math.dist(prev, q)
                if d > 0.0:
                    times.append(d / act.speed_mps)
                prev = q
    if not times:
        return DRY_RUN_DT_S
    times.sort()
    typical = times[len(times) // 100]
    return max(loop_period_s, min(DRY_RUN_DT_S, PIECES_PER_STEP * typical))


@dataclass(frozen=True, slots=True)
class Chunk:
    """Consecutive motions at one speed, at most a given number of points: one path command
    (the first of a job, or after a wait) or one append. `first_line`..`last_line` are their
    G-code lines; `moves` the G0 to G3 moves among them."""

    points_m: tuple[Vec3, ...]
    speed_mps: float
    first_line: int
    last_line: int
    moves: int


Step = Chunk | Dwell | Sync | Disarm | Estop | Shaping


def chunks(actions: Iterable[Action], max_points: int) -> Iterator[Step]:
    """The job's motions gathered into chunks of at most `max_points` points at one speed,
    and its waits, disarm and e-stop in order (a `Limits` needs nothing more: each motion
    carries its speed). Raises ValueError when `max_points` < 1."""
    if max_points < 1:
        raise ValueError(f"max_points must be >= 1, got {max_points}")
    pts: list[Vec3] = []
    speed = 0.0
    first = last = moves = 0
    for act in actions:
        if isinstance(act, Motion):
            if pts and act.speed_mps != speed:
                yield Chunk(tuple(pts), speed, first, last, moves)
                pts = []
            if not pts:
                speed, first, moves = act.speed_mps, act.line_no, 0
            last = act.line_no
            moves += int(act.move)
            k = 0
            while k < len(act.points_m):
                room = max_points - len(pts)
                take = act.points_m[k : k + room]
                pts.extend(take)
                k += len(take)
                if len(pts) >= max_points:
                    yield Chunk(tuple(pts), speed, first, last, moves)
                    pts, first, moves = [], act.line_no, 0
        elif isinstance(act, Limits):
            continue
        else:
            if pts:
                yield Chunk(tuple(pts), speed, first, last, moves)
                pts = []
            yield act
    if pts:
        yield Chunk(tuple(pts), speed, first, last, moves)


@dataclass(frozen=True, slots=True)
class JobPlan:
    """A job as the planner flies it: `duration_s` (motion and dwells), `motion_s` (motion
    only) and the corners flown as stops (`blends_dropped`)."""

    duration_s: float
    motion_s: float
    blends_dropped: int


def plan_job(
    job: Job, planner: MotionPlanner, dt_s: float = DRY_RUN_DT_S, chunk_points: int = 1000
) -> JobPlan:
    """Fly `job` on `planner` (built with the robot's limits; the caller lowers its
    acceleration to `job.accel_mps2`) as the daemon would fly its path commands: one path, then
    appends, resting at every wait (G4, M400, M114, M18/M84); an M112 ends the job. Advances
    the planner `dt_s` at a time (`dry_run_step_s`) and counts the time until it rests at the
    end. Raises
    ValueError for a non-positive `dt_s` (and what the planner raises for a chunk it refuses;
    `interpret` makes none)."""
    if not (dt_s > 0.0 and math.isfinite(dt_s)):
        raise ValueError(f"dt_s must be finite and > 0, got {dt_s!r}")
    planner.hold(job.start_m)
    ticks = 0
    dwell_s = 0.0
    fresh = True
    room = planner.max_queued_points
    for step in chunks(job.actions, chunk_points):
        if isinstance(step, Chunk):
            while planner.queued_points + len(step.points_m) > room:
                planner.advance(dt_s)
                ticks += 1
            if fresh or not planner.appendable:
                planner.follow_points(_deduped(step.points_m, planner.position_m), step.speed_mps)
                fresh = False
            else:
                try:
                    planner.append_points(step.points_m, step.speed_mps)
                except QueueError:  # ran dry and closed meanwhile: start again from rest
                    planner.follow_points(
                        _deduped(step.points_m, planner.position_m), step.speed_mps
                    )
            continue
        while planner.moving:
            planner.advance(dt_s)
            ticks += 1
        fresh = True
        if isinstance(step, Dwell):
            dwell_s += step.duration_s
        elif isinstance(step, Estop):
            break
    while planner.moving:
        planner.advance(dt_s)
        ticks += 1
    motion_s = ticks * dt_s
    return JobPlan(motion_s + dwell_s, motion_s, planner.blends_dropped)


def _deduped(points: tuple[Vec3, ...], start: Vec3) -> tuple[Vec3, ...]:
    """`points` without repeats (the planner's rule), never empty."""
    return dedupe_path(points) or (start,)
