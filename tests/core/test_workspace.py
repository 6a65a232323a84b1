"""Limits: workspace polygon, z band, cable lengths and speeds, paths; reasons name the limit."""

from __future__ import annotations

import math
import timeit

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.core.kinematics import Geometry, footprint_contains, ipk_point
from controller.core.workspace import Limits
from controller.service.config import LimitsConfig, default_config, load_config

CFG = default_config()
LIM = Limits(CFG.limits, CFG.geometry)


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
def test_polygon_agrees_with_kinematics_footprint(x: float, y: float, z: float) -> None:
    inside = footprint_contains(CFG.geometry, x, y, CFG.limits.xy_margin_m)
    reason = LIM.check_point((x, y, z))
    if min(abs(z), abs(z - 6.62)) < 1e-8:
        return  # within the rounding tolerance of a z bound: either answer is right
    z_ok = 0.0 <= z <= 6.62
    if inside and z_ok:
        assert reason is None
    elif not inside:
        # near the edge the two may disagree only within the rounding tolerance
        near = footprint_contains(CFG.geometry, x, y, CFG.limits.xy_margin_m - 1e-8)
        if not near:
            assert reason is not None and "plan-view polygon" in reason
    else:
        assert reason is not None and reason.startswith("z=")


def test_non_rectangular_anchor_layout() -> None:
    # a triangle of anchors at different heights plus an interior (non-hull) anchor
    geom = Geometry([(0, 0, 5), (10, 0, 6), (0, 10, 5.5), (2, 2, 5)])
    lim = Limits(
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
    assert lim.polygon_m == ((0.0, 0.0), (10.0, 0.0), (0.0, 10.0))
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
    lim = Limits(desk.limits, desk.geometry)
    a, b = (-0.45, -0.35, 0.7), (-0.35, -0.45, 0.7)
    assert lim.check_target(a) is None and lim.check_target(b) is None
    mid = (-0.4, -0.4, 0.7)
    assert ipk_point(desk.geometry, mid)[0] == pytest.approx(math.sqrt(0.02 + 0.01))
    tight = Limits(_with_min_cable(desk.limits, 0.18), desk.geometry)
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
        Limits(replace(CFG.limits, xy_margin_m=40.0), CFG.geometry)
    with pytest.raises(ValueError, match="floor_z_m"):
        Limits(replace(CFG.limits, floor_z_m=7.0), CFG.geometry)


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
