"""A cablebot robot file from a RepRapFirmware Hangprinter configuration (`controller.core.rrf`).

Pure: a `HangprinterConfig` in, a `RobotDraft` (every value with the comment saying where it came
from) and its TOML text out. The mapping, parameter by parameter (docs/reprapfirmware.md):

* anchors: `M669` A B C D ... in mm → `[[reels]] anchor_m` in m, in the same order (the last
  on top); `P` → `[limits] print_radius_m`.
* spools (`M666`): `R` → `drum_radius_m` (the radius at the origin, where RepRapFirmware measures
  it) with `reference_length_m` = the anchor's distance from the origin; `H / L` → `gear_ratio`
  (motor turns per spool turn); `U` → `mechanical_advantage`; `Q × O` → `spool_buildup_factor_m`
  (RepRapFirmware's spool model is the reel model's build-up, `controller.core.reel`).
* flex (`M666`): `W` → `[payload] mass_kg`; `S` → `cable_ea_n`, as RepRapFirmware's flex model
  stretches the line: a line of spring constant `S / (U·L + g)` (its whole length, through the
  pulley block and along a guy wire `g`) moves the effector `F / (k·U)` under a force `F`, which
  is cablebot's `L·F / EA` for `EA = S·U·L / (U·L + g)`, taken at the origin (`S` alone
  without a guy wire); `I` / `X` → `[limits] min_tension_n` / `max_tension_n` (the
  strictest of the anchors').
* `M208` Z → `[limits] floor_z_m` / `ceiling_z_m`; `M203` / `M201` X Y Z → `max_speed_mps` /
  `max_accel_mps2` (the least of the three); `M584` CAN boards → `node_id` (the ODrive node
  ids RepRapFirmware addresses); `M569` S0 → `direction = -1`; `M550` → `name`.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from controller.core.reel import ReelModel, spool_buildup_from_factor
from controller.core.rrf import (
    RRF_DEFAULTS,
    HangprinterConfig,
    Unmapped,
    Value,
    Vec3,
    format_driver,
)

DEFAULT_NAME = "hangprinter"
ODRIVE_NODE_MAX = 63
"""The largest ODrive CAN node id (`[drive] kind = "odrive"`)."""
XY_MARGIN_M = 0.05
TOP_MARGIN_M = 0.1
MIN_CABLE_M = 0.05
CABLE_RANGE_SPARE = 1.05
"""`max_cable_m` is this much beyond the longest line the workspace can need."""
CAUTIOUS_SPEED_MPS = 0.1
CAUTIOUS_ACCEL_MPS2 = 1.0
_NAME_BAD = re.compile(r"[^A-Za-z0-9_.-]+")
_COMMENT_COLUMN = 32

TomlValue = float | int | str | tuple[float, ...]


@dataclass(frozen=True, slots=True)
class Entry:
    """One key of the robot file, its value and where it came from (the comment)."""

    key: str
    value: TomlValue
    comment: str = ""


@dataclass(frozen=True, slots=True)
class ReelDraft:
    """One `[[reels]]` table: the anchor's letter, its keys, and the reel model they mean."""

    letter: str
    entries: tuple[Entry, ...]
    node_id: int
    anchor_m: Vec3
    drum_radius_m: float
    gear_ratio: float
    direction: int
    mechanical_advantage: float
    buildup_factor_m: float
    reference_length_m: float
    cable_ea_n: float | None

    def model(self) -> ReelModel:
        """The reel model these keys give (as the configuration parser builds it), homed so that
        motor turn 0 is the origin, as RepRapFirmware counts its steps. Raises ValueError for
        a parameter `ReelModel` refuses."""
        return ReelModel(
            metres_per_rev=2.0 * math.pi * self.drum_radius_m,
            gear_ratio=self.gear_ratio,
            direction=self.direction,
            mechanical_advantage=self.mechanical_advantage,
            spool_buildup_m_per_rev2=spool_buildup_from_factor(self.buildup_factor_m),
            reference_length_m=self.reference_length_m,
        )


@dataclass(frozen=True, slots=True)
class RobotDraft:
    """The robot file: its sections' keys, the reels, what the mapping assumed (`remarks`) and
    what it left out (`unmapped`)."""

    name: Entry
    sections: tuple[tuple[str, tuple[Entry, ...]], ...]
    reels: tuple[ReelDraft, ...]
    remarks: tuple[str, ...]
    unmapped: tuple[Unmapped, ...]


def robot_name(text: str) -> str:
    """`text` as a cablebot robot name (letters, digits, `_ . -`, 63 at most; others become
    `-`), or `DEFAULT_NAME` when nothing is left. Raises nothing."""
    name = _NAME_BAD.sub("-", text).lstrip("-_.")[:63].rstrip("-")
    return name or DEFAULT_NAME


def _r(v: float, digits: int = 12) -> float:
    """`v` rounded to `digits` significant digits (mm/1000 without the float noise)."""
    return float(f"{v:.{digits}g}") + 0.0


def _from(v: Value[Any]) -> str:
    """Where a value came from, for a comment: ``M666 R75.5 (config.g:16)``."""
    if v.where.default:
        return "RepRapFirmware's default"
    return f"{v.text} ({v.where})"


def _guy_wires_m(cfg: HangprinterConfig) -> tuple[tuple[float, str], ...]:
    """Each line's guy wire (m) as RepRapFirmware 3.6 takes it, and why."""
    n = cfg.n
    given = [g.value for g in cfg.guy_wire_mm]
    if cfg.anchor_mode.value != 1:
        return tuple((0.0, f"none: anchor mode {_from(cfg.anchor_mode)}") for _ in range(n))
    if all(g >= 0.0 for g in given):
        return tuple((g / 1000.0, _from(cfg.guy_wire_mm[i])) for i, g in enumerate(given))
    top = cfg.anchors_mm[-1].value
    out = []
    for i in range(n - 1):
        g = math.dist(cfg.anchors_mm[i].value, top) / 1000.0
        out.append((g, f"{g:.3f} m, from this anchor to the top one (spools on the top anchor)"))
    out.append((0.0, "none (the top anchor's spool is on it)"))
    return tuple(out)


def _node_ids(cfg: HangprinterConfig) -> tuple[tuple[int, str], ...]:
    """Each reel's node id: the anchors' CAN boards (the ODrives' node ids) when they are
    distinct and valid ODrive node ids, else 0, 1, ... with the reason."""
    boards = [d.value[0] if d.value is not None else 0 for d in cfg.drivers]
    if all(0 < b <= ODRIVE_NODE_MAX for b in boards) and len(set(boards)) == len(boards):
        return tuple(
            (b, f"M584 {d.text} ({d.where}): the ODrive on CAN board {b}")
            for b, d in zip(boards, cfg.drivers, strict=True)
        )
    if all(d.value is None for d in cfg.drivers):
        why = "no M584 maps the anchors' motors: set your drives' node ids"
    else:
        shown = ", ".join(format_driver(d.value) if d.value else "-" for d in cfg.drivers)
        why = (
            f"M584 drivers {shown} are not one ODrive CAN board each (1..{ODRIVE_NODE_MAX}): "
            "set your drives' node ids"
        )
    return tuple((i, why) for i in range(cfg.n))


def _reels(cfg: HangprinterConfig, flex: bool, remarks: list[str]) -> tuple[ReelDraft, ...]:
    q = cfg.buildup_factor_mm
    s = cfg.spring_k_per_unit_length_n
    guys = _guy_wires_m(cfg)
    nodes = _node_ids(cfg)
    if nodes[0][1].startswith(("no M584", "M584 drivers")):
        remarks.append(f"node ids 0..{cfg.n - 1}: {nodes[0][1]}")
    reels = []
    for i, letter in enumerate(cfg.letters):
        a = cfg.anchors_mm[i]
        anchor = (_r(a.value[0] / 1000.0), _r(a.value[1] / 1000.0), _r(a.value[2] / 1000.0))
        radius = cfg.spool_radius_mm[i]
        u = cfg.mechanical_advantage[i]
        o = cfg.lines_per_spool[i]
        teeth_l, teeth_h = cfg.motor_gear_teeth[i], cfg.spool_gear_teeth[i]
        direction = cfg.directions[i]
        ref_m = _r(math.hypot(*a.value) / 1000.0)
        factor_m = _r(q.value * o.value / 1000.0)
        gear = _r(teeth_h.value / teeth_l.value)
        node_id, node_why = nodes[i]
        entries = [
            Entry("node_id", node_id, node_why),
            Entry("anchor_m", anchor, f"M669 {_from(a)}"),
            Entry("drum_radius_m", _r(radius.value / 1000.0), _item("R", radius, " mm")),
            Entry(
                "gear_ratio",
                gear,
                f"motor turns per spool turn: M666 H{teeth_h.value} / L{teeth_l.value} "
                f"({_where2(teeth_h, teeth_l)})",
            ),
            Entry(
                "direction",
                direction.value,
                "M569 "
                + (_from(direction) if not direction.where.default else "S1, the default")
                + (": backwards" if direction.value < 0 else ": forwards"),
            ),
            Entry("mechanical_advantage", float(u.value), _item("U", u)),
            Entry(
                "spool_buildup_factor_m",
                factor_m,
                f"M666 Q{q.value:g} mm x O{o.value} ({_where2(q, o)})",
            ),
            Entry(
                "reference_length_m",
                ref_m,
                "the anchor's distance from the origin, where the spool radius is R",
            ),
        ]
        ea: float | None = None
        if flex:
            g_m, g_why = guys[i]
            length_m = ref_m * u.value
            ea = float(round(s.value * length_m / (length_m + g_m)))
            how = (
                f"M666 S{s.value:g} N ({_where1(s)})"
                if g_m == 0.0
                else f"M666 S{s.value:g} N x U.L/(U.L+g) at the origin, guy wire g {g_why}"
            )
            entries.append(Entry("cable_ea_n", ea, how))
        reels.append(
            ReelDraft(
                letter=letter,
                entries=tuple(entries),
                node_id=node_id,
                anchor_m=anchor,
                drum_radius_m=_r(radius.value / 1000.0),
                gear_ratio=gear,
                direction=direction.value,
                mechanical_advantage=float(u.value),
                buildup_factor_m=factor_m,
                reference_length_m=ref_m,
                cable_ea_n=ea,
            )
        )
    return tuple(reels)


def _item(letter: str, v: Value[Any], unit: str = "") -> str:
    """One anchor's value of a per-anchor parameter: ``M666 R75.546 mm (config.g:21)``."""
    return f"M666 {letter}{v.value:g}{unit} ({_where1(v)})"


def _where1(v: Value[Any]) -> str:
    return "RepRapFirmware's default" if v.where.default else str(v.where)


def _where2(a: Value[Any], b: Value[Any]) -> str:
    wa, wb = _where1(a), _where1(b)
    return wa if wa == wb else f"{wa}; {wb}"


def _max_cable_m(cfg: HangprinterConfig, floor_m: float) -> float:
    """The longest line the workspace can need, with `CABLE_RANGE_SPARE`: any workspace lies in
    the prism of the anchors' plan view between the floor and the highest anchor, whose
    farthest point from an anchor is one of its corners."""
    points = [tuple(c / 1000.0 for c in a.value) for a in cfg.anchors_mm]
    top = max(max(p[2] for p in points), floor_m)
    corners = [(p[0], p[1], z) for p in points for z in (floor_m, top)]
    longest = max(math.dist(a, c) for a in points for c in corners)
    return math.ceil(longest * CABLE_RANGE_SPARE * 100.0) / 100.0


def _limits(cfg: HangprinterConfig, remarks: list[str]) -> tuple[Entry, ...]:
    out = []
    if cfg.z_min_mm.value is None:
        floor = 0.0
        out.append(Entry("floor_z_m", floor, "no M208 S1 Z: RepRapFirmware's default Z minimum"))
    else:
        floor = _r(cfg.z_min_mm.value / 1000.0)
        out.append(Entry("floor_z_m", floor, f"M208 {_from(cfg.z_min_mm)}"))
    if cfg.z_max_mm.value is not None:
        out.append(
            Entry("ceiling_z_m", _r(cfg.z_max_mm.value / 1000.0), f"M208 {_from(cfg.z_max_mm)}")
        )
    else:
        remarks.append("no M208 Z maximum: no limits.ceiling_z_m (the anchors bound the top)")
    pr = cfg.print_radius_mm
    why = f"M669 {_from(pr)}"
    if pr.where.default:
        why = f"no M669 P: RepRapFirmware's default {pr.value:g} mm"
    out.append(Entry("print_radius_m", _r(pr.value / 1000.0), why))
    out.append(Entry("xy_margin_m", XY_MARGIN_M, "cablebot's own: RepRapFirmware has none"))
    out.append(Entry("top_margin_m", TOP_MARGIN_M, "cablebot's own"))
    out.append(Entry("min_cable_m", MIN_CABLE_M, "cablebot's own: RepRapFirmware has none"))
    out.append(
        Entry(
            "max_cable_m",
            _max_cable_m(cfg, floor),
            f"{CABLE_RANGE_SPARE - 1:.0%} beyond the longest line between the floor and the "
            "highest anchor",
        )
    )
    f = cfg.max_feedrate_mm_per_min
    if f.value is None:
        speed = CAUTIOUS_SPEED_MPS
        out.append(Entry("max_speed_mps", speed, "no M203 X Y Z: a cautious start"))
    else:
        speed = _r(f.value / 60000.0)
        out.append(Entry("max_speed_mps", speed, f"{f.text} mm/min ({f.where}): the least"))
    acc = cfg.max_accel_mm_per_s2
    if acc.value is None:
        out.append(Entry("max_accel_mps2", CAUTIOUS_ACCEL_MPS2, "no M201 X Y Z: a cautious start"))
    else:
        out.append(
            Entry(
                "max_accel_mps2",
                _r(acc.value / 1000.0),
                f"{acc.text} mm/s² ({acc.where}): the least",
            )
        )
    out.append(
        Entry(
            "max_cable_speed_mps",
            speed,
            "max_speed_mps: no line changes length faster than the effector moves",
        )
    )
    return tuple(out)


def _tensions(cfg: HangprinterConfig) -> tuple[Entry, ...]:
    lo = max(range(cfg.n), key=lambda i: cfg.min_force_n[i].value)
    hi = min(range(cfg.n), key=lambda i: cfg.max_force_n[i].value)
    i_min, x_max = cfg.min_force_n[lo], cfg.max_force_n[hi]
    return (
        Entry("min_tension_n", _r(i_min.value), f"{_item('I', i_min, ' N')}: the largest"),
        Entry("max_tension_n", _r(x_max.value), f"{_item('X', x_max, ' N')}: the least"),
    )


def _defaults_used(cfg: HangprinterConfig) -> list[str]:
    d = RRF_DEFAULTS
    used = []
    if cfg.buildup_factor_mm.where.default:
        used.append(f"Q{d.buildup_factor_mm:g}")
    for letter, values in (
        ("R", cfg.spool_radius_mm),
        ("U", cfg.mechanical_advantage),
        ("O", cfg.lines_per_spool),
        ("L", cfg.motor_gear_teeth),
        ("H", cfg.spool_gear_teeth),
    ):
        if any(v.where.default for v in values):
            used.append(letter + ":".join(f"{v.value:g}" for v in values))
    return used


def robot_draft(cfg: HangprinterConfig, *, name: str | None = None) -> RobotDraft:
    """The cablebot robot file for `cfg` (the module docstring has the mapping); `name` overrides
    the machine's M550 name. Raises nothing: every value of `cfg` is finite and in range."""
    remarks: list[str] = []
    defaults = _defaults_used(cfg)
    if defaults:
        remarks.append(f"RepRapFirmware's defaults used: M666 {' '.join(defaults)}")
    if cfg.print_radius_mm.where.default:
        remarks.append(
            f"no M669 P: RepRapFirmware's default print radius {cfg.print_radius_mm.value:g} mm"
        )
    if name is not None:
        name_entry = Entry("name", robot_name(name), "given to import-rrf")
    elif cfg.machine_name.value is not None:
        name_entry = Entry(
            "name", robot_name(cfg.machine_name.value), f"M550 {_from(cfg.machine_name)}"
        )
    else:
        name_entry = Entry("name", DEFAULT_NAME, "no M550 name")
    heights = [a.value[2] for a in cfg.anchors_mm]
    if cfg.anchor_mode.value == 1 and heights[-1] < max(heights):
        top = cfg.letters[heights.index(max(heights))]
        remarks.append(
            f"the last anchor ({cfg.letters[-1]}) is not the highest ({top} is): RepRapFirmware's "
            "last-on-top mode takes it to be; the reels keep the configuration's order"
        )
    payload = cfg.mover_mass_kg.value > 0.0
    flex = payload and cfg.flex_on
    if not payload:
        remarks.append(
            "M666 W is 0 (RepRapFirmware: no flex compensation): no [payload], so no tension "
            "limits and no cable stretch; give [payload] mass_kg and limits.min_tension_n / "
            "max_tension_n for cablebot to plan the tensions"
        )
    elif not flex:
        remarks.append(
            f"M666 {_from(cfg.flex_algorithm)} turns flex compensation off: rigid cables"
        )
    limits = _limits(cfg, remarks)
    if payload:
        limits = limits + _tensions(cfg)
    sections: list[tuple[str, tuple[Entry, ...]]] = [
        ("bus", (Entry("interface", "virtual"), Entry("channel", name_entry.value))),
        ("drive", (Entry("kind", "odrive"),)),
        ("limits", limits),
    ]
    if payload:
        mass = cfg.mover_mass_kg
        sections.append(("payload", (Entry("mass_kg", _r(mass.value), f"M666 {_from(mass)}"),)))
    sections.append(
        (
            "homing",
            (
                Entry(
                    "power_up_position_m",
                    (0.0, 0.0, 0.0),
                    "RepRapFirmware starts a Hangprinter at the origin",
                ),
            ),
        )
    )
    sections.append(
        (
            "gcode",
            (Entry("dialect", "reprapfirmware", "M203 in mm/min, as RepRapFirmware reads it"),),
        )
    )
    return RobotDraft(
        name=name_entry,
        sections=tuple(sections),
        reels=_reels(cfg, flex, remarks),
        remarks=tuple(remarks),
        unmapped=cfg.unmapped,
    )


# ------------------------------------------------------------------------------ TOML
def _toml(v: TomlValue) -> str:
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, tuple):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    if isinstance(v, int):
        return str(v)
    return repr(_r(v))


def _comment(text: str) -> str:
    """`text` safe inside a TOML comment (printable, one line)."""
    return "".join(c if c.isprintable() else " " for c in text)


def _line(e: Entry) -> str:
    text = f"{e.key} = {_toml(e.value)}"
    if not e.comment:
        return text
    return f"{text.ljust(_COMMENT_COLUMN - 1)} # {_comment(e.comment)}"


_BUS_NOTE = (
    "# The built-in simulator: `cablebot run --config` this file flies simulated ODrives on a\n"
    '# virtual bus inside the daemon. For the machine: its CAN bus (interface = "socketcan",\n'
    '# channel = "can0") and [sim] enabled = false.\n'
)


def robot_toml(draft: RobotDraft, sources: Sequence[str]) -> str:
    """The robot file's TOML text: the keys with their comments, a header naming `sources` (the
    configuration files read) and the remarks, and at the end every line or parameter that
    was not mapped, with the reason. Raises nothing."""
    n = len(draft.reels)
    letters = " ".join(r.letter for r in draft.reels)
    out = [
        "# cablebot robot file, imported by `cablebot import-rrf` from RepRapFirmware's",
        f"# Hangprinter configuration {_comment(', '.join(sources))}: {n} anchors ({letters}),",
        "# the last on top. RepRapFirmware's millimetres are metres here. Every line and parameter",
        "# not used is listed at the end, with the reason. Check the file with",
        "# `cablebot check-config`, and each reel's direction on the machine, before flying.",
    ]
    out += [f"# Note: {_comment(r)}" for r in draft.remarks]
    out += ["", _line(draft.name)]
    for section, entries in draft.sections:
        out += ["", f"[{section}]"]
        if section == "bus":
            out.append(_BUS_NOTE.rstrip("\n"))
        out += [_line(e) for e in entries]
    for reel in draft.reels:
        out += ["", f"# anchor {reel.letter}", "[[reels]]"]
        out += [_line(e) for e in reel.entries]
    if draft.unmapped:
        out += ["", "# Not mapped from the configuration, and why:"]
        out += [f"# {_comment(str(u))}" for u in draft.unmapped]
    return "\n".join(out) + "\n"
