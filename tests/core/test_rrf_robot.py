"""A cablebot robot file from a RepRapFirmware Hangprinter configuration
(`controller.core.rrf_robot`): the reference anchors to 0.01 mm, the motor turns of
RepRapFirmware's spool model, the flex, limits and node id mappings, and TOML that reads back
to the same values."""

from __future__ import annotations

import math
import tomllib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.core.rrf import HangprinterConfig, RrfError, read_rrf
from controller.core.rrf_robot import (
    CABLE_RANGE_SPARE,
    DEFAULT_NAME,
    RobotDraft,
    robot_draft,
    robot_name,
    robot_toml,
)
from tests.core.test_rrf import ANCHORS_LINE, FIVE, GARBAGE, HP4, HP4_ANCHORS_MM

MICROSTEPS = 16
"""Any microstepping: RepRapFirmware's steps per motor turn are J x microsteps."""
LINE_LENGTHS_M = (1.0, 2.0, 3.0)


def read(text: str) -> HangprinterConfig:
    return read_rrf([("config.g", text)])


def draft(text: str, **kw: str) -> RobotDraft:
    return robot_draft(read(text), **kw)


def entries(d: RobotDraft, section: str) -> dict[str, object]:
    return {e.key: e.value for s, es in d.sections if s == section for e in es}


def rrf_motor_steps(cfg: HangprinterConfig, i: int, length_mm: float) -> float:
    """RepRapFirmware's motor position (steps) of anchor `i`'s motor at line length
    `length_mm`, its spool model written out from HangprinterKinematics.cpp (Recalc,
    CartesianToMotorSteps; flex compensation aside), in its own units (mm, steps):

        stepsPerUnitTimesR = U * J * microsteps * H / (2 pi L)
        k2 = -U * O * Q,  k0 = 2 * stepsPerUnitTimesR / k2
        linePos = length - |anchor|          (distancesOrigin)
        steps = k0 * (sqrt(R^2 + linePos * k2) - R)
    """
    u = cfg.mechanical_advantage[i].value
    j = cfg.full_steps_per_rev[i].value
    h, teeth_l = cfg.spool_gear_teeth[i].value, cfg.motor_gear_teeth[i].value
    o, q = cfg.lines_per_spool[i].value, cfg.buildup_factor_mm.value
    r = cfg.spool_radius_mm[i].value
    steps_per_unit_times_r = u * j * MICROSTEPS * h / (2.0 * math.pi * teeth_l)
    k2 = -(u * o) * q
    k0 = 2.0 * steps_per_unit_times_r / k2
    line_pos = length_mm - math.sqrt(sum(c * c for c in cfg.anchors_mm[i].value))
    return k0 * (math.sqrt(r * r + line_pos * k2) - r)


def rrf_turns_per_metre(cfg: HangprinterConfig, i: int, length_mm: float) -> float:
    """d(steps)/d(length) of the same formula, as motor turns per metre of line."""
    u = cfg.mechanical_advantage[i].value
    j = cfg.full_steps_per_rev[i].value
    o, q = cfg.lines_per_spool[i].value, cfg.buildup_factor_mm.value
    r = cfg.spool_radius_mm[i].value
    h, teeth_l = cfg.spool_gear_teeth[i].value, cfg.motor_gear_teeth[i].value
    k2 = -(u * o) * q
    k0 = 2.0 * (u * j * MICROSTEPS * h / (2.0 * math.pi * teeth_l)) / k2
    line_pos = length_mm - math.sqrt(sum(c * c for c in cfg.anchors_mm[i].value))
    steps_per_mm = k0 * k2 / (2.0 * math.sqrt(r * r + line_pos * k2))
    return steps_per_mm * 1000.0 / (j * MICROSTEPS)


def test_the_reference_anchors_come_out_within_0_01_mm() -> None:
    d = draft(HP4)
    worst = max(
        abs(reel.anchor_m[k] * 1000.0 - HP4_ANCHORS_MM[i][k])
        for i, reel in enumerate(d.reels)
        for k in range(3)
    )
    assert worst <= 1e-9  # far inside 0.01 mm: the mm values, divided by 1000
    assert [r.letter for r in d.reels] == ["A", "B", "C", "D"]


@pytest.mark.parametrize("text", [HP4, ANCHORS_LINE, FIVE], ids=["reference", "defaults", "five"])
def test_motor_turns_agree_with_repraps_spool_model(text: str) -> None:
    """At three line lengths per anchor, the reel model of the robot file (homed at the origin,
    as RepRapFirmware counts) turns the motor as RepRapFirmware's spool formula does, and
    the turns per metre agree: RepRapFirmware's steps over J x microsteps, its direction
    (M569) applied."""
    cfg = read(text)
    d = robot_draft(cfg)
    for i, reel in enumerate(d.reels):
        model = reel.model()
        j = cfg.full_steps_per_rev[i].value
        for length_m in LINE_LENGTHS_M:
            turns = model.position_rev(length_m) * reel.direction
            expected = rrf_motor_steps(cfg, i, length_m * 1000.0) / (j * MICROSTEPS)
            assert turns == pytest.approx(expected, rel=1e-9, abs=1e-9)
            per_m = reel.direction / model.length_rate_mps(model.position_rev(length_m), 1.0)
            assert per_m == pytest.approx(rrf_turns_per_metre(cfg, i, length_m * 1000), rel=1e-9)
        assert model.position_rev(reel.reference_length_m) == 0.0  # motor turn 0 at the origin


def test_the_reference_spools_numbers() -> None:
    """Hand-derived for anchor A: 255/20 gear, 2:1 block, 75.546 mm at the origin: at the
    origin 2 x 12.75 / (2 pi x 0.075546) = 53.72 motor turns per metre of line."""
    d = draft(HP4)
    a = d.reels[0]
    model = a.model()
    assert a.gear_ratio == 12.75 and a.mechanical_advantage == 2.0
    assert a.drum_radius_m == 0.075546
    assert a.buildup_factor_m == pytest.approx(0.128181e-3, rel=1e-12)
    at_origin = 1.0 / model.length_rate_mps(0.0, 1.0)
    assert at_origin == pytest.approx(2 * 12.75 / (2 * math.pi * 0.075546), rel=1e-12)
    assert at_origin == pytest.approx(53.72, abs=0.005)
    # line out: the spool empties, its radius falls, more turns per metre
    assert 1.0 / model.length_rate_mps(model.position_rev(3.0), 1.0) > at_origin
    assert [r.direction for r in d.reels] == [1, 1, -1, -1]
    assert [r.node_id for r in d.reels] == [40, 41, 42, 43]


def test_flex_maps_to_the_cable_stiffness_repraps_way() -> None:
    """RepRapFirmware moves the effector F (U L + g) / (S U) under a force F; cablebot's
    stretch is L F / EA: EA = S U L / (U L + g) at the origin, S without a guy wire."""
    d = draft(HP4)
    a, top = HP4_ANCHORS_MM[0], HP4_ANCHORS_MM[3]
    length = math.dist(a, (0, 0, 0)) / 1000.0
    guy = math.dist(a, top) / 1000.0
    assert d.reels[0].cable_ea_n == round(20000.0 * 2 * length / (2 * length + guy))
    assert d.reels[0].cable_ea_n == 10514.0
    assert d.reels[3].cable_ea_n == 20000.0  # the top anchor: no guy wire
    # guy wires given (0: spools on their anchors), or another anchor mode: EA = S
    for extra in ("M666 Y0:0:0:0", "M666 A0"):
        d = draft(HP4 + "\n" + extra)
        assert [r.cable_ea_n for r in d.reels] == [20000.0] * 4, extra
    d = draft(HP4 + "\nM666 Y1000:1000:1000:0")
    assert d.reels[1].cable_ea_n == round(
        20000.0 * 2 * d.reels[1].reference_length_m / (2 * d.reels[1].reference_length_m + 1.0)
    )
    # flex off: the payload stays, the cables are rigid
    d = draft(HP4 + "\nM666 F0")
    assert entries(d, "payload") == {"mass_kg": 1.0}
    assert all(r.cable_ea_n is None for r in d.reels)
    assert any("turns flex compensation off" in r for r in d.remarks)
    # no mover mass: no payload, no tension limits, no stretch
    d = draft(ANCHORS_LINE)
    assert entries(d, "payload") == {}
    assert "min_tension_n" not in entries(d, "limits")
    assert all(r.cable_ea_n is None for r in d.reels)
    assert any("M666 W is 0" in r for r in d.remarks)


def test_limits_of_the_reference() -> None:
    d = draft(HP4)
    lim = entries(d, "limits")
    assert lim["floor_z_m"] == -0.01 and lim["ceiling_z_m"] == 2.0
    assert lim["print_radius_m"] == 2.0
    assert lim["max_speed_mps"] == 0.6 and lim["max_cable_speed_mps"] == 0.6
    assert lim["max_accel_mps2"] == 10.0
    assert lim["min_tension_n"] == 0.0 and lim["max_tension_n"] == 70.0
    # every line the anchors' plan view can need between the floor and the top anchor fits
    points = [tuple(c / 1000 for c in a) for a in HP4_ANCHORS_MM]
    corners = [(p[0], p[1], z) for p in points for z in (-0.01, 2.29983)]
    longest = max(math.dist(p, q) for p in points for q in corners)
    assert longest == pytest.approx(math.dist(points[0], corners[3]))  # A to above B
    assert longest * CABLE_RANGE_SPARE <= lim["max_cable_m"] < longest * CABLE_RANGE_SPARE + 0.01
    assert entries(d, "homing") == {"power_up_position_m": (0.0, 0.0, 0.0)}
    assert entries(d, "gcode") == {"dialect": "reprapfirmware"}


def test_limits_without_m208_m201_m203_and_the_strictest_forces() -> None:
    d = draft(ANCHORS_LINE + "\nM666 W2 I1:5:2:0 X70:60:80:90")
    lim = entries(d, "limits")
    assert lim["floor_z_m"] == 0.0 and "ceiling_z_m" not in lim
    assert lim["print_radius_m"] == 1.5  # RepRapFirmware's default
    assert lim["max_speed_mps"] == 0.1 and lim["max_accel_mps2"] == 1.0
    assert lim["min_tension_n"] == 5.0 and lim["max_tension_n"] == 60.0
    assert any("no M208 Z maximum" in r for r in d.remarks)
    assert any("default print radius 1500 mm" in r for r in d.remarks)
    assert any("RepRapFirmware's defaults used: M666 Q0.007 R75:75:75:75" in r for r in d.remarks)


def test_node_ids_fall_back_when_not_one_odrive_board_each() -> None:
    d = draft(ANCHORS_LINE)
    assert [r.node_id for r in d.reels] == [0, 1, 2, 3]
    assert any("no M584 maps the anchors' motors" in r for r in d.remarks)
    d = draft(ANCHORS_LINE + "\nM584 X0 Y1 Z2 U3")  # steppers on the main board
    assert [r.node_id for r in d.reels] == [0, 1, 2, 3]
    assert any("M584 drivers 0, 1, 2, 3 are not one ODrive CAN board each" in r for r in d.remarks)
    d = draft(ANCHORS_LINE + "\nM584 X40.0 Y40.1 Z42.0 U43.0")  # two axes on one board
    assert [r.node_id for r in d.reels] == [0, 1, 2, 3]


def test_names() -> None:
    assert draft(HP4).name.value == "hp4-lab"
    assert draft(HP4, name="my printer").name.value == "my-printer"
    assert draft(ANCHORS_LINE).name.value == DEFAULT_NAME
    assert robot_name('a"b\nc]d') == "a-b-c-d"
    assert robot_name("..") == DEFAULT_NAME
    assert robot_name("x" * 100) == "x" * 63


def all_finite(v: object) -> bool:
    if isinstance(v, float):
        return math.isfinite(v)
    if isinstance(v, dict):
        return all(all_finite(x) for x in v.values())
    if isinstance(v, list):
        return all(all_finite(x) for x in v)
    return True


def test_the_toml_reads_back_to_the_draft() -> None:
    d = draft(HP4)
    text = robot_toml(d, ["config.g"])
    data = tomllib.loads(text)
    assert data["name"] == "hp4-lab"
    assert data["bus"] == {"interface": "virtual", "channel": "hp4-lab"}
    for s, es in d.sections:
        for e in es:
            v = data[s][e.key]
            assert (tuple(v) if isinstance(v, list) else v) == e.value, (s, e.key)
    assert len(data["reels"]) == 4
    for table, reel in zip(data["reels"], d.reels, strict=True):
        assert tuple(table["anchor_m"]) == reel.anchor_m
        for e in reel.entries:
            v = table[e.key]
            assert (tuple(v) if isinstance(v, list) else v) == e.value, e.key
    assert all_finite(data)
    # the unmapped lines are listed at the end, each with its reason
    tail = text.split("# Not mapped from the configuration, and why:\n")[1].splitlines()
    assert len(tail) == len(d.unmapped)
    assert (
        tail[0]
        == "# config.g:6 G21: G-code units: a job sets its own ([gcode] units, mm by default)"
    )


def test_a_hostile_name_and_source_stay_inside_their_strings_and_comments() -> None:
    d = draft('M550 P"x"" ]  [bus] = 1"\n' + ANCHORS_LINE)
    text = robot_toml(d, ["evil\nname = 1.g"])
    data = tomllib.loads(text)  # still one valid file
    assert data["name"] == "x-bus-1"
    assert text.splitlines()[1].startswith("# Hangprinter configuration evil name = 1.g:")
    assert set(data) == {"name", "bus", "drive", "limits", "homing", "gcode", "reels"}


def test_a_last_anchor_below_another_is_remarked() -> None:
    d = draft(ANCHORS_LINE.replace("D0:0:2299.83", "D0:0:-100").replace("-121.28", "2000"))
    assert any("the last anchor (D) is not the highest (B is)" in r for r in d.remarks)
    assert not any("is not the highest" in r for r in draft(HP4).remarks)


@settings(max_examples=200, deadline=None)
@given(st.lists(GARBAGE, max_size=8), st.integers(0, 60))
def test_any_readable_configuration_gives_a_toml_file_of_finite_numbers(
    lines: list[str], at: int
) -> None:
    base = HP4.splitlines()
    try:
        cfg = read("\n".join(base[:at] + lines + base[at:]))
    except RrfError:
        return
    d = robot_draft(cfg)
    data = tomllib.loads(robot_toml(d, ["config.g"]))
    assert all_finite(data)
    assert len(data["reels"]) == cfg.n
