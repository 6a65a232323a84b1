"""controller.core.scale: values that cannot be meant for the robot they are given to."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.core.scale import (
    MIN_CROSSING_S,
    TINY_JOB_M,
    job_extent_m,
    speed_scale_problem,
    tiny_job_problem,
)

DESK_BOX = ((-0.45, 0.45), (-0.45, 0.45), (0.01, 0.7))


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
    points = [(0.0001, 0.0001, 0.0002), (0.0004, 0.0001, 0.0002), (0.0004, 0.0004, 0.0002)]
    assert job_extent_m(points) == pytest.approx(0.0003)
    why = tiny_job_problem(job_extent_m(points), DESK_BOX)
    assert why is not None and "0.3 mm" in why and "written in metres" in why
    assert tiny_job_problem(0.0, DESK_BOX) is None  # no motion: nothing to say
    assert tiny_job_problem(0.02, DESK_BOX) is None  # a 20 mm job is a job
    small_rig = ((0.0, 0.3), (0.0, 0.3), (0.0, 0.3))  # a 4 mm job on a 0.3 m rig may be meant
    assert tiny_job_problem(TINY_JOB_M * 0.8, small_rig) is None
    assert job_extent_m([]) == 0.0
