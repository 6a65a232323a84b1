"""The G-code interpreter: modal state to robot-frame motion, and the whole-job check."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.core.gcode import parse_lines
from controller.core.gcode_job import (
    Disarm,
    Dwell,
    Estop,
    GcodeFrame,
    Job,
    JobError,
    Limits,
    Motion,
    Sync,
    check_job,
    interpret,
)
from controller.core.statics import TensionCheck
from controller.core.workspace import Workspace
from controller.service.config import default_config

ORIGIN = (1.0, -2.0, 2.0)
FRAME = GcodeFrame(origin_m=ORIGIN, max_speed_mps=2.0, max_accel_mps2=1.0, arc_tolerance_m=1e-4)


def run(text: str, frame: GcodeFrame = FRAME, start: tuple[float, float, float] = ORIGIN) -> Job:
    return interpret(parse_lines(text.strip().splitlines()), frame, start)


def motions(job: Job) -> list[Motion]:
    return [a for a in job.actions if isinstance(a, Motion)]


def close(a: tuple[float, ...], b: tuple[float, ...], tol: float = 1e-9) -> bool:
    return all(abs(x - y) <= tol for x, y in zip(a, b, strict=True))


def test_g1_in_mm_from_the_origin_with_modal_feed() -> None:
    job = run("G21\nG90\nG1 X100 Y-50 F6000\nG1 Z10\n")
    m = motions(job)
    assert close(m[0].points_m[0], (1.1, -2.05, 2.0))
    assert m[0].speed_mps == pytest.approx(0.1)  # 6000 mm/min
    assert close(m[1].points_m[0], (1.1, -2.05, 2.01))
    assert m[1].speed_mps == pytest.approx(0.1)  # modal F
    assert job.moves == 2
    assert job.path_m == pytest.approx(math.hypot(0.1, 0.05) + 0.01)
    # the box of where the job goes, not of where it starts (the origin, x 1.0 y -2.0)
    assert close(job.bbox_m[0], (1.1, -2.05, 2.0)) and close(job.bbox_m[1], (1.1, -2.05, 2.01))


def test_the_box_of_a_job_without_motion_is_its_start() -> None:
    job = run("G21\nM104 S200\n", start=(0.5, 0.25, 3.0))
    assert job.bbox_m == ((0.5, 0.25, 3.0), (0.5, 0.25, 3.0))


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(*[st.floats(-1000.0, 1000.0, allow_nan=False)] * 3), min_size=1, max_size=8),
    st.tuples(*[st.floats(-5.0, 5.0, allow_nan=False)] * 3),
)
def test_the_box_is_that_of_the_motions_points_wherever_the_job_starts(
    targets_mm: list[tuple[float, float, float]], start: tuple[float, float, float]
) -> None:
    moves = "".join(f"G1 X{x:.4f} Y{y:.4f} Z{z:.4f}\n" for x, y, z in targets_mm)
    text = "G21\nG90\nF6000\n" + moves
    job = run(text, start=start)
    pts = [p for m in motions(job) for p in m.points_m]
    lo = tuple(min(p[i] for p in pts) for i in range(3))
    hi = tuple(max(p[i] for p in pts) for i in range(3))
    assert job.bbox_m == (lo, hi)


def test_relative_inches_and_g92() -> None:
    job = run("G20\nG91\nG1 X1 F60\nG1 X1\nG90\nG92 X0\nG1 X1\n")
    xs = [m.points_m[0][0] for m in motions(job)]
    assert xs == pytest.approx([1.0254, 1.0508, 1.0762])
    assert motions(job)[0].speed_mps == pytest.approx(0.0254)


def test_g0_without_f_is_rapid_and_with_f_sets_the_feed() -> None:
    job = run("G0 X10\nG0 X20 F600\nG1 X30\n", GcodeFrame(origin_m=ORIGIN, rapid_speed_mps=0.5))
    assert [m.speed_mps for m in motions(job)] == pytest.approx([0.5, 0.01, 0.01])


def test_feed_limited_by_m203_and_scaled_by_m220() -> None:
    job = run("M203 X50 Y60 Z2\nG1 X10 F6000\nM220 S50\nG1 X20\nM203 X900000\nG1 X30 F999999\n")
    lim = [a for a in job.actions if isinstance(a, Limits)]
    assert lim[0].max_speed_mps == pytest.approx(0.05)  # Z's 2 mm/s is not the robot's
    assert lim[1].max_speed_mps == pytest.approx(2.0)  # never above the configuration
    assert [m.speed_mps for m in motions(job)] == pytest.approx([0.05, 0.05, 2.0])


def test_m203_per_minute_in_reprapfirmware_dialect() -> None:
    frame = GcodeFrame(origin_m=ORIGIN, max_speed_mps=2.0, m203_per_minute=True)
    lim = [a for a in run("M203 X6000 Y6000\n", frame).actions if isinstance(a, Limits)]
    assert lim[0].max_speed_mps == pytest.approx(0.1)


def test_accelerations_lowered_never_raised() -> None:
    job = run("M201 X500 Y400 Z50\nM204 P300 T600\nM204 S5000\n")
    acc = [a.max_accel_mps2 for a in job.actions if isinstance(a, Limits)]
    assert acc == pytest.approx([0.4, 0.3, 1.0])


def test_arc_ij_quarter_circle_within_tolerance() -> None:
    # from (10, 0) counter-clockwise about (0, 0) to (0, 10): radius 10 mm
    job = run("G1 X10 Y0 F600\nG3 X0 Y10 I-10 J0\n")
    arc = motions(job)[1]
    cx, cy = ORIGIN[0], ORIGIN[1]
    r = 0.01
    for p in arc.points_m:
        assert math.hypot(p[0] - cx, p[1] - cy) == pytest.approx(r, abs=1e-12)
    pts = [motions(job)[0].points_m[0], *arc.points_m]
    for a, b in itertools.pairwise(pts):
        mid = ((a[0] + b[0]) / 2 - cx, (a[1] + b[1]) / 2 - cy)
        assert r - math.hypot(*mid) <= 1e-4 + 1e-12  # chord within the tolerance
        assert math.atan2(b[1] - cy, b[0] - cx) > math.atan2(a[1] - cy, a[0] - cx)  # ccw
    assert close(arc.points_m[-1], (cx, cy + r, ORIGIN[2]))
    assert job.moves == 2


def test_arc_clockwise_and_r_form_agree() -> None:
    a = motions(run("G1 X0 Y0 F600\nG2 X10 Y10 I10 J0\n"))[1].points_m
    b = motions(run("G1 X0 Y0 F600\nG2 X10 Y10 R10\n"))[1].points_m
    assert len(a) == len(b)
    assert all(close(p, q, 1e-9) for p, q in zip(a, b, strict=True))
    # clockwise about (10, 0) from 180 to 90 degrees: the quarter up and left of the centre
    for p in a:
        x, y = (p[0] - ORIGIN[0]) * 1e3, (p[1] - ORIGIN[1]) * 1e3
        assert math.hypot(x - 10.0, y) == pytest.approx(10.0)
        assert x <= 10.0 + 1e-9 and y >= -1e-9


def test_negative_r_takes_the_long_way_and_full_circle_with_ij() -> None:
    short = motions(run("G1 X0 Y0 F600\nG2 X10 Y10 R10\n"))[1]
    long = motions(run("G1 X0 Y0 F600\nG2 X10 Y10 R-10\n"))[1]
    assert len(long.points_m) == pytest.approx(3 * len(short.points_m), rel=0.1)
    full = motions(run("G1 X10 Y0 F600\nG2 X10 Y0 I-10 J0 Z5\n"))[1]
    assert len(full.points_m) == pytest.approx(4 * len(short.points_m), rel=0.1)
    assert full.points_m[-1][2] == pytest.approx(ORIGIN[2] + 0.005)  # a helix


def test_bad_arcs_are_refused_naming_the_line() -> None:
    with pytest.raises(JobError, match="line 2: G2: the end is"):
        run("G1 X0 Y0 F600\nG2 X10 Y0 I3 J0\n")
    with pytest.raises(JobError, match="line 1: G18"):
        run("G18\nG2 X1 I1\n")
    with pytest.raises(JobError, match="line 2: G3: an arc needs"):
        run("G1 F600\nG3 X1\n")


def test_g1_before_any_feed_and_too_slow_feeds_are_refused() -> None:
    with pytest.raises(JobError, match="line 1: G1 before any feed"):
        run("G1 X1\n")
    with pytest.raises(JobError, match="line 1: feed F30"):
        run("G1 X1 F30\n")  # 0.5 mm/s


def test_modal_motion_without_a_command() -> None:
    job = run("G1 X1 F600\nX2 Y3\nY4\n")
    assert [m.points_m[0][:2] for m in motions(job)] == [
        pytest.approx((1.001, -2.0)),
        pytest.approx((1.002, -1.997)),
        pytest.approx((1.002, -1.996)),
    ]


def test_dwell_sync_report_disarm_estop() -> None:
    job = run("G1 X1 F600\nG4 P250\nG4 S2\nM400\nM114\nM84 E\nM84\nM112\n")
    acts = [a for a in job.actions if not isinstance(a, Motion)]
    assert acts[0] == Dwell(2, 0.25) and acts[1] == Dwell(3, 2.0)
    assert acts[2] == Sync(4)
    assert acts[3] == Sync(5, "X:1.000 Y:0.000 Z:0.000 E:0.000")
    assert acts[4] == Disarm(7) and acts[5] == Estop(8)
    assert job.not_driven == {"M84": 1}


def test_g28_goes_to_the_home_pose() -> None:
    frame = GcodeFrame(origin_m=ORIGIN, home_m=(0.0, 0.0, 3.0), rapid_speed_mps=0.5)
    job = run("G1 X5 Y5 Z5 F600\nG28 Z\nG28\n", frame)
    m = motions(job)
    assert close(m[1].points_m[0], (1.005, -1.995, 3.0)) and not m[1].move
    assert close(m[2].points_m[0], (0.0, 0.0, 3.0)) and m[2].speed_mps == 0.5
    assert job.moves == 1


def test_extrusion_tools_heaters_summarised_unknown_counted_per_code() -> None:
    job = run(
        "M104 S200\nM109 S200\nT0\nM106 S255\nM83\nG1 X1 E0.5 F600\nG1 X2 E0.5\n"
        "G29\nG29\nM999\nM117 Printing\nM73 P0\n"
    )
    assert job.not_driven == {"M104": 1, "M109": 1, "T": 1, "M106": 1, "M83": 1, "E": 2}
    assert job.unsupported == {"G29": 2, "M999": 1}
    assert job.lines == 12


def test_m114_reports_e_in_relative_mode() -> None:
    job = run("M83\nG1 X1 E2 F600\nG1 E3\nM114\n")
    assert next(a for a in job.actions if isinstance(a, Sync)).report == (
        "X:1.000 Y:0.000 Z:0.000 E:5.000"
    )
    assert job.moves == 1  # E-only lines are not moves


# ------------------------------------------------------------------------- the whole-job check
CFG = default_config()
WS = Workspace.from_limits(CFG.limits, CFG.geometry)
TENSION = TensionCheck(CFG.anchors_m, 5.0, 5.0, 500.0, 5.0, "limits.max_tension_n")
HOME = (0.0, 0.0, 2.0)
PAPER = GcodeFrame(origin_m=HOME, max_speed_mps=2.0)


def test_a_job_inside_passes() -> None:
    job = run("G1 X1000 Y1000 F6000\nG2 X2000 Y0 R1000\nG1 Z1000\n", PAPER, HOME)
    assert check_job(job, WS, TENSION) is None


def test_a_job_out_of_the_workspace_names_the_first_line() -> None:
    job = run("G1 X1000 F6000\nG1 Z-1000\nG1 Z-3000\nG1 Z-4000\n", PAPER, HOME)
    failure = check_job(job, WS, TENSION)
    assert failure is not None and failure[0] == 3
    assert "z" in failure[1] and "floor_z_m" in failure[1]


def test_a_job_out_of_the_tension_region_names_its_line() -> None:
    # 6.5 m up is inside the geometric workspace (top 6.62 m) but the cables would pull > 495 N
    job = run("G1 X1000 F6000\nG1 Z4500\nG1 Z0\n", PAPER, HOME)
    assert check_job(job, WS, None) is None
    failure = check_job(job, WS, TENSION)
    assert failure is not None and failure[0] == 2
    assert "above 495 N" in failure[1]


def test_an_arc_leaving_the_footprint_names_the_arc_line() -> None:
    # a circle of radius 30 m about the origin bulges past the 23 m plan-view limit in y
    job = run("G1 X30000 F60000\nG3 X30000 Y0 I-30000 J0\n", PAPER, HOME)
    failure = check_job(job, WS, None)
    assert failure is not None and failure[0] == 2


@settings(max_examples=60, deadline=None)
@given(
    st.floats(1.0, 500.0),
    st.floats(-math.pi, math.pi),
    st.floats(0.1, 6.2),
    st.booleans(),
    st.floats(1e-5, 1e-3),
)
def test_arc_chords_stay_within_tolerance(
    r_mm: float, a0: float, sweep: float, cw: bool, tol: float
) -> None:
    frame = GcodeFrame(origin_m=(0.0, 0.0, 0.0), arc_tolerance_m=tol)
    sx, sy = r_mm * math.cos(a0), r_mm * math.sin(a0)
    a1 = a0 - sweep if cw else a0 + sweep
    ex, ey = r_mm * math.cos(a1), r_mm * math.sin(a1)
    code = "G2" if cw else "G3"
    text = f"G1 X{sx:.6f} Y{sy:.6f} F600\n{code} X{ex:.6f} Y{ey:.6f} I{-sx:.6f} J{-sy:.6f}\n"
    job = run(text, frame, (0.0, 0.0, 0.0))
    pts = [motions(job)[0].points_m[0], *motions(job)[1].points_m]
    r = r_mm / 1000.0
    turned = 0.0
    for a, b in itertools.pairwise(pts):
        assert math.dist(a, (0, 0, 0)) == pytest.approx(r, abs=1e-8)
        mid = math.hypot((a[0] + b[0]) / 2, (a[1] + b[1]) / 2)
        assert r - mid <= tol + 1e-9
        d = math.atan2(a[0] * b[1] - a[1] * b[0], a[0] * b[0] + a[1] * b[1])
        assert (d < 0) == cw
        turned += abs(d)
    assert turned == pytest.approx(sweep, abs=1e-5)


def test_dry_run_step_follows_the_shortest_segments_but_not_below_the_loop() -> None:
    from controller.core.gcode_job import DRY_RUN_DT_S, dry_run_step_s

    slow = run("G1 X100 F600\nG1 X200\n")  # 10 s a segment
    assert dry_run_step_s(slow, 0.002) == DRY_RUN_DT_S
    # 0.1 mm segments at 100 mm/s: 1 ms each, 4 of them a step
    fine = run("G1 F6000\n" + "".join(f"G1 X{0.1 * k:.1f}\n" for k in range(1, 500)))
    assert dry_run_step_s(fine, 0.002) == pytest.approx(0.004)
    assert dry_run_step_s(fine, 0.01) == 0.01  # never below the loop's period


# --- M593: input shaping --------------------------------------------------------------------


def test_m593_shapes_the_moves_after_it_in_repraps_syntax() -> None:
    from controller.core.gcode_job import Chunk, Shaping, chunks

    job = run('G1 X1 F600\nM593 P"ei2" F12.5 S0.05\nG1 X2\nM593 P"None"\nM593 F30\nM593\n')
    acts = [a for a in job.actions if not isinstance(a, Motion)]
    assert acts == [
        Shaping(2, "2hump_ei", 12.5, 0.05),
        Shaping(4, "off", None, None),
        Shaping(5, "2hump_ei", 30.0, None),  # no P: the default type; M593 alone: nothing
    ]
    steps = list(chunks(job.actions, 100))
    assert [type(s).__name__ for s in steps] == ["Chunk", "Shaping", "Chunk", "Shaping", "Shaping"]
    assert isinstance(steps[0], Chunk) and isinstance(steps[2], Chunk)
    # RepRapFirmware's names and cablebot's, any case; no F: the model's modes
    for word, kind in (
        ("zvd", "zvd"),
        ("MZV", "mzv"),
        ("ei3", "3hump_ei"),
        ("2hump_ei", "2hump_ei"),
    ):
        (shaping,) = run(f'M593 P"{word}"').actions
        assert shaping == Shaping(1, kind, None, None)


@pytest.mark.parametrize(
    ("line", "why"),
    [
        (
            'M593 P"zvdd" F40',
            r"line 2: M593 P\"zvdd\": unknown or unsupported .*did you mean 'zvd'",
        ),
        ('M593 P"ie2" F40', r"line 2: M593 P\"ie2\": unknown .*did you mean 'ei2'"),
        ('M593 P"custom" H0.4:0.7 T0.0135:0.0135', r"line 2: M593 H/T .*not supported"),
        ('M593 P"zvd" F0', r"line 2: M593: frequency 0.0 Hz out of range \(0.05 to 1000 Hz\)"),
        ('M593 P"zvd" F40 S0.5', r"line 2: M593: damping ratio 0.5 out of range \(0 to 0.3\)"),
        ("M593 P3 F40", r"line 2: M593 P: a quoted type"),
    ],
)
def test_m593_refuses_a_shaper_it_cannot_run_naming_the_line(line: str, why: str) -> None:
    with pytest.raises(JobError, match=why):
        run(f"G1 X1 F600\n{line}\nG1 X2\n")
