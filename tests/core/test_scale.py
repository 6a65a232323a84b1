"""controller.core.scale: values that cannot be meant for the robot they are given to."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from controller.core.scale import (
    MIN_CROSSING_S,
    TINY_JOB_M,
    TINY_JOB_RATIO,
    UNIT_FACTOR,
    speed_limit_problem,
    speed_scale_problem,
    tiny_job_problem,
)

DESK_BOX = ((-0.45, 0.45), (-0.45, 0.45), (0.01, 0.7))
PAPER_BOX = ((-38.45, 38.45), (-23.0, 23.0), (0.0, 6.62))
"""The workspace box of the shipped paper robot (config/paper-acre.toml): 76.9 m long."""


def test_a_speed_in_mm_per_s_on_the_desk_rig_is_named_as_such() -> None:
    assert speed_scale_problem(300.0, DESK_BOX) == (
        "300 m/s crosses the workspace's 0.9 m in 3 ms: a speed this robot cannot mean (the unit"
        " is metres per second; a value in mm/s?)"
    )
    assert speed_scale_problem(2.0, DESK_BOX) is None


@given(
    st.floats(1e-3, 1e4, allow_nan=False),
    st.floats(1e-3, 1e3, allow_nan=False),
)
def test_a_speed_is_refused_exactly_when_it_crosses_the_longest_side_too_fast(
    speed_mps: float, side_m: float
) -> None:
    box = ((0.0, side_m), (0.0, side_m / 2.0), (0.0, side_m / 3.0))
    refused = speed_scale_problem(speed_mps, box) is not None
    assert refused == (side_m / speed_mps < MIN_CROSSING_S)


def test_a_job_a_few_millimetres_across_on_a_metre_scale_robot_is_flagged() -> None:
    why = tiny_job_problem(0.0003, DESK_BOX)  # a 0.3 m square written in metres
    assert why is not None and "0.3 mm" in why and "written in metres" in why
    assert tiny_job_problem(0.0, DESK_BOX) is None  # no motion: nothing to say
    assert tiny_job_problem(0.02, DESK_BOX) is None  # a 20 mm job is a job
    small_rig = ((0.0, 0.3), (0.0, 0.3), (0.0, 0.3))  # a 4 mm job on a 0.3 m rig may be meant
    assert tiny_job_problem(TINY_JOB_M * 0.8, small_rig) is None


def test_a_file_in_metres_on_the_paper_robot_is_flagged_though_wider_than_5_mm() -> None:
    # a 3 m circle written in metres spans 6 mm read as millimetres: 5 mm alone missed it,
    # and the robot flew the whole job 2 mm above the floor
    why = tiny_job_problem(0.006, PAPER_BOX)
    assert why == (
        "the job's motions span only 6 mm on a robot whose workspace is 76.9 m long: is the file"
        " written in metres? G-code lengths are millimetres (G21) or inches (G20), and [gcode]"
        " units sets the unit a job starts in"
    )
    assert tiny_job_problem(0.07, PAPER_BOX) is not None  # under 76.9 mm: a thousandth
    assert tiny_job_problem(0.1, PAPER_BOX) is None  # a 10 cm job on it may be meant


@given(st.floats(0.0, 100.0, allow_nan=False), st.floats(0.01, 1000.0, allow_nan=False))
def test_a_job_is_flagged_exactly_when_it_fits_in_a_thousandth_or_5_mm_of_a_big_workspace(
    extent_m: float, side_m: float
) -> None:
    box = ((0.0, side_m / 2.0), (0.0, side_m), (0.0, side_m / 3.0))
    flagged = tiny_job_problem(extent_m, box) is not None
    big = side_m >= TINY_JOB_RATIO * TINY_JOB_M
    assert flagged == (big and 0.0 < extent_m < max(TINY_JOB_M, side_m / UNIT_FACTOR))


def test_an_m203_far_below_the_jobs_feeds_is_taken_for_the_other_dialect() -> None:
    # Marlin's M203 X200 (mm/s) read as RepRapFirmware's mm/min, feeds up to 120 mm/s
    why = speed_limit_problem(13, 0.2 / 60.0, 0.12, per_minute=True)
    assert why is not None and why.startswith("line 13: M203 limits the job to 3.333 mm/s")
    assert '"marlin"' in why and "36 times below" in why
    why = speed_limit_problem(5, 0.001, 0.02, per_minute=False)
    assert why is not None and '"reprapfirmware"' in why and "(read in mm/s)" in why
    # a limit the feeds stay near is meant: a slow first layer, a cautious job
    assert speed_limit_problem(13, 0.2, 0.12, per_minute=True) is None
    assert speed_limit_problem(13, 0.02, 0.19, per_minute=False) is None
    assert speed_limit_problem(13, 0.0, 0.19, per_minute=False) is None
