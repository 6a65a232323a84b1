"""RepRapFirmware Hangprinter configurations read (`controller.core.rrf`): every value of the
reference configuration, RepRapFirmware's defaults, 4, 5 and 8 anchors, files read in order,
and every kind of line that makes a configuration unusable named by its line."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.core.rrf import (
    RRF_DEFAULTS,
    HangprinterConfig,
    RrfError,
    driver_words,
    read_rrf,
    written_out,
)

DATA = Path(__file__).resolve().parents[1] / "data"
HP4 = (DATA / "hangprinter-v4-config.g").read_text()
HP4_ANCHORS_MM = (
    (0.0, -1610.98, -131.53),
    (1314.22, 1268.14, -121.28),
    (-1415.73, 707.61, -121.82),
    (0.0, 0.0, 2299.83),
)
ANCHORS_LINE = (
    "M669 K6 A0:-1610.98:-131.53 B1314.22:1268.14:-121.28 C-1415.73:707.61:-121.82 D0:0:2299.83"
)
FIVE = (
    "M669 K6 N5 A0:-2000:-100 B2000:0:-100 C0:2000:-100 D-2000:0:-100 I0:0:3000\n"
    "M666 R75:75:75:75:76 U2:2:2:2:4\n"
)


def read(text: str) -> HangprinterConfig:
    return read_rrf([("config.g", text)])


def problems(text: str, *more: tuple[str, str]) -> list[str]:
    with pytest.raises(RrfError) as info:
        read_rrf([("config.g", text), *more])
    return [str(p) for p in info.value.problems]


def test_the_reference_configuration_is_read_whole() -> None:
    c = read(HP4)
    assert c.n == 4 and c.letters == "ABCD"
    assert [a.value for a in c.anchors_mm] == list(HP4_ANCHORS_MM)
    assert str(c.anchors_mm[0].where) == "config.g:20"
    assert c.print_radius_mm.value == 2000.0
    assert c.buildup_factor_mm.value == 0.128181
    assert [v.value for v in c.spool_radius_mm] == [75.546, 75.659, 76.128, 75.192]
    assert [v.value for v in c.mechanical_advantage] == [2, 2, 2, 4]
    assert [v.value for v in c.lines_per_spool] == [1, 1, 1, 1]
    assert [v.value for v in c.motor_gear_teeth] == [20] * 4
    assert [v.value for v in c.spool_gear_teeth] == [255] * 4
    assert [v.value for v in c.full_steps_per_rev] == [25] * 4
    assert c.mover_mass_kg.value == 1.0
    assert c.spring_k_per_unit_length_n.value == 20000.0
    assert [v.value for v in c.min_force_n] == [0.0] * 4
    assert [v.value for v in c.max_force_n] == [70.0] * 4
    assert all(v.where.default and v.value < 0 for v in c.guy_wire_mm)  # derived (3.6)
    assert c.flex_on
    assert (c.z_min_mm.value, c.z_max_mm.value) == (-10.0, 2000.0)
    assert c.max_feedrate_mm_per_min.value == 36000.0
    assert c.max_accel_mm_per_s2.value == 10000.0
    assert [d.value for d in c.drivers] == [(40, 0), (41, 0), (42, 0), (43, 0)]
    assert [d.value for d in c.directions] == [1, 1, -1, -1]
    assert c.machine_name.value == "hp4-lab"


def test_the_reference_configuration_lists_what_it_does_not_map() -> None:
    c = read(HP4)
    shown = [str(u) for u in c.unmapped]
    lines = [u.where.line_no for u in c.unmapped]
    assert lines == sorted(lines)
    assert (
        "config.g:6 G21: G-code units: a job sets its own ([gcode] units, mm by default)" in shown
    )
    assert any(s.startswith("config.g:19 M669 S430 T0.1: segmentation") for s in shown)
    assert any(s.startswith("config.g:36 M666 T10: target force") for s in shown)
    assert any(s.startswith("config.g:40 M569 P0 S1: this driver moves no anchor") for s in shown)
    assert any(s.startswith("config.g:48 M201 U10000 E1000: not the effector's") for s in shown)
    assert any(s.startswith("config.g:57 M308 S1") for s in shown)
    assert any(s.startswith("config.g:65 T0: not a motion setting") for s in shown)
    # what is mapped is not listed
    assert not any(" M669 A" in s or " M666 Q" in s or " M208 " in s for s in shown)
    # every line holding a command is either mapped or listed
    mapped = {9, 13, 17, 18, 20, 21, 23, 24, 26, 27, 28, 29, 32, 33, 34, 35, 39, 42, 43, 44, 45}
    for n, line in enumerate(HP4.splitlines(), start=1):
        if line.split(";")[0].strip():
            assert n in mapped or n in lines, (n, line)


def test_repraps_defaults_fill_what_the_configuration_leaves_out() -> None:
    c = read(ANCHORS_LINE)
    d = RRF_DEFAULTS
    assert c.buildup_factor_mm.value == d.buildup_factor_mm == 0.007
    assert c.buildup_factor_mm.where.default
    assert [v.value for v in c.spool_radius_mm] == [75.0] * 4
    assert [v.value for v in c.mechanical_advantage] == [2, 2, 2, 2]  # 3.6: D too, unless set
    assert [v.value for v in c.spool_gear_teeth] == [255] * 4
    assert c.print_radius_mm.value == 1500.0 and c.print_radius_mm.where.default
    assert c.mover_mass_kg.value == 0.0 and not c.flex_on
    assert c.z_min_mm.value is None and c.z_max_mm.value is None
    assert c.max_feedrate_mm_per_min.value is None
    assert all(d.value is None for d in c.drivers)
    assert all(d.value == 1 for d in c.directions)


def test_five_anchors_four_low_one_high() -> None:
    c = read(FIVE)
    assert c.n == 5 and c.letters == "ABCDI"
    assert c.anchors_mm[4].value == (0.0, 0.0, 3000.0)
    assert [v.value for v in c.mechanical_advantage] == [2, 2, 2, 2, 4]
    assert [v.value for v in c.spool_radius_mm] == [75.0, 75.0, 75.0, 75.0, 76.0]


def test_eight_anchors_take_repraps_3_7_letters() -> None:
    ring = " ".join(
        f"{letter}{1000 * math.cos(k):.3f}:{1000 * math.sin(k):.3f}:-100"
        for letter, k in zip("ABCDIJL", [2 * math.pi * i / 7 for i in range(7)], strict=True)
    )
    c = read(f"M669 K6 N8 {ring} O0:0:2500\nM584 X40.0 Y41.0 Z42.0 U43.0 V44.0 W45.0 A46.0 B47.0")
    assert c.n == 8 and c.letters == "ABCDIJLO"
    assert c.anchors_mm[7].value == (0.0, 0.0, 2500.0)
    assert [d.value[0] for d in c.drivers if d.value] == list(range(40, 48))


def test_later_lines_and_files_win_and_keep_their_order() -> None:
    override = ("config-override.g", "M669 K6 D0:0:2400\nM666 Q0.01 R70:70:70:70\nG21\n")
    c = read_rrf([("config.g", HP4), override])
    assert c.anchors_mm[3].value == (0.0, 0.0, 2400.0)
    assert str(c.anchors_mm[3].where) == "config-override.g:1"
    assert c.anchors_mm[0].value == HP4_ANCHORS_MM[0]
    assert c.buildup_factor_mm.value == 0.01
    assert [v.value for v in c.spool_radius_mm] == [70.0] * 4
    sources = [u.where.source for u in c.unmapped]
    assert sources[-1] == "config-override.g" and sources[0] == "config.g"


def test_m208_min_max_pair_and_both_forms() -> None:
    c = read(ANCHORS_LINE + "\nM208 Z-5:1800")
    assert (c.z_min_mm.value, c.z_max_mm.value) == (-5.0, 1800.0)
    c = read(ANCHORS_LINE + "\nM208 S1 Z-5 X-100\nM208 Z1700")
    assert (c.z_min_mm.value, c.z_max_mm.value) == (-5.0, 1700.0)
    assert any("M208 X-100: RepRapFirmware limits" in str(u) for u in c.unmapped)


def test_flex_compensation_follows_w_and_f() -> None:
    assert read(ANCHORS_LINE + "\nM666 W0.5").flex_on
    assert not read(ANCHORS_LINE + "\nM666 W0.5 F0").flex_on
    assert read(ANCHORS_LINE + "\nM666 W0.5 F1").flex_on
    assert not read(ANCHORS_LINE + "\nM666 F2").flex_on  # no mover mass


def test_driver_ids_are_read_as_written() -> None:
    assert driver_words("M584 X40.0 Y1 Z1.2:3 ; X9") == {
        "M": ((0, 584),),
        "X": ((40, 0),),
        "Y": ((0, 1),),
        "Z": ((1, 2), (0, 3)),
    }
    c = read(ANCHORS_LINE + "\nM584 X1.0 Y1 Z2.0:2.1 U3.0\nM569 P1.0 S0\nM569 P1 S1")
    assert [d.value for d in c.drivers] == [(1, 0), (0, 1), (2, 0), (3, 0)]
    assert [d.value for d in c.directions] == [-1, 1, 1, 1]
    assert any("several drivers on one axis" in str(u) for u in c.unmapped)
    c = read(ANCHORS_LINE + "\nM584 X40.0 Y41.0 Z42.0 U43.0 V44.0")
    assert "config.g:2 M584 V44.0: not an anchor's motor (N4)" in [str(u) for u in c.unmapped]


BAD = [
    ("M669 K5", 1, "M669 K5: not a Hangprinter (K6)"),
    ("M669 K6 A0:-1610,98:-131.53", 1, "cannot read the line: column 17: cannot read ',98"),
    (ANCHORS_LINE.replace("A0:-1610.98:-131.53", "A0:-1610.98"), 1, "an anchor is X:Y:Z in mm"),
    (ANCHORS_LINE + " I0:0:3000", 1, "M669 I: anchor 5, but N is 4 (RepRapFirmware reads A B C D"),
    (ANCHORS_LINE + "\nM666 R75:75:75", 2, "M666 R: 3 values, RepRapFirmware expects 4"),
    (ANCHORS_LINE + "\nM666 R75:75:75:75:75", 2, "5 values, RepRapFirmware expects 4"),
    (ANCHORS_LINE + "\nM666 U2.5:2:2:4", 2, "every value must be whole numbers >= 1"),
    (ANCHORS_LINE + "\nM666 R0:75:75:75", 2, "every value must be > 0"),
    (ANCHORS_LINE + "\nM666 Q-0.1", 2, "M666 Q-0.1: must be >= 0"),
    (ANCHORS_LINE + "\nM666 Q", 2, "M666 Q: needs one number, no value"),
    (ANCHORS_LINE + "\nM666 W-1", 2, "M666 W-1: must be >= 0"),
    (ANCHORS_LINE + "\nM666 S0", 2, "M666 S0: must be > 0"),
    (ANCHORS_LINE + "\nM669 N9", 2, "M669 N9: must be >= 3 and <= 8"),
    ("M666 Q0.1\n" + ANCHORS_LINE, 1, "M666 before M669 K6"),
    (ANCHORS_LINE.replace(" D0:0:2299.83", ""), 0, "M669 gives no anchor D (anchor 4 of N4)"),
    (ANCHORS_LINE.replace("D0:0:2299.83", "D0:0:0"), 1, "an anchor at the origin"),
    ("; nothing here\nG21\n", 0, "no M669 K6: not a RepRapFirmware Hangprinter configuration"),
    ("", 0, "no M669 K6"),
    ("if true\n" + ANCHORS_LINE, 1, "meta commands"),
    (ANCHORS_LINE.replace("A0:", "A99999999:"), 1, "beyond 1e+06 mm"),
    (ANCHORS_LINE + " A1:2:3", 1, "A given twice"),
    ("N1 M669 K6*99\n" + ANCHORS_LINE, 1, "checksum 99 does not match"),
    (ANCHORS_LINE.replace("A0:", "A" + "9" * 400 + ":"), 1, "out of range"),
    (ANCHORS_LINE + "\nM208 Z2000:-10", 2, "the minimum is not below the maximum"),
    (ANCHORS_LINE + "\nM584 X40.0 Y", 2, "M584 Y: not a driver number"),
    (ANCHORS_LINE + '\nM569 P"x" S0', 2, "not a driver number"),
    (ANCHORS_LINE + "\nM569 P40.0 S3", 2, "M569 S3: must be >= 0 and <= 1"),
]


@pytest.mark.parametrize(("text", "line_no", "reason"), BAD, ids=[b[2][:40] for b in BAD])
def test_each_unusable_line_is_named(text: str, line_no: int, reason: str) -> None:
    found = problems(text)
    hit = [p for p in found if reason in p]
    assert hit, found
    prefix = f"config.g:{line_no}: " if line_no else "config.g: "
    assert hit[0].startswith(prefix), hit[0]


def test_every_problem_is_collected_at_once() -> None:
    text = "\n".join([ANCHORS_LINE, "M666 R1:2", "G21", "M666 U2:2:x:2", "M669 K4", "M208 Z"])
    found = problems(text)
    assert [p.split(":")[1] for p in found] == ["2", "4", "5", "6"], found


def test_a_problem_shows_the_line_as_written_and_clipped() -> None:
    found = problems("M669 K7 ; " + "x" * 200)
    assert found[0].startswith("config.g:1: M669 K7: not a Hangprinter")
    assert "('M669 K7 ; xxx" in found[0] and found[0].endswith("...')")


GARBAGE = st.text(
    alphabet=st.sampled_from(list('GMNKTABCDIJLOPQRSUVWXYZ0123456789.:-+ ;"{}()*\t')),
    max_size=40,
)


@settings(max_examples=300, deadline=None)
@given(st.lists(GARBAGE, max_size=8), st.integers(0, 60))
def test_any_text_is_read_or_refused_by_line(lines: list[str], at: int) -> None:
    """Whatever the file holds, the reader returns a configuration of finite values or raises
    RrfError naming lines; nothing else escapes."""
    base = HP4.splitlines()
    text = "\n".join(base[:at] + lines + base[at:])
    try:
        c = read(text)
    except RrfError as exc:
        assert exc.problems and all(str(p) for p in exc.problems)
        return
    for a in c.anchors_mm:
        assert all(math.isfinite(x) for x in a.value)
    for group in (c.spool_radius_mm, c.min_force_n, c.max_force_n):
        assert all(math.isfinite(v.value) for v in group)
    assert math.isfinite(c.buildup_factor_mm.value) and c.buildup_factor_mm.value >= 0.0


def test_numbers_with_an_exponent_are_read_as_reprapfirmware_reads_them() -> None:
    """RepRapFirmware reads `S2e4` as 20000: so does the import, where the G-code parser
    alone would read `S2` and an `E4` word (a 2 N/m spring: lines of EA 1 N)."""
    from controller.core.gcode import numbered

    c = read(HP4.replace("M666 S20000.0", "M666 S2e4").replace("D0:0:2299.83", "D0:0:2.29983E3"))
    assert c.spring_k_per_unit_length_n.value == 20000.0
    assert c.anchors_mm[3].value == (0.0, 0.0, 2299.83)
    assert not any(u.where.line_no in (20, 33) for u in c.unmapped)  # no E word left over
    c = read(HP4 + "\nM666 Q1.28181e-1 W+1e0 X7e1:7e1:7.0e+1:70\nM208 Z2e3")
    assert c.buildup_factor_mm.value == 0.128181 and c.mover_mass_kg.value == 1.0
    assert [v.value for v in c.max_force_n] == [70.0] * 4
    assert c.z_max_mm.value == 2000.0
    # a checksum is checked on the line as written
    c = read(HP4 + "\n" + numbered(7, "M666 S2.5e4"))
    assert c.spring_k_per_unit_length_n.value == 25000.0
    assert "checksum" in problems(HP4 + "\nN7 M666 S2.5e4*1")[0]
    # other commands, quoted strings and comments are as the G-code parser reads them
    assert written_out('M550 P"hp4e5" ; S2e4') == 'M550 P"hp4e5" ; S2e4'
    assert written_out("M666 S1e400") == "M666 S1e400"
    assert written_out("M666 R7.5e1:.75E2 Y-1e-1") == "M666 R75.0:75.00 Y-0.1"
    c = read(HP4.replace("M584 X40.0 Y41.0", "M584 X40.0E0:1 Y41.0"))
    assert c.drivers[0].value == (40, 0)
