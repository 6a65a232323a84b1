"""The vectorised path check gives exactly the verdict and reason of checking point by point."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.core.workspace import TOL_M, Workspace, points_array
from tests.fakes import make_config

CFG = make_config()
LIM = Workspace.from_limits(CFG.limits, CFG.geometry)
# Cables of at least 10 m: a leg between two allowed points can pass too close to an anchor.
CFG10 = make_config(limits={"min_cable_m": 10.0})
LIM10 = Workspace.from_limits(CFG10.limits, CFG10.geometry)
ANCHORS = [tuple(float(v) for v in a) for a in CFG.geometry.anchors_m]


def reference(
    points: Sequence[Sequence[float]], start: Sequence[float] | None, lim: Workspace = LIM
) -> tuple[int, str] | None:
    """Point by point with the scalar checks (the definition of the verdict)."""
    prev = start
    for i, p in enumerate(points):
        reason = lim.check_target(p)
        if reason is not None:
            return i, reason
        if prev is not None:
            reason = lim.check_segment(prev, p)
            if reason is not None:
                return i, f"on the leg to it: {reason}"
        prev = p
    return None


# Mostly points inside the workspace (so that later points and legs get checked too), some
# exactly on a limit or 1-2 nm beyond it, some outside, some close to an anchor (short cables,
# legs passing under an anchor).
_inside = st.tuples(st.floats(-38.45, 38.45), st.floats(-23.0, 23.0), st.floats(0.0, 6.62))
_x = st.one_of(st.floats(-45.0, 45.0), st.sampled_from([-38.45, 38.45, -38.45 - TOL_M]))
_y = st.one_of(st.floats(-28.0, 28.0), st.sampled_from([-23.0, 23.0, 23.0 + 2 * TOL_M]))
_z = st.one_of(st.floats(-0.5, 7.5), st.sampled_from([0.0, -TOL_M, 6.62, 6.62 + 2 * TOL_M]))
_edge = st.tuples(_x, _y, _z)
_near_anchor = st.builds(
    lambda a, dx, dy, dz: (a[0] + dx, a[1] + dy, a[2] - 1.0 + dz),
    st.sampled_from(ANCHORS),
    st.floats(-12.0, 12.0),
    st.floats(-12.0, 12.0),
    st.floats(-6.0, 0.5),
)
_point = st.one_of(*[_inside] * 12, _edge, _near_anchor)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(_point, min_size=16, max_size=60),
    st.one_of(st.none(), _point),
    st.sampled_from([LIM, LIM10]),
)
def test_vectorised_equals_point_by_point(
    points: list[tuple[float, float, float]],
    start: tuple[float, float, float] | None,
    lim: Workspace,
) -> None:
    assert lim.path_failure(points, start) == reference(points, start, lim)


def test_a_long_valid_path_and_its_first_bad_point() -> None:
    n = 10_000
    pts = [
        (20.0 * math.cos(2 * math.pi * i / n), 15.0 * math.sin(2 * math.pi * i / n), 2.0)
        for i in range(n)
    ]
    assert LIM.path_failure(pts) is None
    assert LIM.check_path(pts, (0.0, 0.0, 2.0)) is None
    pts[7000] = (pts[7000][0], pts[7000][1], -1.0)  # below the floor
    pts[9000] = (math.inf, 0.0, 2.0)
    got = LIM.path_failure(pts)
    assert got is not None and got == reference(pts, None)
    assert got[0] == 7000 and "below the floor" in got[1]
    assert LIM.check_path(pts) == f"path point 7001: {got[1]}"


def test_a_leg_that_passes_near_an_anchor_is_caught() -> None:
    ax, ay, _ = ANCHORS[0]
    # Both ends 11.4 m from anchor 1, the middle of the leg between them 9.7 m.
    a = (ax + 11.0, ay + 2.5, 6.0)
    b = (ax + 2.5, ay + 11.0, 6.0)
    assert LIM10.check_target(a) is None and LIM10.check_target(b) is None
    pts = [(0.0, 0.0, 2.0)] * 10 + [a, b] + [(0.0, 0.0, 2.0)] * 6
    got = LIM10.path_failure(pts)
    assert got == reference(pts, None, LIM10)
    assert got is not None and got[0] == 11 and "cable 1 would shorten" in got[1], got


def test_points_array_is_none_for_ragged_input_and_the_scalar_check_names_the_point() -> None:
    pts: list[Sequence[float]] = [(0.0, 0.0, 2.0)] * 20
    assert points_array(pts) is not None
    assert np.array_equal(points_array(pts), np.full((20, 3), [0.0, 0.0, 2.0]))
    pts[13] = (0.0, 2.0)
    assert points_array(pts) is None
    assert LIM.path_failure(pts) == (13, "needs 3 coordinates, got 2")
