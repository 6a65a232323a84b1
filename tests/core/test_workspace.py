"""Workspace: polygon, z band, cable lengths and speeds, paths, box; reasons name the limit."""

from __future__ import annotations

import math
import timeit

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.core.kinematics import Geometry, ipk_point, paper_anchors
from controller.core.workspace import (
    Violation,
    Workspace,
    WorkspaceError,
    footprint_contains,
    shrink_polygon,
)
from controller.service.config import LimitsConfig, default_config, load_config

CFG = default_config()
LIM = Workspace.from_limits(CFG.limits, CFG.geometry)


def test_inside_points_pass() -> None:
    for p in [(0, 0, 2), (38.45, 23.0, 0.0), (-38.45, -23.0, 6.62), (10.0, -5.0, 3.0)]:
        assert LIM.check_point(p) is None, p
        assert LIM.check_target(p) is None, p


def test_reasons_name_the_limit_and_the_value() -> None:
    assert LIM.check_point((0, 0, 7.2)) == ("z=7.2 m above the anchor plane minus margin (6.62 m)")
    assert LIM.check_point((0, 0, -0.5)) == "z=-0.5 m below the floor (floor_z_m 0 m)"
    assert LIM.check_point((39.0, 0.0, 2.0)) == (
        "(x, y) = (39, 0) m is 0.55 m outside the anchors' plan-view polygon shrunk by "
        "xy_margin_m (2 m)"
    )
    assert LIM.check_point((0.0, 24.0, 2.0)) is not None
    assert "is 1 m outside" in (LIM.check_point((0.0, -24.0, 2.0)) or "")
    assert LIM.check_point((math.nan, 0, 2)) == "position (nan, 0, 2) is not finite"
    assert LIM.check_lengths([48.0, 0.5, 48.0, 48.0]) == (
        "cable 2 length 0.5 m below min_cable_m (1 m)"
    )
    assert LIM.check_lengths([48.0, 48.0, 48.0, 120.0]) == (
        "cable 4 length 120 m above max_cable_m (100 m)"
    )
    assert LIM.check_lengths([48.0, math.nan, 48.0, 48.0]) == "cable 2 length nan is not finite"
    assert LIM.check_cable_speeds([10, 10, 10, 10], [10, 10, 10.01, 10], 0.002) == (
        "cable 3 speed 5 m/s above max_cable_speed_mps (3 m/s)"
    )


def test_boundaries_are_inclusive_up_to_rounding() -> None:
    assert LIM.check_point((38.45, 0.0, 2.0)) is None  # exactly on the shrunk edge
    assert LIM.check_point((38.45 + 1e-6, 0.0, 2.0)) is not None
    assert LIM.check_point((0.0, 0.0, 6.62)) is None
    assert LIM.check_point((0.0, 0.0, 6.62 + 1e-6)) is not None
    assert LIM.check_lengths([1.0, 100.0, 50.0, 50.0]) is None
    assert LIM.check_cable_speeds([1.0], [1.006], 0.002) is None  # exactly 3 m/s
    assert LIM.check_cable_speeds([1.0], [1.0061], 0.002) is not None
    assert LIM.check_cable_speeds([1.0], [2.0], 0.0) is None  # nothing measurable


coord = st.floats(-60.0, 60.0)


@settings(max_examples=500, deadline=None)
@given(coord, coord, st.floats(-1.0, 9.0))
def test_check_point_agrees_with_the_footprint_rule(x: float, y: float, z: float) -> None:
    inside = footprint_contains(CFG.geometry.footprint_m, x, y, CFG.limits.xy_margin_m)
    assert LIM.contains_xy(x, y) == inside
    reason = LIM.check_point((x, y, z))
    if min(abs(z), abs(z - 6.62)) < 1e-8:
        return  # within the rounding tolerance of a z bound: either answer is right
    z_ok = 0.0 <= z <= 6.62
    if inside and z_ok:
        assert reason is None
    elif not inside:
        # near the edge the two may disagree only within the rounding tolerance
        near = footprint_contains(CFG.geometry.footprint_m, x, y, CFG.limits.xy_margin_m - 1e-8)
        if not near:
            assert reason is not None and "plan-view polygon" in reason
    else:
        assert reason is not None and reason.startswith("z=")


def test_non_rectangular_anchor_layout() -> None:
    # a triangle of anchors at different heights plus an interior (non-hull) anchor
    geom = Geometry([(0, 0, 5), (10, 0, 6), (0, 10, 5.5), (2, 2, 5)])
    lim = Workspace.from_limits(
        LimitsConfig(
            xy_margin_m=1.0,
            floor_z_m=0.0,
            top_margin_m=0.5,
            min_cable_m=0.5,
            max_cable_m=20.0,
            max_cable_speed_mps=1.0,
            max_speed_mps=1.0,
            max_accel_mps2=1.0,
            default_speed_mps=1.0,
        ),
        geom,
    )
    assert lim.footprint_m == ((0.0, 0.0), (10.0, 0.0), (0.0, 10.0))
    # the shrunk triangle: x >= 1, y >= 1, x + y <= 10 - sqrt(2)
    far = 10 - math.sqrt(2) - 1.0
    flat = [c for p in lim.polygon_m for c in p]
    assert flat == pytest.approx([1.0, 1.0, far, 1.0, 1.0, far])
    assert [c for r in lim.box() for c in r] == pytest.approx([1.0, far, 1.0, far, 0.0, 4.5])
    assert lim.top_z_m == 4.5  # lowest anchor minus margin
    assert lim.check_point((1.0, 1.0, 2.0)) is None
    assert lim.check_point((0.5, 5.0, 2.0)) is not None  # within 1 m of the x = 0 edge
    # the hypotenuse x + y = 10 shrunk by 1 m: x + y <= 10 - sqrt(2)
    edge = (10 - math.sqrt(2)) / 2
    assert lim.check_point((edge - 1e-6, edge - 1e-6, 2.0)) is None
    assert lim.check_point((edge + 1e-6, edge + 1e-6, 2.0)) is not None


def test_path_checks_points_and_legs() -> None:
    assert LIM.check_path([(0, 0, 2), (20, 0, 2), (20, 10, 3)]) is None
    assert LIM.check_path([]) == "path has no points"
    assert LIM.check_path([(0, 0, 2), (0, 0, 9)]) == (
        "path point 2: z=9 m above the anchor plane minus margin (6.62 m)"
    )
    # start given: the leg from it is checked too; a leg passing right under an anchor
    # brings that cable below min_cable_m although both ends are fine
    desk = load_config("config/desk.toml")
    lim = Workspace.from_limits(desk.limits, desk.geometry)
    a, b = (-0.45, -0.35, 0.7), (-0.35, -0.45, 0.7)
    assert lim.check_target(a) is None and lim.check_target(b) is None
    mid = (-0.4, -0.4, 0.7)
    assert ipk_point(desk.geometry, mid)[0] == pytest.approx(math.sqrt(0.02 + 0.01))
    tight = Workspace.from_limits(_with_min_cable(desk.limits, 0.18), desk.geometry)
    assert tight.check_target(a) is None and tight.check_target(b) is None
    reason = tight.check_path([b], start_m=a)
    assert reason is not None
    assert reason.startswith("path point 1: on the leg to it: cable 1 would shorten to 0.1732")
    assert tight.check_path([b]) is None  # without the start there is no leg


def _with_min_cable(cfg: LimitsConfig, min_cable_m: float) -> LimitsConfig:
    from dataclasses import replace

    return replace(cfg, min_cable_m=min_cable_m)


def test_bad_limits_are_rejected() -> None:
    from dataclasses import replace

    with pytest.raises(ValueError, match="leaves no workspace"):
        Workspace.from_limits(replace(CFG.limits, xy_margin_m=40.0), CFG.geometry)
    with pytest.raises(ValueError, match="floor_z_m"):
        Workspace.from_limits(replace(CFG.limits, floor_z_m=7.0), CFG.geometry)


def test_per_tick_checks_are_cheap() -> None:
    p = (10.0, -5.0, 3.0)
    lengths = ipk_point(CFG.geometry, p)
    prev = tuple(x - 0.001 for x in lengths)
    n = 2000

    def tick() -> None:
        LIM.check_point(p)
        LIM.check_lengths(lengths)
        LIM.check_cable_speeds(prev, lengths, 0.002)

    per_tick_s = min(timeit.repeat(tick, number=n, repeat=3)) / n
    print(f"per-tick limit checks: {per_tick_s * 1e6:.1f} us")
    assert per_tick_s < 200e-6  # generous for a loaded 2-core machine; typically ~3 us


# ------------------------------------------------------------------------------ the one rule


def test_footprint_contains() -> None:
    paper = Geometry(paper_anchors()).footprint_m
    assert footprint_contains(paper, 0.0, 0.0)
    assert footprint_contains(paper, 40.46, 25.0)
    assert footprint_contains(paper, 40.0, 0.0, margin_m=0.46)
    assert not footprint_contains(paper, 40.0, 0.0, margin_m=0.47)
    assert not footprint_contains(paper, 41.0, 0.0)
    assert not footprint_contains(paper, math.nan, 0.0)
    assert not footprint_contains(paper, 0.0, math.inf)
    tri = Geometry([(0, 0, 5), (10, 0, 5), (0, 10, 5), (2, 2, 5)]).footprint_m  # one inside
    assert footprint_contains(tri, 4.9, 4.9, margin_m=0.0)
    assert not footprint_contains(tri, 5.1, 5.1, margin_m=0.0)
    assert footprint_contains(tri, 4.6, 4.6, margin_m=0.5)  # 0.566 m from the long edge
    assert not footprint_contains(tri, 4.7, 4.7, margin_m=0.5)  # 0.424 m


def test_plain_values_and_a_limits_object_build_the_same_workspace() -> None:
    lim = CFG.limits
    plain = Workspace(
        CFG.geometry,
        xy_margin_m=lim.xy_margin_m,
        floor_z_m=lim.floor_z_m,
        top_margin_m=lim.top_margin_m,
        min_cable_m=lim.min_cable_m,
        max_cable_m=lim.max_cable_m,
        max_cable_speed_mps=lim.max_cable_speed_mps,
    )
    for name in ("footprint_m", "polygon_m", "floor_z_m", "top_z_m", "min_cable_m"):
        assert getattr(plain, name) == getattr(LIM, name), name
    assert plain.box() == LIM.box()
    for p in [(0, 0, 2), (39.0, 0.0, 2.0), (0, 0, 9), (0, 0, -1)]:
        assert plain.check_target(p) == LIM.check_target(p)


def test_box_is_the_shrunk_footprint_and_the_z_band() -> None:
    # the paper robot's box, as `feasible.feasible_workspace` and `calibrate --auto` take it
    assert LIM.box() == ((-38.45, 38.45), (-23.0, 23.0), (0.0, 6.62))
    desk = load_config("config/desk.toml")
    box = Workspace.from_limits(desk.limits, desk.geometry).box()
    assert box[:2] == ((-0.45, 0.45), (-0.45, 0.45))  # exact for a rectangle
    assert box[2] == pytest.approx((0.01, 0.7))
    for x in box[0]:
        for y in box[1]:
            for z in LIM.box()[2]:
                assert LIM.check_point((x * 38.45 / 0.45, y * 23.0 / 0.45, z)) is None


def test_shrink_polygon() -> None:
    square = ((0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0))
    assert shrink_polygon(square, 0.5) == ((0.5, 0.5), (1.5, 0.5), (1.5, 1.5), (0.5, 1.5))
    assert shrink_polygon(square, 1.5) == ()
    # a sharp vertex moves in by far more than the margin
    kite = ((0.0, 0.0), (10.0, -1.0), (10.2, 0.0), (10.0, 1.0))
    inner = shrink_polygon(kite, 0.5)
    assert inner and all(footprint_contains(kite, x, y, 0.5 - 1e-9) for x, y in inner)
    assert min(x for x, _ in inner) > 5.0  # tip half-angle 5.7 deg: 0.5 m / sin(5.7 deg)


def test_errors_name_the_limit() -> None:
    from dataclasses import replace

    cases = [
        (replace(CFG.limits, floor_z_m=7.0), "floor_z_m", "7 m must be below the lowest anchor"),
        (replace(CFG.limits, min_cable_m=200.0), "min_cable_m", "200 m must be < max_cable_m"),
        (replace(CFG.limits, xy_margin_m=30.0), "xy_margin_m", "30 m leaves no workspace"),
        (replace(CFG.limits, top_margin_m=math.nan), "top_margin_m", "must be a finite number"),
        (replace(CFG.limits, max_cable_m=math.inf), "max_cable_m", "must be a finite number"),
    ]
    for limits, key, detail in cases:
        with pytest.raises(WorkspaceError) as info:
            Workspace.from_limits(limits, CFG.geometry)
        assert info.value.limit == key and info.value.detail.startswith(detail), info.value
        assert str(info.value) == f"{key}: {info.value.detail}"


def test_violations_say_which_limit_which_cable_and_the_value() -> None:
    assert LIM.target_violation((0.0, 0.0, 2.0)) is None
    v = LIM.target_violation((39.0, 0.0, 2.0))
    assert v == Violation("xy_margin_m", None, pytest.approx(0.55), 2.0, v.reason)
    assert v.reason == LIM.check_point((39.0, 0.0, 2.0))
    assert LIM.point_violation((0, 0, -0.5)) == Violation(
        "floor_z_m", None, -0.5, 0.0, "z=-0.5 m below the floor (floor_z_m 0 m)"
    )
    top = LIM.point_violation((0, 0, 7.0))
    assert top is not None and (top.limit, top.value, top.bound) == ("top_margin_m", 7.0, 6.62)
    nan = LIM.point_violation((math.nan, 0, 2))
    assert nan is not None and nan.limit == "position"
    short = LIM.lengths_violation([48.0, 0.5, 48.0, 48.0])
    assert short is not None
    assert (short.limit, short.cable, short.value, short.bound) == ("min_cable_m", 2, 0.5, 1.0)
    long = LIM.lengths_violation([48.0, 48.0, 48.0, 120.0])
    assert long is not None and (long.limit, long.cable) == ("max_cable_m", 4)
    # a point near an anchor: in the workspace, but its cable is too short
    tight = Workspace.from_limits(_with_min_cable(CFG.limits, 5.0), CFG.geometry)
    near = (-38.45, -23.0, 6.62)
    assert tight.check_point(near) is None
    v = tight.target_violation(near)
    assert v is not None and (v.limit, v.cable) == ("min_cable_m", 1)
    assert v.reason == tight.check_target(near)


def test_path_failure_points_only() -> None:
    desk = load_config("config/desk.toml")
    tight = Workspace.from_limits(_with_min_cable(desk.limits, 0.18), desk.geometry)
    a, b = (-0.45, -0.35, 0.7), (-0.35, -0.45, 0.7)
    for n in (2, 40):  # scalar and vectorised
        pts = [a, b] * (n // 2)
        assert tight.path_failure(pts) is not None  # a leg passes under anchor 1
        assert tight.path_failure(pts, legs=False) is None
        assert tight.path_failure(pts, start_m=a, legs=False) is None
        bad = [*pts[:-1], (0.0, 0.0, 5.0)]
        got = tight.path_failure(bad, legs=False)
        assert got is not None and got[0] == n - 1 and "above the anchor plane" in got[1]


def test_core_does_not_import_the_service() -> None:
    import subprocess
    import sys

    code = (
        "import sys, controller.core.workspace; "
        "bad = [m for m in sys.modules if m.startswith('controller.service')]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(st.floats(-45.0, 45.0), st.floats(-30.0, 30.0), st.floats(-1.0, 9.0)),
        min_size=1,
        max_size=40,
    )
)
def test_inside_points_is_check_target_vectorised(points: list[tuple[float, float, float]]) -> None:
    import numpy as np

    # add the exact boundary points too: the tolerance must agree
    pts = [*points, (38.45, 23.0, 0.0), (-38.45, -23.0, 6.62), (38.45 + 2e-9, 0.0, 1.0)]
    got = LIM.inside_points(np.asarray(pts))
    assert got.tolist() == [LIM.check_target(p) is None for p in pts]


def test_inside_points_refuses_non_finite_and_wrong_shapes() -> None:
    import numpy as np

    assert LIM.inside_points(np.array([[math.nan, 0.0, 1.0], [0.0, 0.0, 1.0]])).tolist() == [
        False,
        True,
    ]
    with pytest.raises(ValueError, match="shape"):
        LIM.inside_points(np.zeros((3, 2)))
